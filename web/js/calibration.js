// Calibration panel of the machines page: per machine, the current probe calibration
// (ball radius, pre-travel ± 1 sigma), every nozzle's offset (calibrated vs nominal), their
// ages, and flags (stale, a re-check that disagrees) shown as warnings.  "Calibrate probe"
// and "Calibrate nozzle T<k>" submit the calibration jobs after a confirmation (they move
// the machine).  GET /machines/{id}/calibration; POST /jobs.
import { ApiError, get, post } from "./api.js";
import { el, guarded, showInfo } from "./ui.js";

const POLL_MS = 5000;
const main = document.querySelector("main");
const container = document.getElementById("calibration") || el("section", { id: "calibration" });
main.append(container); // after the machine cards (machines.js appended them first)
container.replaceChildren(el("h2", {}, "Calibration"),
  el("p", { class: "small" }, "Probe qualification on the reference sphere (ball radius, pre-travel) and nozzle offsets " +
    "(Z by touch-off on the pad, XY on the sphere). Every job on a machine uses its latest calibration."));
const panels = new Map();

const um = (v) => (v === null || v === undefined ? "—" : `${Number(v).toFixed(1)} µm`);
const mm = (v, d = 4) => (v === null || v === undefined ? "—" : `${Number(v).toFixed(d)} mm`);
const age = (h) => (h === null || h === undefined ? "—" : h < 1 ? `${Math.round(h * 60)} min ago` : `${h.toFixed(1)} h ago`);
const vec = (v, d = 4) => (v ? `(${v.map((x) => Number(x).toFixed(d)).join(", ")})` : "—");

function row(label, value, cls = "") {
  return el("tr", { class: cls }, el("th", { scope: "row" }, label), el("td", { class: "mono" }, value));
}

function probeTable(p) {
  if (!p) return el("p", { class: "calib-missing" }, "Probe: not calibrated. Run \u201cCalibrate probe\u201d first.");
  const state = p.stale ? el("span", { class: "badge failed calib-stale" }, "stale") : el("span", { class: "badge succeeded" }, "current");
  return el("table", { class: "calib-probe" }, el("caption", {}, "Probe (T0) ", state),
    row("ball radius", `${mm(p.ball_radius_mm)} ± ${um(p.ball_radius_std_um)}`),
    row("pre-travel", `${mm(p.pretravel_mm)} ± ${um(p.pretravel_std_um)}`),
    row("lobing cos3 / sin3", `${mm(p.lobing_cos3_mm)} / ${mm(p.lobing_sin3_mm)}`),
    row("sphere residual (rms)", um(p.residual_rms_um)),
    row("pad reading z", mm(p.pad_reading_z_mm)),
    row("measured", `${age(p.age_h)} · ${p.touches} touches · job ${p.job_id}`, p.stale ? "stale" : ""),
    p.disagrees.length ? row("re-check disagrees", p.disagrees.join(", "), "disagrees") : null);
}

function nozzleTable(nozzles) {
  if (!nozzles.length) return el("p", { class: "small" }, "No nozzles in this machine's profile (profile.tools.nozzles).");
  const head = el("tr", {}, ...["tool", "nominal offset", "calibrated offset", "± (µm)", "calibrated − nominal", "measured"].map((t) => el("th", {}, t)));
  const rows = nozzles.map((n) => el("tr", { class: `${n.stale ? "stale" : ""} ${n.disagrees?.length ? "disagrees" : ""}`.trim(), "data-tool": n.tool },
    el("td", {}, `T${n.tool}${n.name ? ` ${n.name}` : ""}`), el("td", { class: "mono" }, vec(n.nominal_offset_mm, 3)),
    el("td", { class: "mono" }, n.calibrated ? vec(n.offset_mm) : "not calibrated"),
    el("td", { class: "mono" }, n.calibrated ? n.offset_std_um.map((s) => Number(s).toFixed(1)).join(" / ") : "—"),
    el("td", { class: "mono" }, n.calibrated ? vec(n.nominal_difference_mm) : "—"),
    el("td", {}, n.calibrated ? `${age(n.age_h)}${n.stale ? " (stale)" : ""}` : "—")));
  return el("table", { class: "calib-nozzles" }, el("caption", {}, "Nozzles"), head, ...rows);
}

async function submit(m, kind, params, what) {
  if (!window.confirm(`${what} on ${m.name}? The machine moves: it touches the reference sphere and pad. Is it clear?`)) return;
  await guarded(what, async () => {
    const job = await post("jobs", { kind, params: { machine_id: m.id, ...params } });
    showInfo(`${what}: job ${job.id} queued (see Jobs for its progress).`, 8000);
  });
}

function render(m, cal) {
  let panel = panels.get(m.id);
  if (!panel) {
    panel = el("section", { class: "calibration-panel", "data-id": m.id });
    panels.set(m.id, panel);
    container.append(panel);
  }
  const flags = cal.flags.length
    ? el("ul", { class: "calib-flags", role: "alert" }, cal.flags.map((f) => el("li", { class: "msg error" }, `⚠ ${f}`)))
    : el("p", { class: "small calib-ok" }, cal.probe ? "No flags: the calibration is current and consistent." : "");
  const buttons = el("div", { class: "row" },
    el("button", { type: "button", class: "calibrate-probe", onclick: () => submit(m, "calibrate_probe", {}, "Calibrate probe") }, "Calibrate probe"),
    ...cal.nozzles.map((n) => el("button", { type: "button", class: "calibrate-nozzle", "data-tool": n.tool, disabled: !cal.probe,
      title: cal.probe ? "" : "calibrate the probe first",
      onclick: () => submit(m, "calibrate_nozzle", { tool: n.tool }, `Calibrate nozzle T${n.tool}`) }, `Calibrate nozzle T${n.tool}`)));
  panel.replaceChildren(el("h3", { title: m.id }, m.name), flags,
    probeTable(cal.probe), nozzleTable(cal.nozzles), buttons,
    el("p", { class: "small" }, `A calibration older than ${cal.max_age_h} h is flagged stale.`));
}

async function refresh() {
  try {
    const page = await get("machines");
    const ids = new Set(page.items.map((m) => m.id));
    for (const [id, panel] of panels) if (!ids.has(id)) { panel.remove(); panels.delete(id); }
    for (const m of page.items) render(m, await get(`machines/${m.id}/calibration`));
  } catch (err) {
    if (err instanceof ApiError && err.status === 404) { container.hidden = true; return; }
    if (!err.offline && !err.noKey) guarded("Calibration", () => { throw err; });
  }
}

document.addEventListener("conforma:key", () => refresh());
await refresh();
setInterval(refresh, POLL_MS);
