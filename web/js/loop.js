// The closed-loop wizard: a VIEW of one server-side `closed_loop` job.  Part -> traces ->
// machine -> start: ONE job, paused by the server at every point where the operator decides
// (plan reviewed before anything moves, touches made, traces verified, before printing).
// The page only shows that job and sends the operator's decisions (continue, accept, add
// stations, resume, abandon); reload it, open it in another browser: the same run, at the
// same step.  Nothing moves a machine without a click and a confirmation.
import { download, get, post } from "./api.js";
import { length } from "./results.js";
import { el, guarded, initPage, latest, markReady, query, showInfo, viewerPanel } from "./ui.js";

const main = initPage("loop.html");
const FINISHED = new Set(["succeeded", "needs_attention", "failed", "cancelled"]);
const LIVE = ["waiting", "interrupted", "running", "queued"];  // a loop in these states is "the run"
const PAUSES = ["plan", "probed", "verified", "print"];        // the console stops at every one
const POLL_MS = 1000;
const STEP_OF = { plan: "wz-4", probed: "wz-5", verified: "wz-6", print: "wz-7" };
// traces: the part's printable traces; rings: its circuit imports' pad / area probe rings
// (traces with source.role "pad_probe"), probed with the import's traces, never printed.
const state = { part: null, traces: [], rings: [], machine: null, loop: null, names: {} };

function step(id, title, ...body) {
  return el("section", { id, class: "wizard-step", "data-done": "0", "aria-labelledby": `${id}-h` },
    el("h2", { id: `${id}-h` }, title), ...body);
}

const partSelect = el("select", { id: "wz-part", "aria-label": "part" });
const traceList = el("div", { id: "wz-traces", role: "group", "aria-label": "traces to print" });
const ringNote = el("p", { id: "wz-pad-rings", class: "small", "data-rings": "0" });
const machineSelect = el("select", { id: "wz-machine", "aria-label": "machine" });
const machineState = el("span", { id: "wz-machine-state", class: "small" });
const runBox = el("div", { id: "wz-run", "data-status": "", "data-step": "" });
const stepOut = { plan: el("div", { id: "wz-plan-out" }), probed: el("div", { id: "wz-probe-out" }),
  verified: el("div", { id: "wz-review-out" }), print: el("div", { id: "wz-print-out" }) };
const reportOut = el("div", { id: "wz-report-out" });
const childrenOut = el("div", { id: "wz-children" });
const buttons = {
  connect: el("button", { id: "wz-connect", type: "button", onclick: () => connect() }, "Connect"),
  start: el("button", { id: "wz-start", class: "primary", type: "button", onclick: () => start() }, "Start the loop"),
};
const viewerSection = el("section", { id: "viewer-panel" });
main.append(el("h1", {}, "Closed loop"),
  el("p", { class: "small" }, "Probe the real part, rebuild each trace on its real surface and print at the standoff above it. ",
    "The loop runs on the server: close this page and open it anywhere, the run is still there. ",
    "It waits for you before probing, after probing, after verifying and before printing; the machine moves only at “Probe” and “Print”."),
  el("div", { class: "layout" },
    el("div", {},
      step("wz-1", "1 · Part", partSelect),
      step("wz-2", "2 · Traces", traceList, ringNote),
      step("wz-3", "3 · Machine", machineSelect, " ", buttons.connect, " ", machineState),
      step("wz-run-step", "Run", el("p", { class: "small" }, "One job on the server: its plan is shown before anything moves."),
        buttons.start, runBox),
      step("wz-4", "4 · Plan", stepOut.plan),
      step("wz-5", "5 · Probe", stepOut.probed),
      step("wz-6", "6 · Review", stepOut.verified),
      step("wz-7", "7 · Print", stepOut.print),
      step("wz-8", "8 · Report", reportOut),
      el("details", { id: "wz-children-box" }, el("summary", {}, "The loop's steps (child jobs)"), childrenOut)),
    viewerSection));
const viewer = viewerPanel(viewerSection);

const done = (id, yes = true) => { document.getElementById(id).dataset.done = yes ? "1" : "0"; };

