// The closed-loop wizard: part -> traces -> machine -> plan (touches and predicted error
// before anything moves) -> probe (live touch count) -> review (how far the model was off,
// where, and the compensated programs) -> print (after a confirmation) -> run report.
// Every step is an ordinary job of the API; nothing moves a machine without a click and a
// confirmation.
import { download, get, post, streamEvents } from "./api.js";
import { chart, length } from "./results.js";
import { el, guarded, initPage, latest, markReady, showInfo, viewerPanel } from "./ui.js";

const main = initPage("loop.html");
const TERMINAL = new Set(["succeeded", "needs_attention", "failed", "cancelled", "interrupted"]);
// traces: the part's printable traces; rings: its circuit imports' pad / area probe rings
// (traces with source.role "pad_probe"), probed with the import's traces, never printed.
const state = { part: null, traces: [], rings: [], machine: null, plan: null, run: null, rows: [] };

function step(id, title, ...body) {
  return el("section", { id, class: "wizard-step", "data-done": "0", "aria-labelledby": `${id}-h` },
    el("h2", { id: `${id}-h` }, title), ...body);
}

const partSelect = el("select", { id: "wz-part", "aria-label": "part" });
const traceList = el("div", { id: "wz-traces", role: "group", "aria-label": "traces to print" });
const ringNote = el("p", { id: "wz-pad-rings", class: "small", "data-rings": "0" });
const machineSelect = el("select", { id: "wz-machine", "aria-label": "machine" });
const machineState = el("span", { id: "wz-machine-state", class: "small" });
const planOut = el("div", { id: "wz-plan-out" });
const probeOut = el("div", { id: "wz-probe-out" });
const reviewOut = el("div", { id: "wz-review-out" });
const printOut = el("div", { id: "wz-print-out" });
const reportOut = el("div", { id: "wz-report-out" });
const buttons = {
  connect: el("button", { id: "wz-connect", type: "button", onclick: () => connect() }, "Connect"),
  plan: el("button", { id: "wz-plan", class: "primary", type: "button", onclick: () => plan() }, "Plan the probes"),
  probe: el("button", { id: "wz-probe", class: "primary", type: "button", disabled: true, onclick: () => probe() }, "Probe the part"),
  print: el("button", { id: "wz-print", class: "primary", type: "button", disabled: true, onclick: () => printAll() }, "Print"),
};
const viewerSection = el("section", { id: "viewer-panel" });
main.append(el("h1", {}, "Closed loop"),
  el("p", { class: "small" }, "Probe the real part, rebuild each trace on its real surface and print at the standoff above it. ",
    "The machine moves only at “Probe” and “Print”, each after a confirmation."),
  el("div", { class: "layout" },
    el("div", {},
      step("wz-1", "1 · Part", partSelect),
      step("wz-2", "2 · Traces", traceList, ringNote),
      step("wz-3", "3 · Machine", machineSelect, " ", buttons.connect, " ", machineState),
      step("wz-4", "4 · Plan", el("p", { class: "small" }, "How many touches, and the error they leave, before anything moves."),
        buttons.plan, planOut),
      step("wz-5", "5 · Probe", buttons.probe, probeOut),
      step("wz-6", "6 · Review", reviewOut),
      step("wz-7", "7 · Print", buttons.print, printOut),
      step("wz-8", "8 · Report", reportOut)),
    viewerSection));
const viewer = viewerPanel(viewerSection);

const done = (id) => { document.getElementById(id).dataset.done = "1"; };

async function waitJob(job, onEvent) {
  if (TERMINAL.has(job.status)) return job;
  await new Promise((resolve) => {
    streamEvents(`/api/v1/jobs/${job.id}/events`, (ev) => onEvent?.(ev.data), () => resolve());
  });
  return get(`jobs/${job.id}?include=result`);
}

function failed(job, what) {
  const reason = job.error ? `${job.error.title}: ${job.error.detail}` : job.status;
  throw new Error(`${what} ${job.id} ${job.status}: ${reason}`);
}

