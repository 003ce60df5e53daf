// Jobs: submit from forms generated from the job kinds' schemas, follow progress live
// (Server-Sent Events over fetch with the key in the header), read results, download
// artifacts, cancel, open in 3D.
import { ApiError, download, get, post, streamEvents } from "./api.js";
import { schemaForm } from "./schema_form.js";
import { figuresTable, kindView } from "./results.js";
import { el, fmt, guarded, initPage, latest, markReady, query, showError, showInfo, viewerPanel } from "./ui.js";

const TERMINAL = new Set(["succeeded", "needs_attention", "failed", "cancelled"]);
const main = initPage("jobs.html");
const left = el("div");
const right = el("div");
const viewerSection = el("section", { id: "viewer-panel" });
const detail = el("section", { id: "job-detail" }, el("h2", {}, "Job"), el("p", { class: "small" }, "Select a job in the list."));
right.append(detail, viewerSection);
main.append(el("h1", {}, "Jobs"), el("div", { class: "layout" }, left, right));
const viewer = viewerPanel(viewerSection);

// ---- submission -----------------------------------------------------------------------
const kindSelect = el("select", { id: "job-kind", "aria-label": "job kind" });
const kindDescription = el("p", { class: "small", id: "kind-description" });
const formBody = el("div", { id: "job-form-body" });
const submitButton = el("button", { type: "submit", class: "primary", id: "submit-job" }, "Submit job");
const form = el("form", { id: "job-form", onsubmit: onSubmit }, formBody, submitButton);
left.append(el("section", {}, el("h2", {}, "New job"), kindSelect, kindDescription, form));
let kinds = [];
let current = null;

const JOB_SUGGESTIONS = { plan_job_id: "probe_plan", probe_run_job_id: "probe_run", reconstruct_job_id: "reconstruct",
  slice_job_id: "slice", surface_fit_job_id: "surface_fit", closed_loop_job_id: "closed_loop", scan_run_job_id: "scan_run" };

// Suggestions (datalists) for the id fields THIS kind's form has; only what it uses is fetched,
// all at once (one part's traces after another cost most of a second with 100 parts stored).
async function suggestions(kind) {
  const want = new Set(Object.keys(kind.params_schema?.properties || {}));
  const out = {};
  const jobKeys = Object.keys(JOB_SUGGESTIONS).filter((k) => want.has(k));
  if (want.has("material")) {  // a print's dispense profile by preset name
    const presets = await loadMaterials();
    out.material = presets.filter((m) => m.dispense).map((m) => [m.name, m.label]);
  }
  const [parts, jobs, machines, programs] = await Promise.all([
    want.has("part_id") || want.has("trace_id") ? get("parts?limit=50") : null,
    jobKeys.length ? get("jobs?limit=200") : null,
    want.has("machine_id") ? get("machines").catch(() => null) : null,
    want.has("program_id") ? get("programs?limit=200").catch(() => null) : null]);
  if (parts) out.part_id = parts.items.map((p) => [p.id, p.name]);
  if (parts && want.has("trace_id")) {
    const shown = parts.items.slice(0, 20);
    const traceLists = await Promise.all(shown.map((p) => get(`parts/${p.id}/traces?limit=200`)));
    out.trace_id = shown.flatMap((p, i) => traceLists[i].items.map((t) => [t.id, `${t.name}${t.source?.net ? ` · ${t.source.net}` : ""} on ${p.name}`]));
  }
  for (const key of jobKeys) {
    out[key] = jobs.items.filter((j) => j.kind === JOB_SUGGESTIONS[key] && j.status === "succeeded")
      .map((j) => [j.id, `${j.title || j.kind} · ${fmt.time(j.created_at)}`]);
  }
  if (machines) out.machine_id = machines.items.map((m) => [m.id, m.name]);
  if (programs) out.program_id = programs.items.map((p) => [p.id, `${p.name} (${p.lines} lines)`]);
  return out;
}

// Material presets (GET /materials): a picker fills the fields of the form that a preset sets
// (a paste's mode, line width, standoff and speed; a substrate plastic's temperatures).  A
// fresh form with a mode to choose starts from the default preset (a paste), never from a
// plastic printer's 210 °C nozzle / 60 °C bed.
let materials = null;
const loadMaterials = () => (materials ??= get("materials").catch(() => []));

