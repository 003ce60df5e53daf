// Shared page furniture: navigation, the API key box, the connection indicator, the
// message area and the embedded 3D view.
import { ApiError, get, getKey, post, setKey, verifyKey } from "./api.js";

const PAGES = [
  ["index.html", "Home"], ["loop.html", "Closed loop"], ["parts.html", "Parts"], ["traces.html", "Traces"],
  ["jobs.html", "Jobs"], ["programs.html", "Programs"], ["machines.html", "Machines"],
];

// el("div", {class: "x", onclick: f}, child, "text", ...)
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else if (k === "dataset") Object.assign(node.dataset, v);
    else node.setAttribute(k, v === true ? "" : String(v));
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export const fmt = {
  mm: (v, d = 3) => (v === null || v === undefined ? "—" : `${Number(v).toFixed(d)} mm`),
  num: (v, d = 3) => (v === null || v === undefined ? "—" : Number(v).toFixed(d)),
  time: (iso) => (iso ? new Date(iso).toLocaleString() : "—"),
  bytes: (n) => (n < 1024 ? `${n} B` : n < 2 ** 20 ? `${(n / 1024).toFixed(1)} KiB` : `${(n / 2 ** 20).toFixed(1)} MiB`),
};

// ---- messages ---------------------------------------------------------------------
function messageArea() {
  return document.getElementById("messages");
}

// Show an error (ApiError or any Error) as a readable, dismissable message.  The same
// message is shown once; it goes away by itself after ERROR_TTL_MS unless it names
// fields to fix; a missing key is not an error (the key box says what to do).
const ERROR_TTL_MS = 20000;

export function showError(err, context = "") {
  const area = messageArea();
  if (err?.noKey) return null;
  const text = err instanceof ApiError ? err.message : `${err?.message || err}`;
  const signature = `${context}|${text}`;
  for (const old of area.querySelectorAll(".msg.error")) if (old.dataset.signature === signature) old.remove();
  const box = el("div", { class: `msg error${err?.offline ? " offline" : ""}`, role: "alert", dataset: { signature } },
    el("button", { class: "close", title: "dismiss", onclick: () => box.remove() }, "×"),
    el("strong", {}, context ? `${context}: ` : ""), text);
  if (err instanceof ApiError && err.fieldErrors.length) {
    box.append(el("ul", { class: "field-errors" },
      err.fieldErrors.map((e) => el("li", {}, el("code", {}, e.loc || "request"), ` ${e.msg}`))));
  }
  area.prepend(box);
  while (area.children.length > 4) area.lastChild.remove();
  if (!(err instanceof ApiError && err.fieldErrors.length)) setTimeout(() => box.remove(), ERROR_TTL_MS);
  return box;
}

export function showInfo(text, timeoutMs = 5000) {
  const box = el("div", { class: "msg info", role: "status" }, text);
  messageArea().prepend(box);
  if (timeoutMs) setTimeout(() => box.remove(), timeoutMs);
  return box;
}

export function clearMessages() {
  messageArea().replaceChildren();
}

// Run an async action, showing its error instead of breaking the page.
export async function guarded(context, fn) {
  try {
    return await fn();
  } catch (err) {
    showError(err, context);
    return undefined;
  }
}

// ---- header: navigation, key, connection --------------------------------------------
function header(active) {
  const keyInput = el("input", { type: "password", id: "api-key", placeholder: "paste your API key",
    autocomplete: "off", value: getKey(), "aria-label": "API key" });
  const form = el("form", { id: "key-form", onsubmit: async (e) => {
    e.preventDefault();
    const key = keyInput.value.trim();
    if (key) {
      try {
        await verifyKey(key);
      } catch (err) {
        showError(err, "API key not saved");
        return;
      }
    }
    for (const box of messageArea().querySelectorAll(".msg")) if (/API key/.test(box.textContent)) box.remove();
    setKey(key);
    showInfo(key ? "API key checked and saved in this browser." : "API key removed.");
  } }, keyInput, el("button", { type: "submit" }, "Save key"));
  const status = el("span", { id: "conn", class: "conn unknown", title: "API connection" }, "…");
  const stop = el("button", { type: "button", id: "stop-all", class: "stop-all",
    title: "Emergency stop every connected machine (keyboard: Alt+S)", onclick: stopAll }, "STOP ALL");
  return el("header", {},
    el("a", { class: "brand", href: "index.html" }, "Conforma"),
    el("nav", {}, PAGES.map(([href, label]) =>
      el("a", { href, class: href === active ? "active" : null }, label))),
    form, status, stop);
}