// ---- 1-3: part, traces, machine ------------------------------------------------------------
async function loadParts() {
  const parts = (await get("parts?limit=200")).items;
  partSelect.replaceChildren(el("option", { value: "" }, "choose a part…"), ...parts.map((p) => el("option", { value: p.id }, p.name)));
}

const isRing = (t) => (t.source || {}).role === "pad_probe";

const tracesLatest = latest();  // the part changed quickly: never the traces of a part no longer chosen

async function loadTraces() {
  const current = tracesLatest();
  const part = partSelect.value || null;
  const all = part ? (await get(`parts/${part}/traces?limit=1000`)).items : [];
  if (!current()) return;
  state.part = part;
  state.traces = all.filter((t) => !isRing(t));
  state.rings = all.filter(isRing);
  traceList.replaceChildren(...(state.traces.length ? state.traces.map((t) => el("label", { class: "inline" },
    el("input", { type: "checkbox", value: t.id, checked: true }), ` ${t.name} (${length(t.length_mm)})`))
    : [el("p", { class: "small" }, state.part ? "This part has no traces: add some on the Traces page." : "Choose a part first.")]));
  showRings();
  if (state.part) { done("wz-1"); viewer.show({ part_id: state.part }); }
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
  machineSelect.selectedOptions[0].textContent = `${m.name} (${m.state})`;
  machineState.dataset.state = m.state;
  buttons.connect.disabled = m.state !== "disconnected";
  if (m.state !== "disconnected") done("wz-3");
}

async function connect() {
  await guarded("Connect", async () => {
    await post(`machines/${state.machine}/connect`);
    await showMachine();
  });
}

const chosenTraces = () => [...traceList.querySelectorAll("input:checked")].map((i) => i.value);

// ---- 4: plan ---------------------------------------------------------------------------------
async function plan() {
  await guarded("Plan", async () => {
    const traceIds = chosenTraces();
    if (!traceIds.length) throw new Error("choose at least one trace");
    const rings = padRings().map((r) => r.id);
    buttons.plan.disabled = true;
    planOut.textContent = "planning…";
    const job = await waitJob(await post("jobs", { kind: "probe_plan",
      params: { trace_ids: [...traceIds, ...rings], method: "field" } }));
    if (job.status !== "succeeded") failed(job, "probe plan");
    state.plan = job;
    const sds = (job.result.traces || []).map((t) => t.predicted_sd_mm).filter(Number.isFinite);
    const worst = sds.length ? Math.max(...sds) : null;  // under the prior told; checked after probing
    planOut.replaceChildren(el("p", { id: "wz-plan-summary" },
      el("strong", { class: "figure", "data-touches": job.result.count }, `${job.result.count} touches`),
      ` on ${traceIds.length} trace(s)`, rings.length ? el("span", { id: "wz-plan-rings", "data-rings": rings.length },
        ` and ${rings.length} pad probe ring(s)`) : "", worst !== null ? ` · predicted error (3σ) ≤ ${length(3 * worst)}` : ""));
    done("wz-4");
    buttons.probe.disabled = !state.machine;
    viewer.show({ job_id: job.id });
  });
  buttons.plan.disabled = false;
}

// ---- 5: probe --------------------------------------------------------------------------------
async function probe() {
  if (!state.plan || !state.machine) return;
  if (!window.confirm(`Probe ${state.plan.result.count} points? The machine will move.`)) return;
  await guarded("Probe", async () => {
    buttons.probe.disabled = true;
    const live = el("p", { id: "wz-probe-live" }, "starting…");
    probeOut.replaceChildren(live);
    const total = state.plan.result.count;
    const job = await waitJob(await post("jobs", { kind: "probe_run", params: { plan_job_id: state.plan.id, machine_id: state.machine } }),
      (ev) => { live.textContent = `touch ${Math.round(ev.progress * total)} of ${total} · ${ev.message || ""}`; });
    if (job.status !== "succeeded") failed(job, "probe run");
    state.run = job;
    const stats = job.result.stats || {};
    live.textContent = `${stats.count} touches · largest |real − model| ${length(stats.max_abs_mm)} · rms ${length(stats.rms_mm)}`;
    probeOut.append(chart(job.result.points, { x: "index", ys: ["deviation_mm"], title: "Real − model height at each touch" }) || "");
    done("wz-5");
    viewer.show({ job_id: job.id });
    await review();
  });
}