function materialPicker(fields, presets, fresh) {
  const fits = (m) => Object.keys(m.params).filter((k) => fields.names.includes(k)).length >= 2;
  const usable = presets.filter(fits);
  if (!usable.length) return null;
  const select = el("select", { id: "material-preset", "aria-label": "material preset" },
    el("option", { value: "" }, "(as the fields say)"), usable.map((m) => el("option", { value: m.name, title: m.description }, m.label)));
  const note = el("span", { class: "small", id: "material-note" });
  const apply = (name) => {
    const preset = usable.find((m) => m.name === name);
    if (!preset) { note.textContent = ""; return; }
    const set = Object.entries(preset.params).filter(([k, v]) => fields.set(k, v)).map(([k]) => k);
    note.textContent = ` ${preset.description}; sets ${set.length} field${set.length === 1 ? "" : "s"}`;
  };
  select.addEventListener("change", () => apply(select.value));
  const start = fresh && fields.names.includes("mode") ? usable.find((m) => m.default) : null;
  if (start) { select.value = start.name; apply(start.name); }
  return el("div", { class: "field material-field" }, el("label", { for: "material-preset" }, "Material"), select, note);
}

async function buildForm(prefill = {}) {
  const kind = kinds.find((k) => k.name === kindSelect.value);
  if (!kind) return;
  kindDescription.textContent = kind.description || "";
  const [hints, presets] = await Promise.all([suggestions(kind).catch(() => ({})), loadMaterials()]);
  current = schemaForm(kind.params_schema, { suggestions: hints, prefill });
  const fresh = !Object.keys(prefill).some((k) => current.names.includes(k) && k !== "slice_job_id");
  const picker = materialPicker(current, presets, fresh);
  formBody.replaceChildren(...(picker ? [picker] : []), current.node);
  formBody.dataset.kind = kind.name;
}

async function loadKinds() {
  await guarded("Job kinds", async () => {
    kinds = await get("job-kinds");
    const wanted = query("kind");
    kindSelect.replaceChildren(...kinds.map((k) => el("option", { value: k.name, selected: k.name === wanted }, k.name)));
    filterKind.replaceChildren(el("option", { value: "" }, "any kind"), ...kinds.map((k) => el("option", { value: k.name }, k.name)));
    const prefill = Object.fromEntries([...new URLSearchParams(location.search)].filter(([k]) => k !== "kind"));
    await buildForm(prefill);
  });
}
kindSelect.addEventListener("change", () => { delete formBody.dataset.kind; buildForm(); });

async function onSubmit(event) {
  event.preventDefault();
  if (!current) return;
  let params;
  try {
    params = current.values();
  } catch (err) {
    current.markErrors(err.field ? [{ loc: `params.${err.field}`, msg: err.message }] : []);
    showError(err, "New job");
    return;
  }
  submitButton.disabled = true;
  try {
    const job = await post("jobs", { kind: kindSelect.value, params });
    current.markErrors([]);
    showInfo(`${job.kind.replaceAll("_", " ")} queued.`);
    await refresh();
    openJob(job.id);
  } catch (err) {
    if (err instanceof ApiError) current.markErrors(err.fieldErrors);
    showError(err, `Submitting ${kindSelect.value}`);
  } finally {
    submitButton.disabled = false;
  }
}

// ---- history: filters, paging and live progress ------------------------------------------
const PAGE_SIZE = 25;
const STATUSES = ["queued", "running", "succeeded", "needs_attention", "failed", "cancelled", "interrupted", "waiting"];
const tbody = el("tbody", { id: "jobs-body" });
const filterKind = el("select", { id: "filter-kind", "aria-label": "filter by kind" }, el("option", { value: "" }, "any kind"));
const filterStatus = el("select", { id: "filter-status", "aria-label": "filter by status" },
  el("option", { value: "" }, "any status"), STATUSES.map((st) => el("option", { value: st }, st)));