// ---- 1-3: part, traces, machine ------------------------------------------------------------
async function loadParts() {
  const parts = (await get("parts?limit=200")).items;
  partSelect.replaceChildren(el("option", { value: "" }, "choose a part…"), ...parts.map((p) => el("option", { value: p.id }, p.name)));
}

const isRing = (t) => (t.source || {}).role === "pad_probe";
const tracesLatest = latest();  // the part changed quickly: never the traces of a part no longer chosen

async function loadTraces(checked = null) {
  const current = tracesLatest();
  const part = partSelect.value || null;
  const all = part ? (await get(`parts/${part}/traces?limit=1000`)).items : [];
  if (!current()) return;
  state.part = part;
  state.traces = all.filter((t) => !isRing(t));
  state.rings = all.filter(isRing);
  const named = (t) => (t.source?.net && !t.name.includes(t.source.net) ? `${t.name} · ${t.source.net}` : t.name);
  state.names = Object.fromEntries(all.map((t) => [t.id, named(t)]));
  traceList.replaceChildren(...(state.traces.length ? state.traces.map((t) => el("label", { class: "inline" },
    el("input", { type: "checkbox", value: t.id, checked: checked ? checked.includes(t.id) : true }), ` ${named(t)} (${length(t.length_mm)})`))
    : [el("p", { class: "small" }, state.part ? "This part has no traces: add some on the Traces page." : "Choose a part first.")]));
  showRings();
  if (state.part) { done("wz-1"); if (!state.loop) viewer.show({ part_id: state.part }); }
  if (state.traces.length) done("wz-2");
}

// The pad / area probe rings of the circuit imports the chosen traces come from: probed with
// them (so that the pads are measured where they will be filled), never printed.
function padRings() {
  const imports = new Set(chosenTraces().map((id) => state.traces.find((t) => t.id === id))
    .map((t) => (t?.source || {}).import_id).filter(Boolean));
  return state.rings.filter((r) => imports.has(r.source.import_id));
}

function showRings() {
  const rings = padRings();
  ringNote.dataset.rings = String(rings.length);
  ringNote.textContent = rings.length
    ? `+ ${rings.length} pad probe ring(s) of the imported circuit, probed with these traces (not printed): `
      + rings.map((r) => r.source.pad || r.name).join(", ")
    : "";
}
traceList.addEventListener("change", showRings);

async function loadMachines() {
  const machines = (await get("machines")).items;
  machineSelect.replaceChildren(el("option", { value: "" }, "choose a machine…"),
    ...machines.map((m) => el("option", { value: m.id, "data-state": m.state }, `${m.name} (${m.state})`)));
}

async function showMachine() {
  state.machine = machineSelect.value || null;
  if (!state.machine) { machineState.textContent = ""; return; }
  const m = await get(`machines/${state.machine}`);
  machineState.textContent = `${m.state}${m.firmware ? ` · ${m.firmware}` : ""}`;
  if (machineSelect.selectedOptions[0]) machineSelect.selectedOptions[0].textContent = `${m.name} (${m.state})`;
  machineState.dataset.state = m.state;
  buttons.connect.disabled = m.state !== "disconnected" || Boolean(state.loop && !FINISHED.has(state.loop.status));
  if (m.state !== "disconnected") done("wz-3");
}

async function connect() {
  await guarded("Connect", async () => {
    await post(`machines/${state.machine}/connect`);
    await showMachine();
  });
}

const chosenTraces = () => [...traceList.querySelectorAll("input:checked")].map((i) => i.value);

// ---- the run: one closed_loop job ------------------------------------------------------------
async function start() {
  await guarded("Start", async () => {
    const traceIds = chosenTraces();
    if (!traceIds.length) throw new Error("choose at least one trace");
    if (!state.machine) throw new Error("choose a machine");
    buttons.start.disabled = true;
    const job = await post("jobs", { kind: "closed_loop", params: {
      part_id: state.part, trace_ids: [...traceIds, ...padRings().map((r) => r.id)], machine_id: state.machine,
      joint_probing: true, sequential: false, print: true, pause_at: PAUSES } });
    history.replaceState(null, "", `?job=${job.id}`);
    await follow(job.id);
  });
  buttons.start.disabled = Boolean(state.loop && !FINISHED.has(state.loop.status));
}