// ---- 6: review -------------------------------------------------------------------------------
async function review() {
  reviewOut.textContent = "rebuilding each trace on the real surface…";
  const rows = [];
  for (const traceId of chosenTraces()) {
    const trace = state.traces.find((t) => t.id === traceId);
    const rebuilt = await waitJob(await post("jobs", { kind: "reconstruct", params: {
      trace_id: traceId, probe_run_job_id: state.run.id, method: "field" } }));
    if (rebuilt.status !== "succeeded") failed(rebuilt, `reconstruction of ${trace.name}`);
    const program = await waitJob(await post("jobs", { kind: "compensate", params: {
      trace_id: traceId, reconstruct_job_id: rebuilt.id, machine_id: state.machine } }));
    const samples = rebuilt.result.deviation?.samples || [];
    const worst = samples.reduce((a, b) => (Math.abs(b[1]) > Math.abs(a[1]) ? b : a), [0, 0]);
    rows.push({ trace, rebuilt, program, worst });
  }
  state.rows = rows;
  reviewOut.replaceChildren(el("table", { id: "wz-review", class: "records" },
    el("thead", {}, el("tr", {}, ["trace", "model off by (max)", "where", "compensated program", "ready"].map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, rows.map((r) => el("tr", { "data-trace": r.trace.id, "data-ready": r.program.status === "succeeded" ? "1" : "0" },
      el("td", {}, r.trace.name),
      el("td", {}, length(r.rebuilt.result.deviation?.max_mm)),
      el("td", {}, `${length(r.worst[0])} along the trace (${length(r.worst[1])})`),
      el("td", {}, r.program.status === "succeeded"
        ? `${r.program.result.segments} segments, chord error ≤ ${length(r.program.result.max_chord_error_mm)}`
        : `${r.program.error?.title || r.program.status}: ${r.program.error?.detail || ""}`),
      el("td", {}, r.program.status === "succeeded" ? el("span", { class: "badge succeeded" }, "ready") : el("span", { class: "badge failed" }, "not printable")))))),
  ...rows.map((r) => chart((r.rebuilt.result.deviation?.samples || []).map(([s, d]) => ({ s_mm: s, deviation_mm: d })),
    { x: "s_mm", ys: ["deviation_mm"], title: `${r.trace.name}: real surface − model along the trace` }) || ""));
  const check = rows.find((r) => r.rebuilt.result.field_check)?.rebuilt.result.field_check;
  if (check) reviewOut.prepend(fieldCheck(check, rows));
  done("wz-6");
  const ready = rows.filter((r) => r.program.status === "succeeded");
  buttons.print.textContent = `Print ${ready.length} trace(s)`;
  // a field check that asks for attention holds the print until the operator accepts it explicitly
  const accept = document.getElementById("wz-accept");
  buttons.print.disabled = !ready.length || Boolean(accept && !accept.checked);
  accept?.addEventListener("change", () => { buttons.print.disabled = !ready.length || !accept.checked; });
  await showReport();
}

// the field learned from the touches and checked at the verification points
function fieldCheck(check, rows) {
  const bound = Math.max(...rows.map((r) => r.rebuilt.result.bound_mm).filter(Number.isFinite));
  const verified = (check.verification || []);
  const worst = verified.reduce((m, p) => Math.max(m, Math.abs(p.residual_mm)), 0);
  const learned = check.learned;
  const param = (name, unit) => learned ? `${name.split("_")[0]} ${length(learned[name].value)}${unit} (told ${length(learned[name].prior)})` : "";
  const box = el("div", { id: "wz-field-check", "data-attention": check.needs_attention ? "1" : "0" },
    el("p", {}, el("strong", {}, check.needs_attention ? "Needs attention" : "Verified"), ` · verified at ${verified.length} points: `
      + `max |residual| ${length(worst)} (bound ${length(bound)})`),
    learned ? el("p", { id: "wz-learned" }, `Learned from ${learned.touches} touches: `,
      [param("amplitude_mm", ""), param("wavelength_mm", ""), param("sigma_mm", "")].join(" · ")) : "",
    el("table", { id: "wz-verify", class: "records" },
      el("thead", {}, el("tr", {}, ["x, y", "measured", "predicted", "residual", "limit"].map((h) => el("th", { scope: "col" }, h)))),
      el("tbody", {}, verified.map((p) => el("tr", { "data-within": p.within ? "1" : "0" },
        el("td", {}, `${p.xy[0].toFixed(1)}, ${p.xy[1].toFixed(1)} mm`), el("td", {}, length(p.measured_mm)),
        el("td", {}, length(p.predicted_mm)), el("td", {}, length(p.residual_mm)), el("td", {}, length(p.limit_mm)))))));
  if (check.needs_attention) {
    box.append(el("ul", {}, check.reasons.map((r) => el("li", {}, r))),
      el("p", {}, "What to do: plan again with the learned prior (deviation wavelength and amplitude above) and probe "
        + "again, or accept and print as it is."),
      el("label", {}, el("input", { type: "checkbox", id: "wz-accept" }), " accept the field as it is and allow printing"));
  }
  return box;
}

// ---- 7: print --------------------------------------------------------------------------------
async function printAll() {
  const ready = state.rows.filter((r) => r.program.status === "succeeded");
  if (!window.confirm(`Print ${ready.length} compensated trace(s) on the machine? It will move.`)) return;
  await guarded("Print", async () => {
    buttons.print.disabled = true;
    const list = el("ol", { id: "wz-prints" });
    printOut.replaceChildren(list);
    for (const r of ready) {
      const item = el("li", { "data-trace": r.trace.id }, `${r.trace.name}: queued`);
      list.append(item);
      const job = await waitJob(await post(`machines/${state.machine}/print`, { job_id: r.program.id, artifact: "print.gcode" }),
        (ev) => { item.textContent = `${r.trace.name}: ${Math.round(ev.progress * 100)} % ${ev.message || ""}`; });
      item.textContent = `${r.trace.name}: ${job.status}${job.result ? ` (${job.result.executed}/${job.result.total} commands)` : ""}`;
      item.dataset.status = job.status;
      if (job.status !== "succeeded") failed(job, `print of ${r.trace.name}`);
    }
    done("wz-7");
    showInfo("Every trace printed. The run report lists the programs and their hashes.");
  });
}

// ---- 8: report -------------------------------------------------------------------------------
async function showReport() {
  const path = `/api/v1/jobs/${state.run.id}/report`;
  reportOut.replaceChildren(
    el("button", { id: "wz-report-open", type: "button", onclick: () => guarded("Report", async () => {
      const blob = await download(`${path}`, `run-report-${state.run.id}.html`);
      return blob;
    }) }, "Download the run report"),
    el("p", { class: "small" }, "One page with the part, machine, touches, how far the model was off on each trace, ",
      "the compensated programs with their hashes and the prints."));
  done("wz-8");
}

partSelect.addEventListener("change", () => guarded("Traces", loadTraces));
machineSelect.addEventListener("change", () => guarded("Machine", showMachine));
document.addEventListener("conforma:key", () => guarded("Parts", async () => { await loadParts(); await loadMachines(); }));
await Promise.all([guarded("Parts", loadParts), guarded("Machines", loadMachines)]);
markReady();