const filterPart = el("select", { id: "filter-part", "aria-label": "filter by part" }, el("option", { value: "" }, "any part"));
const filterMachine = el("select", { id: "filter-machine", "aria-label": "filter by machine" }, el("option", { value: "" }, "any machine"));
const filterAfter = el("input", { type: "date", id: "filter-after", "aria-label": "created on or after" });
const filterBefore = el("input", { type: "date", id: "filter-before", "aria-label": "created before" });
const filterTop = el("input", { type: "checkbox", id: "filter-top", checked: true });
const pageInfo = el("span", { id: "page-info", class: "small" });
const prevButton = el("button", { type: "button", id: "page-prev", onclick: () => { offset = Math.max(0, offset - PAGE_SIZE); refresh(); } }, "← newer");
const nextButton = el("button", { type: "button", id: "page-next", onclick: () => { offset += PAGE_SIZE; refresh(); } }, "older →");
let offset = 0;
for (const control of [filterKind, filterStatus, filterPart, filterMachine, filterAfter, filterBefore, filterTop]) {
  control.addEventListener("change", () => { offset = 0; refresh(); });
}
left.append(el("section", {}, el("h2", {}, "History ", el("button", { onclick: () => refresh(), class: "small" }, "Refresh")),
  el("div", { class: "filters", role: "group", "aria-label": "job filters" }, filterKind, filterStatus, filterPart, filterMachine,
    el("label", {}, "from ", filterAfter), el("label", {}, "before ", filterBefore),
    el("label", {}, filterTop, " hide workflow steps")),
  el("table", { id: "jobs-table" }, el("thead", {}, el("tr", {}, ["Job", "Status", "Progress", "Message"].map((h) => el("th", { scope: "col" }, h)))), tbody),
  el("div", { class: "row pager" }, prevButton, pageInfo, nextButton)));
const streams = new Map();
let selected = null;

function historyQuery() {
  const q = new URLSearchParams({ limit: PAGE_SIZE, offset });
  if (filterKind.value) q.set("kind", filterKind.value);
  if (filterStatus.value) q.set("status", filterStatus.value);
  if (filterPart.value) q.set("part_id", filterPart.value);
  if (filterMachine.value) q.set("machine_id", filterMachine.value);
  if (filterAfter.value) q.set("created_after", new Date(`${filterAfter.value}T00:00:00`).toISOString());
  if (filterBefore.value) q.set("created_before", new Date(`${filterBefore.value}T00:00:00`).toISOString());
  if (filterTop.checked) q.set("top_level", "true");
  return q.toString();
}

async function loadFilterChoices() {
  await guarded("Filters", async () => {
    const [parts, machines] = await Promise.all([get("parts?limit=200"), get("machines").catch(() => ({ items: [] }))]);
    filterPart.replaceChildren(el("option", { value: "" }, "any part"), ...parts.items.map((p) => el("option", { value: p.id }, p.name)));
    filterMachine.replaceChildren(el("option", { value: "" }, "any machine"), ...machines.items.map((m) => el("option", { value: m.id }, m.name)));
    if (query("part_id")) filterPart.value = query("part_id");
    if (query("machine_id")) filterMachine.value = query("machine_id");
  });
}

function statusCell(job) {
  return el("span", { class: `badge ${job.status}`, "data-status": job.status }, job.status.replace("_", " "));
}

function row(job) {
  return el("tr", { "data-id": job.id, onclick: () => openJob(job.id), class: "clickable" },
    el("td", { title: job.id }, el("strong", {}, job.title || job.kind), job.title ? el("div", { class: "small" }, job.kind) : null),
    el("td", { class: "status" }, statusCell(job)),
    el("td", {}, el("progress", { max: 1, value: job.progress })),
    el("td", { class: "small message" }, job.message || (job.error ? job.error.detail : "")));
}

function updateRow(job) {
  const tr = tbody.querySelector(`tr[data-id="${job.id}"]`);
  if (!tr) return;
  tr.querySelector(".status").replaceChildren(statusCell(job));
  tr.querySelector("progress").value = job.progress;
  tr.querySelector(".message").textContent = job.message || "";
}

function follow(job) {
  if (TERMINAL.has(job.status) || streams.has(job.id)) return;
  const ctrl = streamEvents(`/api/v1/jobs/${job.id}/events`, (ev) => {
    updateRow(ev.data);
    if (selected === job.id) renderProgress(ev.data);
  }, async (err) => {
    streams.delete(job.id);
    if (err) { showError(err, `Live progress of ${job.id}`); return; }
    await guarded("Jobs", async () => {
      const fresh = await get(`jobs/${job.id}?include=result&include=artifacts&include=params`);
      updateRow(fresh);
      if (selected === job.id) renderDetail(fresh);
    });
  });
  streams.set(job.id, ctrl);
}

const historyLatest = latest();  // filters changed quickly: only the newest query's answer is shown

async function refresh() {
  const isLatest = historyLatest();
  await guarded("Jobs", async () => {
    const page = await get(`jobs?${historyQuery()}`);
    if (!isLatest()) return;
    tbody.replaceChildren(...page.items.map(row));
    if (!page.items.length) tbody.append(el("tr", {}, el("td", { colspan: 4, class: "small" }, offset ? "No older jobs." : "No jobs match.")));
    const last = Math.min(offset + page.items.length, page.total);
    pageInfo.textContent = page.total ? `${offset + 1}–${last} of ${page.total}` : "0 jobs";
    prevButton.disabled = offset === 0;
    nextButton.disabled = last >= page.total;
    page.items.forEach(follow);
    if (selected) tbody.querySelector(`tr[data-id="${selected}"]`)?.classList.add("selected");
  });
}