// The loop this page shows: ?job=<id>, else the newest one still live (waiting, interrupted,
// running or queued), whoever started it.
async function findLoop() {
  const asked = query("job");
  if (asked) return asked;
  for (const status of LIVE) {
    const page = await get(`jobs?kind=closed_loop&status=${status}&limit=1`);
    if (page.items.length) return page.items[0].id;
  }
  return null;
}

let polling = null;
async function follow(jobId) {
  await refresh(jobId);
  if (polling) clearTimeout(polling);
  const tick = async () => {
    if (state.loop && FINISHED.has(state.loop.status)) return;
    await guarded("Loop", () => refresh(jobId));
    polling = setTimeout(tick, POLL_MS);
  };
  polling = setTimeout(tick, POLL_MS);
}

let shownRevision = "";
// the loop's parameters whole, read once per loop: a board's trace_ids are left out of a poll
const fullParams = { id: null, params: null };
async function refresh(jobId) {
  const job = await get(`jobs/${jobId}?include=result`);
  if (job.params_omitted) {
    if (fullParams.id !== jobId) Object.assign(fullParams, { id: jobId, params: (await get(`jobs/${jobId}?include=params`)).params });
    job.params = fullParams.params;
  }
  const kids = (await get(`jobs?parent_id=${jobId}&limit=500`)).items;
  const signature = `${job.status}|${job.message}|${kids.map((k) => k.status).join(",")}`;
  state.loop = job;
  if (signature === shownRevision) return;
  shownRevision = signature;
  await showSetup(job);
  render(job, kids);
}

// the setup the loop was started with, read back (another browser shows the same)
async function showSetup(job) {
  const p = job.params;
  if (partSelect.value !== p.part_id) { partSelect.value = p.part_id; await loadTraces(p.trace_ids); }
  if (machineSelect.value !== p.machine_id) { machineSelect.value = p.machine_id; await showMachine(); }
  const live = !FINISHED.has(job.status);
  for (const input of [partSelect, machineSelect, ...traceList.querySelectorAll("input")]) input.disabled = live;
  buttons.start.disabled = live;
}

function action(id, label, path, confirmText, body) {
  return el("button", { id, type: "button", class: id === "wz-abandon" ? "" : "primary", onclick: () => guarded(label, async () => {
    if (confirmText && !window.confirm(confirmText)) return;
    for (const b of runBox.querySelectorAll("button")) b.disabled = true;
    await post(`jobs/${state.loop.id}/${path}`, body);
    shownRevision = "";
    await follow(state.loop.id);
  }) }, label);
}

function render(job, kids) {
  const ps = job.program_state || {};
  const waiting = job.status === "waiting" ? ps.waiting || {} : null;
  runBox.dataset.status = job.status;
  runBox.dataset.step = waiting ? waiting.at : "";
  runBox.dataset.job = job.id;
  const head = el("p", { id: "wz-run-status" }, el("span", { class: `badge ${job.status}` }, job.status),
    " ", el("span", { title: job.id }, "closed loop"), ` · ${job.message || ""}`);
  const actions = el("div", { id: "wz-actions" });
  const passed = new Set((ps.passed || []).map((k) => k.split("@")[0]));
  for (const point of PAUSES) done(STEP_OF[point], passed.has(point) || (FINISHED.has(job.status) && job.status !== "failed"));
  if (waiting) actions.append(...actionsAt(waiting, job));
  if (job.status === "needs_attention") {
    actions.append(action("wz-accept", "Accept and print", "accept", "Accept the field as it is and print? The machine will move."),
      " ", action("wz-add-stations", "Add stations and probe again", "add-stations", "Plan more stations and probe them? The machine will move."));
  }
  const stuck = kids.filter((k) => k.status === "interrupted");
  if (job.status === "interrupted") {
    actions.append(el("p", {}, stuck.length ? `Step ${stuck[0].kind.replaceAll("_", " ")} was interrupted: resume it first (the Jobs page shows where it stopped).`
      : "The loop was interrupted (its process stopped): resume it; it reuses every finished step."));
    actions.append(stuck.length
      ? el("a", { id: "wz-resume-step", href: `jobs.html?job=${stuck[0].id}` }, `resume ${stuck[0].kind}`)
      : action("wz-resume", "Resume", "resume", "Resume the loop? It continues where it stopped; the machine may move.", { confirm: true }));
  }
  if (waiting || job.status === "interrupted") actions.append(" ", action("wz-abandon", "Abandon the run", "abandon", "Abandon this run? Nothing more is probed or printed."));
  if (job.status === "running" || job.status === "queued") {
    actions.append(el("progress", { max: 1, value: job.progress || 0, "aria-label": "loop progress" }));
  }
  if (FINISHED.has(job.status)) actions.append(" ", el("button", { id: "wz-new", type: "button", onclick: () => newRun() }, "Start another loop"));
  runBox.replaceChildren(head, actions);
  if (waiting) showStep(waiting);
  if (job.result?.traces) showResult(job);
  showChildren(kids);
  if (FINISHED.has(job.status) || kids.some((k) => k.kind === "probe_run" && k.status === "succeeded")) showReport(job);
}

