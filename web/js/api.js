// The Conforma API from the browser: the operator's key, JSON requests, uploads with
// progress, Server-Sent Events over fetch() (so the key travels in the Authorization
// header, never in a URL), and readable error messages from RFC 9457 problem details.

const KEY_STORAGE = "conforma.apiKey";
export const API = "/api/v1";

export function getKey() {
  try { return localStorage.getItem(KEY_STORAGE) || ""; } catch { return ""; }
}

export function setKey(key) {
  localStorage.setItem(KEY_STORAGE, key.trim());
  document.dispatchEvent(new CustomEvent("conforma:key"));
}

function headers(extra = {}) {
  const h = { Accept: "application/json, application/problem+json", ...extra };
  const key = getKey();
  if (key) h.Authorization = `Bearer ${key}`;
  return h;
}

// An error the pages can show: `message` is one readable sentence, `problem` the body.
export class ApiError extends Error {
  constructor(message, { status = 0, problem = null, offline = false } = {}) {
    super(message);
    this.status = status;
    this.problem = problem;
    this.offline = offline;
  }

  // [{loc: "params.trace_id", msg}] from the problem's errors list.
  get fieldErrors() {
    const errors = (this.problem && Array.isArray(this.problem.errors)) ? this.problem.errors : [];
    return errors.map((e) => ({
      loc: Array.isArray(e.loc) ? e.loc.filter((p) => p !== "body").join(".") : String(e.loc ?? ""),
      msg: String(e.msg ?? ""),
    }));
  }
}

const STATUS_HINTS = {
  401: "The API key was refused; paste a valid key at the top of the page.",
  403: "Your key's role is not allowed to do this.",
  413: "The file or request is too large for this server.",
};

// Turn a non-2xx response into an ApiError with the problem's detail and field errors.
export async function errorFrom(response) {
  let problem;
  const text = await response.text().catch(() => "");
  try { problem = text ? JSON.parse(text) : null; } catch { problem = null; }
  let message;
  if (problem && typeof problem === "object" && (problem.detail || problem.title)) {
    message = `${problem.title || "Error"} (${response.status}): ${problem.detail || ""}`.trim();
  } else if (response.status >= 500) {
    message = `The server failed (${response.status} ${response.statusText || ""}). Try again; if it persists, check the server log.`;
  } else {
    message = `Request failed (${response.status} ${response.statusText || ""}).`;
  }
  if (STATUS_HINTS[response.status]) message += ` ${STATUS_HINTS[response.status]}`;
  return new ApiError(message.replace(/\s+/g, " ").trim(), { status: response.status, problem });
}

export function offlineError(cause) {
  const err = new ApiError(
    `Cannot reach the Conforma API at ${location.origin} (connection lost or server stopped). ` +
    "Your data is safe on the server; the page retries automatically.",
    { offline: true });
  err.cause = cause;
  document.dispatchEvent(new CustomEvent("conforma:offline"));
  return err;
}

// Raised without a request when the browser holds no key: every call but /health needs one.
export class NoKeyError extends ApiError {
  constructor() {
    super("No API key yet: paste one in the box at the top.", { status: 401 });
    this.noKey = true;
  }
}

// Check a key against the API before it is stored: resolves, or throws ApiError (401).
export async function verifyKey(key) {
  let response;
  try {
    response = await fetch(`${API}/parts?limit=1`, { headers: { Accept: "application/json", Authorization: `Bearer ${key.trim()}` } });
  } catch (cause) {
    throw offlineError(cause);
  }
  if (!response.ok) throw await errorFrom(response);
}

// JSON request: returns the parsed body (null for 204) or throws ApiError.
export async function request(method, path, body) {
  if (!getKey() && !String(path).endsWith("health")) throw new NoKeyError();
  const init = { method, headers: headers() };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let response;
  const sentAt = performance.now();
  try {
    response = await fetch(path.startsWith("/") ? path : `${API}/${path}`, init);
  } catch (cause) {
    throw offlineError(cause);
  }
  document.dispatchEvent(new CustomEvent("conforma:online", { detail: { sentAt } }));
  if (!response.ok) throw await errorFrom(response);
  if (response.status === 204) return null;
  const text = await response.text();
  return text ? JSON.parse(text) : null;
}

export const get = (path) => request("GET", path);
export const post = (path, body) => request("POST", path, body ?? {});
export const del = (path) => request("DELETE", path);
export const patch = (path, body) => request("PATCH", path, body ?? {});

// Multipart upload with progress (fetch() cannot report upload progress).
export function upload(path, formData, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", path.startsWith("/") ? path : `${API}/${path}`);
    for (const [k, v] of Object.entries(headers())) xhr.setRequestHeader(k, v);
    xhr.upload.onprogress = (e) => { if (e.lengthComputable && onProgress) onProgress(e.loaded / e.total); };
    xhr.onerror = () => reject(offlineError(new Error("upload failed")));
    const sentAt = performance.now();
    xhr.onload = async () => {
      if (xhr.status >= 200 && xhr.status < 300) {
        document.dispatchEvent(new CustomEvent("conforma:online", { detail: { sentAt } }));
        resolve(xhr.responseText ? JSON.parse(xhr.responseText) : null);
      } else {
        reject(await errorFrom(new Response(xhr.responseText, { status: xhr.status, statusText: xhr.statusText })));
      }
    };
    xhr.send(formData);
  });
}

// Download an authenticated file (artifacts, meshes) and hand it to the browser.
export async function download(path, filename) {
  let response;
  try { response = await fetch(path, { headers: headers({ Accept: "*/*" }) }); } catch (cause) { throw offlineError(cause); }
  if (!response.ok) throw await errorFrom(response);
  const blob = await response.blob();
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
  return blob;
}

// Server-Sent Events over fetch(): onEvent({event, data, id}) per event; returns an
// AbortController.  onEnd(error|null) when the stream ends (null: the server closed it).
export function streamEvents(path, onEvent, onEnd) {
  const controller = new AbortController();
  (async () => {
    let response;
    try {
      response = await fetch(path, { headers: headers({ Accept: "text/event-stream" }), signal: controller.signal });
    } catch (cause) {
      if (!controller.signal.aborted) onEnd?.(offlineError(cause));
      return;
    }
    if (!response.ok) { onEnd?.(await errorFrom(response)); return; }
    const reader = response.body.getReader();
    const decoder = new TextDecoder();
    let buffer = "";
    try {
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += decoder.decode(value, { stream: true }).replace(/\r\n/g, "\n");
        let cut;
        while ((cut = buffer.indexOf("\n\n")) >= 0) {
          const block = buffer.slice(0, cut);
          buffer = buffer.slice(cut + 2);
          const ev = { event: "message", data: "", id: null };
          for (const line of block.split("\n")) {
            if (line.startsWith(":")) continue;
            const [field, ...rest] = line.split(":");
            const val = rest.join(":").replace(/^ /, "");
            if (field === "event") ev.event = val;
            else if (field === "data") ev.data += (ev.data ? "\n" : "") + val;
            else if (field === "id") ev.id = val;
          }
          if (ev.data) {
            try { ev.data = JSON.parse(ev.data); } catch { /* plain text */ }
            onEvent(ev);
          }
        }
      }
      onEnd?.(null);
    } catch (cause) {
      if (!controller.signal.aborted) onEnd?.(offlineError(cause));
    }
  })();
  return controller;
}