// ---- detail ------------------------------------------------------------------------------
function compact(value) {
  return JSON.stringify(value, (k, v) => (Array.isArray(v) && v.length > 12 ? [...v.slice(0, 6), `… ${v.length - 6} more`] : v), 2);
}

function renderProgress(ev) {
  const bar = detail.querySelector("#detail-progress");
  if (bar) bar.value = ev.progress;
  const st = detail.querySelector("#detail-status");
  if (st) st.replaceChildren(statusCell(ev), ` ${ev.message || ""}`);
}

// Deviation samples [[s_mm, dz_mm], ...] as an SVG line plot (data kept on the node).
function deviationPlot(samples, title) {
  const w = 600, h = 180, pad = 30;
  const xs = samples.map((p) => p[0]); const ys = samples.map((p) => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), ylim = Math.max(1e-6, ...ys.map(Math.abs));
  const X = (x) => pad + ((x - x0) / Math.max(x1 - x0, 1e-9)) * (w - 2 * pad);
  const Y = (y) => h / 2 - (y / ylim) * (h / 2 - pad / 2);
  const ns = "http://www.w3.org/2000/svg";
  const svg = document.createElementNS(ns, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  const mk = (tag, attrs, text) => { const n = document.createElementNS(ns, tag); for (const [k, v] of Object.entries(attrs)) n.setAttribute(k, v); if (text) n.textContent = text; svg.append(n); return n; };
  mk("line", { x1: pad, x2: w - pad, y1: h / 2, y2: h / 2, stroke: "#999", "stroke-dasharray": "4 3" });
  mk("polyline", { points: samples.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" "), fill: "none", stroke: "#d33", "stroke-width": 2 });
  mk("text", { x: pad, y: 14, "font-size": 12 }, `${title}  (±${ylim.toFixed(4)} mm)`);
  mk("text", { x: w - pad, y: h - 4, "font-size": 11, "text-anchor": "end" }, `${x1.toFixed(1)} mm along the trace`);
  return el("div", { class: "plot", id: "deviation-plot", "data-samples": JSON.stringify(samples) }, svg);
}

// A machine job that stopped on a dropped link or a dead server waits for the operator:
// resume (re-homes, then continues from the first command not known executed) or abandon.
function interruptedPanel(job) {
  const st = job.program_state || {};
  const where = `stopped at command ${st.executed ?? "?"} of ${st.total ?? "?"}` +
    (st.acked_line_no != null ? ` (firmware line ${st.acked_line_no} acknowledged)` : "") +
    (st.position ? `, position ${st.position.map((v) => Number(v).toFixed(3)).join(", ")}` : ", position unknown");
  return el("div", { class: "msg error", id: "interrupted" },
    el("p", {}, `Interrupted: ${where}. ${st.reason || ""}`),
    el("div", { class: "row" },
      el("button", { id: "resume-job", onclick: () => guarded("Resume", async () => {
        if (!window.confirm("Resume: the machine re-homes and moves. Is it clear?")) return;
        renderDetail(await post(`jobs/${job.id}/resume`, { confirm: true })); follow(job);
      }) }, "Resume (re-homes)"),
      el("button", { class: "danger", id: "abandon-job", onclick: () => guarded("Abandon", async () => {
        renderDetail(await post(`jobs/${job.id}/abandon`));
      }) }, "Abandon")));
}