function actionsAt(waiting, job) {
  const n = job.params.trace_ids.length;
  if (waiting.at === "plan") return [action("wz-continue", "Probe the part", "continue", `Probe ${waiting.summary.touches} points? The machine will move.`)];
  if (waiting.at === "probed") return [action("wz-continue", "Rebuild and compensate", "continue")];
  if (waiting.at === "verified") {
    if (!waiting.needs_attention) return [action("wz-continue", "Go on to printing", "continue")];
    return [action("wz-accept", "Accept the field as it is", "accept", "Accept although the verification failed? The loop goes on to printing."),
      " ", action("wz-add-stations", "Add stations and probe again", "add-stations", "Plan more stations from what was learned and probe them? The machine will move.")];
  }
  return [action("wz-continue", `Print ${waiting.summary.trace_count ?? n} trace(s)`, "continue", "Print the compensated traces on the machine? It will move.")];
}

function showStep(waiting) {
  const s = waiting.summary || {};
  const out = stepOut[waiting.at];
  if (waiting.at === "plan") {
    out.replaceChildren(el("p", { id: "wz-plan-summary" }, el("strong", { class: "figure", "data-touches": s.touches }, `${s.touches} touches`),
      ` · ${s.headline}`));
    if (s.plans?.length) viewer.show({ job_id: s.plans[s.plans.length - 1] });
  } else if (waiting.at === "probed") {
    out.replaceChildren(el("p", { id: "wz-probe-live" }, s.headline));
    if (s.runs?.length) viewer.show({ job_id: s.runs[s.runs.length - 1] });
  } else if (waiting.at === "verified") {
    out.replaceChildren(reviewTable(s.traces || []), s.verdict ? fieldCheck(s.verdict) : "");
  } else {
    out.replaceChildren(el("p", { id: "wz-print-summary" }, s.headline));
  }
}