// ---- the global emergency stop --------------------------------------------------------
// The machines are listed every few seconds, so a click sends the stops at once (no list
// request first); the list is then re-read and any machine not yet stopped gets one too.
let knownMachines = [];

async function listMachines() {
  try { knownMachines = (await get("machines")).items.map((m) => m.id); } catch { /* shown elsewhere */ }
  return knownMachines;
}

export async function stopAll() {
  const sent = new Set(knownMachines);
  const stops = knownMachines.map((id) => post(`machines/${id}/stop`).then(() => id, (err) => ({ id, err })));
  const later = (await listMachines()).filter((id) => !sent.has(id));
  stops.push(...later.map((id) => post(`machines/${id}/stop`).then(() => id, (err) => ({ id, err }))));
  const results = await Promise.all(stops);
  const failed = results.filter((r) => typeof r !== "string");
  if (!results.length) showInfo("No machine is registered: nothing to stop.");
  else if (failed.length) failed.forEach((f) => showError(f.err, `STOP ${f.id}`));
  else showInfo(`Emergency stop sent to ${results.length} machine(s). Home and check each machine before resuming.`, 15000);
  document.dispatchEvent(new CustomEvent("conforma:stopped"));
}

function setConnection(state, text) {
  const node = document.getElementById("conn");
  if (!node) return;
  node.className = `conn ${state}`;
  node.textContent = text;
  document.body.classList.toggle("is-offline", state === "offline");
}

// When a request last found the API unreachable (performance.now() ms).  An answer to a
// request (or a health check) sent before that says nothing about now: it does not show the
// API online again (the next one sent, at most a second later, tells).
let lastOfflineAt = -Infinity;

// Poll the health endpoint: every 5 s, every second while the API is unreachable.
async function checkHealth() {
  let offline = false;
  const sentAt = performance.now();
  try {
    const r = await fetch("/api/v1/health", { cache: "no-store" });
    if (sentAt < lastOfflineAt) offline = true;
    else if (r.ok) setConnection("online", "API online");
    else setConnection("degraded", `API error ${r.status}`);
  } catch {
    offline = true;
    setConnection("offline", "API unreachable");
  }
  setTimeout(checkHealth, offline || document.body.classList.contains("is-offline") ? 1000 : 5000);
}

// Build the common page frame; returns the <main> element to fill.
export function initPage(active) {
  document.body.prepend(header(active));
  const banner = el("div", { id: "offline-banner", role: "alert" },
    "Connection to the Conforma API lost — retrying. Actions are paused until it is back.");
  document.body.insertBefore(banner, document.querySelector("main"));
  document.addEventListener("conforma:offline", () => {
    lastOfflineAt = performance.now();
    setConnection("offline", "API unreachable");
  });
  document.addEventListener("conforma:online", (e) => {
    if (e.detail.sentAt >= lastOfflineAt) setConnection("online", "API online");
  });
  checkHealth();
  document.addEventListener("keydown", (e) => { if (e.altKey && (e.key === "s" || e.key === "S")) { e.preventDefault(); stopAll(); } });
  listMachines();
  setInterval(listMachines, 5000);
  document.addEventListener("conforma:key", listMachines);
  if (!getKey()) {
    showInfo("Paste your API key in the box at the top (`make run` printed one at the first start), then Save key.", 0);
    setTimeout(() => document.getElementById("api-key")?.focus(), 0);
  }
  return document.querySelector("main");
}