function renderDetail(job) {
  const canCancel = !TERMINAL.has(job.status);
  const parts = [
    el("h2", { title: job.id }, job.title || tbody.querySelector(`tr[data-id="${job.id}"] strong`)?.textContent || job.kind),
    el("div", { id: "detail-status" }, statusCell(job), ` ${job.message || ""}`),
    el("progress", { id: "detail-progress", max: 1, value: job.progress }),
    el("div", { class: "row" },
      el("button", { id: "open-3d", onclick: () => viewer.show({ job_id: job.id }) }, "Open in 3D"),
      canCancel ? el("button", { class: "danger", id: "cancel-job", onclick: () => guarded("Cancel", async () => {
        renderDetail(await post(`jobs/${job.id}/cancel`)); showInfo(`Cancel requested for ${job.id}.`);
      }) }, "Cancel") : null,
      el("button", { id: "rerun-job", onclick: () => rerun(job) }, "Run again"),
      el("button", { id: "edit-rerun", onclick: () => editCopy(job) }, "Edit a copy")),
    el("p", { class: "small" }, `created ${fmt.time(job.created_at)} · started ${fmt.time(job.started_at)} · finished ${fmt.time(job.finished_at)}`),
  ];
  if (job.status === "interrupted") parts.push(interruptedPanel(job));
  if (job.status === "waiting") {
    parts.push(el("div", { class: "msg", id: "waiting" }, `${job.message || "waiting for an operator"} — `,
      el("a", { href: `loop.html?job=${job.id}` }, "continue, accept, add stations or abandon it on the Closed loop page")));
  }
  if (job.error) parts.push(el("div", { class: "msg error", id: "job-error" }, `${job.error.title}: ${job.error.detail}`));
  if (job.earlier_attempts?.length) {  // a job run again is never run again silently
    parts.push(el("div", { class: "msg", id: "earlier-attempts" }, `Run ${job.attempts} times: `,
      job.earlier_attempts.map((a) => `attempt ${a.attempt} ended ${fmt.time(a.ended_at)}: ${a.reason}`).join("; ")));
  }
  const samples = job.result?.deviation?.samples;
  if (Array.isArray(samples) && samples.length > 1) {
    parts.push(el("h3", {}, "Deviation along the trace"),
      el("p", { class: "small" }, `max ${fmt.mm(job.result.deviation.max_mm, 4)}, rms ${fmt.mm(job.result.deviation.rms_mm, 4)}`),
      deviationPlot(samples, "measured − nominal"));
  }
  if (job.artifacts?.length) {
    parts.push(el("h3", {}, "Artifacts"), el("ul", { id: "artifacts" }, job.artifacts.map((a) => el("li", {},
      el("button", { class: "artifact", onclick: () => guarded("Download", () => download(a.url, a.name)) }, a.name),
      ` ${a.media_type}, ${fmt.bytes(a.bytes)}`))));
  }
  parts.push(el("details", {}, el("summary", {}, "Parameters"), el("pre", {}, compact(job.params))));
  if (job.result) {
    const figures = figuresTable(job.result);
    if (figures) parts.push(el("h3", {}, "Result"), figures);
    parts.push(...kindView(job));
    parts.push(el("details", {}, el("summary", {}, "Raw result (JSON)"), el("pre", { id: "job-result" }, compact(job.result))));
  }
  detail.replaceChildren(...parts);
  detail.dataset.jobId = job.id;
  detail.dataset.status = job.status;
}

// A job's parameters whole (a record in brief leaves long ones out: params_omitted names them).
const allParams = async (job) => (job.params_omitted ? (await get(`jobs/${job.id}?include=params`)).params : job.params);

// Run a job again with exactly its parameters (a machine job asks first: it moves a machine).
async function rerun(job) {
  const moves = ["print", "probe_run", "register", "closed_loop", "calibrate_probe", "calibrate_nozzle", "scan_run",
    "calibrate_sensor"].includes(job.kind);
  if (moves && !window.confirm(`Run ${job.kind} again? It will move the machine.`)) return;
  await guarded("Run again", async () => {
    const copy = await post("jobs", { kind: job.kind, params: await allParams(job) });
    showInfo(`${copy.kind.replaceAll("_", " ")} queued again with the same parameters.`);
    await refresh();
    openJob(copy.id);
  });
}

// Fill the submission form with this job's parameters, to change some before submitting.
async function editCopy(job) {
  kindSelect.value = job.kind;
  await buildForm(await allParams(job));
  kindSelect.scrollIntoView({ behavior: "smooth", block: "start" });
}

async function openJob(jobId) {
  selected = jobId;
  tbody.querySelectorAll("tr.selected").forEach((r) => r.classList.remove("selected"));
  tbody.querySelector(`tr[data-id="${jobId}"]`)?.classList.add("selected");
  await guarded(`Job ${jobId}`, async () => {
    const job = await get(`jobs/${jobId}?include=result&include=artifacts&include=params`);
    renderDetail(job);
    follow(job);
  });
}

// The form (job kinds + suggestions) and the history (filters, then the page of jobs the
// filters select) load side by side: one after the other they cost twice the time.
const loadAll = () => Promise.all([loadKinds(), loadFilterChoices().then(refresh)]);
document.addEventListener("conforma:key", loadAll);
await loadAll();
if (query("job")) await openJob(query("job"));
markReady();