function reviewTable(rows) {
  return el("table", { id: "wz-review", class: "records" },
    el("thead", {}, el("tr", {}, ["trace", "model off by (max)", "bound", "ends held", "compensated program"].map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, rows.map((r) => el("tr", { "data-trace": r.trace_id, "data-ready": r.compensate ? "1" : "0" },
      el("td", {}, state.names[r.trace_id] || r.trace_id), el("td", {}, length(r.deviation_max_mm)),
      el("td", {}, r.bound_mm != null ? length(r.bound_mm) : "—"),
      el("td", {}, r.held_ends_mm ? `${length(r.held_ends_mm[0])} / ${length(r.held_ends_mm[1])}` : "—"),
      el("td", {}, el("a", { href: `jobs.html?job=${r.compensate}` }, "program"))))));
}

// the field learned from the touches and checked at the verification points
function fieldCheck(v) {
  const learned = v.learned;
  const param = (name) => learned ? `${name.split("_")[0]} ${length(learned[name].value)} (told ${length(learned[name].prior)})` : "";
  return el("div", { id: "wz-field-check", "data-attention": v.needs_attention ? "1" : "0" },
    el("p", {}, el("strong", {}, v.needs_attention ? "Needs attention" : "Verified"), ` · ${v.verified}`, v.accepted ? " · accepted by an operator" : ""),
    learned ? el("p", { id: "wz-learned" }, `Learned from ${learned.touches} touches: `,
      [param("amplitude_mm"), param("wavelength_mm"), param("sigma_mm")].join(" · ")) : "",
    el("table", { id: "wz-verify", class: "records" },
      el("thead", {}, el("tr", {}, ["x, y", "measured", "predicted", "residual", "limit"].map((h) => el("th", { scope: "col" }, h)))),
      el("tbody", {}, (v.verification || []).map((p) => el("tr", { "data-within": p.within ? "1" : "0" },
        el("td", {}, `${p.xy[0].toFixed(1)}, ${p.xy[1].toFixed(1)} mm`), el("td", {}, length(p.measured_mm)),
        el("td", {}, length(p.predicted_mm)), el("td", {}, length(p.residual_mm)), el("td", {}, length(p.limit_mm)))))),
    v.needs_attention ? el("ul", {}, v.reasons.map((r) => el("li", {}, r))) : "");
}

function showResult(job) {
  const traces = job.result.traces;
  stepOut.verified.replaceChildren(reviewTable(traces), job.result.verdict ? fieldCheck(job.result.verdict) : "");
  stepOut.print.replaceChildren(el("ol", { id: "wz-prints" }, traces.map((t) => el("li", { "data-trace": t.trace_id,
    "data-status": t.print ? "printed" : "not printed" }, `${state.names[t.trace_id] || t.trace_id}: `,
    t.print ? el("a", { href: `jobs.html?job=${t.print}` }, "printed") : (t.role === "pad_probe" ? "pad probe ring, never printed" : "not printed")))));
}

function showChildren(kids) {
  childrenOut.replaceChildren(el("table", { class: "records", id: "wz-children-table" },
    el("thead", {}, el("tr", {}, ["step", "status", ""].map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, [...kids].reverse().map((k) => el("tr", { "data-kind": k.kind, "data-status": k.status },
      el("td", {}, k.title || k.kind.replaceAll("_", " ")), el("td", {}, el("span", { class: `badge ${k.status}` }, k.status)),
      el("td", {}, el("a", { href: `jobs.html?job=${k.id}`, title: k.id }, "open")))))));
}

function showReport(job) {
  if (reportOut.dataset.job === job.id && reportOut.dataset.status === job.status) return;
  reportOut.dataset.job = job.id;
  reportOut.dataset.status = job.status;
  reportOut.replaceChildren(
    el("button", { id: "wz-report-open", type: "button", onclick: () => guarded("Report", () =>
      download(`/api/v1/jobs/${job.id}/report`, `run-report-${job.id}.html`)) }, "Download the run report"),
    el("p", { class: "small" }, "One page for the whole run: the part, machine, touches, how far the model was off on each trace, ",
      "the compensated programs with their hashes and the prints."));
  if (FINISHED.has(job.status)) done("wz-8");
}

function newRun() {
  state.loop = null;
  shownRevision = "";
  history.replaceState(null, "", location.pathname);
  runBox.replaceChildren();
  for (const out of [...Object.values(stepOut), reportOut, childrenOut]) out.replaceChildren();
  for (const input of [partSelect, machineSelect, ...traceList.querySelectorAll("input")]) input.disabled = false;
  buttons.start.disabled = false;
  for (const id of ["wz-4", "wz-5", "wz-6", "wz-7", "wz-8"]) done(id, false);
  showInfo("Choose the traces and start a new loop.");
}

partSelect.addEventListener("change", () => guarded("Traces", () => loadTraces()));
machineSelect.addEventListener("change", () => guarded("Machine", showMachine));
document.addEventListener("conforma:key", () => guarded("Parts", async () => { await loadParts(); await loadMachines(); }));
await Promise.all([guarded("Parts", loadParts), guarded("Machines", loadMachines)]);
await guarded("Loop", async () => {
  const found = await findLoop();
  if (found) await follow(found);
});
markReady();