// Mark the page as loaded with its first data (used by tests and the load benchmark).
export function markReady() {
  // the mark's startTime is ms since this navigation began: what the page-load budget reads
  if (!performance.getEntriesByName("conforma:ready").length) performance.mark("conforma:ready");
  document.body.dataset.ready = "1";
}

// A query repeated while its answer is on the way (a filter or a choice changed quickly) may
// be answered out of order; only the newest answer may be shown. `const isLatest = latest();`
// once, then per query `const current = isLatest();` and after the await `if (!current()) return;`.
export function latest() {
  let newest = 0;
  return () => {
    const mine = ++newest;
    return () => mine === newest;
  };
}

export function query(name) {
  return new URLSearchParams(location.search).get(name);
}

// ---- the embedded 3D view -----------------------------------------------------------
let viewerInfo = null;

// Fill `container` with the 3D view panel; returns {show({part_id}|{job_id})}.
export function viewerPanel(container) {
  const frameBox = el("div", { class: "viewer-frame" });
  const caption = el("div", { class: "viewer-caption", id: "viewer-caption" }, "Open a part or a job to see it in 3D.");
  const previewBox = el("div", { class: "preview-panel", id: "preview-panel" });
  container.append(el("h2", {}, "3D view"), caption, frameBox, previewBox);

  let viewId = null;

  // The view needs a short-lived token from the API (any key may view); the token rides in
  // the websocket URL that viser's client opens (?websocket=...), and names this page's
  // own view, whose focus no other page changes.
  async function ensureFrame() {
    if (!viewerInfo) viewerInfo = await get("viewer");
    if (!viewerInfo.enabled) {
      caption.textContent = "The 3D view is off on this server (start it without --no-viewer).";
      return false;
    }
    if (!frameBox.querySelector("iframe")) {
      const grant = await post("viewer/token", viewId ? { view_id: viewId } : {});
      viewId = grant.view_id;
      container.dataset.view = viewId;
      const origin = `${location.protocol}//${location.hostname}:${grant.port}`;
      const ws = `${location.protocol === "https:" ? "wss:" : "ws:"}//${location.hostname}:${grant.port}/?token=${encodeURIComponent(grant.token)}`;
      const src = `${origin}/?websocket=${encodeURIComponent(ws)}`;
      frameBox.append(el("iframe", { id: "viewer-iframe", src, title: "3D view", loading: "eager" }));
      frameBox.append(el("a", { href: src, target: "_blank", rel: "noopener noreferrer", class: "small" },
        "open the 3D view in its own tab"));
    }
    return true;
  }

  async function show(target) {
    if (!(await ensureFrame())) return null;
    const scene = await post("viewer/focus", { ...target, view_id: viewId });
    const nodes = Object.values(scene.nodes || {});
    const plots = Object.keys(scene.plots || {}).length;
    caption.textContent = `Showing ${target.job_id ? `job ${target.job_id}` : `part ${target.part_id}`}: ` +
      `${nodes.length} scene nodes` + (plots ? `, ${plots} deviation plot(s) in the side panel` : "") +
      ((scene.notes || []).length ? ` — ${scene.notes.join("; ")}` : "");
    container.dataset.generation = scene.generation;
    await showPreview(scene);
    return scene;
  }

  // A program's preview (slider, legend, layers) is loaded only when a scene has one.
  async function showPreview(scene) {
    if (!Object.keys(scene.previews || {}).length) { previewBox.replaceChildren(); return; }
    const { renderPreview } = await import("./preview_panel.js");
    renderPreview(previewBox, scene, (layer) => post("viewer/layer", { view_id: viewId, layer }));
  }

  // Draw a machine's head where it is now (the view should show the program it prints).
  async function head(machineId) {
    if (!viewId) return null;
    return post("viewer/head", { view_id: viewId, machine_id: machineId });
  }

  return { show: (target) => guarded("3D view", () => show(target)), ensureFrame, head };
}
