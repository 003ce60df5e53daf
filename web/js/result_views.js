// Result views that need more than the job's own record: the probe plan's stations drawn
// on the part (top view, with the traces), compensation's standoff along the trace
// (nominal program vs compensated) with the program's time (a board compensation: its
// traces worst first, web/js/board_view.js), and a five-axis program's A/C
// angles and tip speed along the path.  Each returns a container at once and fills it
// when its reads answer (the raw JSON stays one click away on the job page).
import { get } from "./api.js";
import { chart, duration, length, recordsTable, round } from "./results.js";
import { bandNote, standoffBand, standoffRows } from "./standoff.js";
import { el } from "./ui.js";

const NS = "http://www.w3.org/2000/svg";

function box(id, title) {
  const body = el("div", { class: "view-body" }, el("p", { class: "small" }, "loading…"));
  return { node: el("section", { class: "result-view", id }, el("h3", {}, title), body), body };
}

function figureList(rows) {
  return el("table", { class: "figures" }, el("tbody", {}, rows.filter(Boolean).map(([name, value, key]) =>
    el("tr", { "data-key": key }, el("th", { scope: "row" }, name), el("td", {}, value)))));
}

async function fill(body, build) {
  try {
    body.replaceChildren(...(await build()).filter(Boolean));
  } catch (err) {
    body.replaceChildren(el("p", { class: "small" }, `could not load this view: ${err.message || err}`));
  }
}

// ---- probe plan: stations on the part (top view) ---------------------------------------
export function topView({ bounds, traces, stations, title }) {
  const w = 640, h = 420, pad = 24;
  const xy = [...traces.flatMap((t) => t.points), ...stations];
  const lo = bounds ? bounds[0] : [Math.min(...xy.map((p) => p[0])), Math.min(...xy.map((p) => p[1]))];
  const hi = bounds ? bounds[1] : [Math.max(...xy.map((p) => p[0])), Math.max(...xy.map((p) => p[1]))];
  const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-6);
  const k = Math.min((w - 2 * pad) / Math.max(hi[0] - lo[0], span * 0.05), (h - 2 * pad) / Math.max(hi[1] - lo[1], span * 0.05));
  const X = (x) => pad + (x - lo[0]) * k;
  const Y = (y) => h - pad - (y - lo[1]) * k;  // +Y up, as seen from above
  const svg = document.createElementNS(NS, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  svg.setAttribute("role", "img");
  svg.setAttribute("aria-label", title);
  const mk = (tag, attrs, text) => {
    const n = document.createElementNS(NS, tag);
    for (const [a, v] of Object.entries(attrs)) n.setAttribute(a, v);
    if (text !== undefined) n.textContent = text;
    svg.append(n);
    return n;
  };
  if (bounds) mk("rect", { class: "part-outline", x: X(lo[0]), y: Y(hi[1]), width: (hi[0] - lo[0]) * k, height: (hi[1] - lo[1]) * k,
    fill: "#d0d7de", stroke: "#57606a", "stroke-width": 1 });
  for (const t of traces) {
    mk("polyline", { class: "trace", points: t.points.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" "),
      fill: "none", stroke: "#0550ae", "stroke-width": 2 });
  }
  for (const p of stations) mk("circle", { class: "station", cx: X(p[0]).toFixed(1), cy: Y(p[1]).toFixed(1), r: 4, fill: "#cf222e", stroke: "#fff" });
  mk("text", { x: pad, y: 14, "font-size": 12 }, `top view · ${stations.length} stations (red) · traces (blue) · part (grey)`);
  mk("text", { x: w - pad, y: h - 6, "font-size": 11, "text-anchor": "end" },
    `${round(hi[0] - lo[0], 4)} × ${round(hi[1] - lo[1], 4)} mm`);
  return el("figure", { class: "chart top-view", "data-stations": stations.length, "data-traces": traces.length }, svg,
    el("figcaption", { class: "small" }, title));
}

function planView(job) {
  const { node, body } = box("plan-view", "Probe stations on the part");
  const r = job.result;
  fill(body, async () => {
    const ids = job.params.trace_ids || (job.params.trace_id ? [job.params.trace_id] : []);
    const traces = (await Promise.all(ids.slice(0, 200).map((id) => get(`traces/${id}`).catch(() => null)))).filter(Boolean);
    const part = traces.length ? await get(`parts/${traces[0].part_id}`).catch(() => null) : null;
    const sds = (r.traces || []).map((t) => t.predicted_sd_mm).filter(Number.isFinite);
    const worstSd = r.field?.max_sd_mm ?? (sds.length ? Math.max(...sds) : null);
    const rows = [["Stations", String(r.count), "count"], ["Method", r.method, "method"],
      ["Traces", String(ids.length), "traces"],
      worstSd !== null ? ["Predicted sd (worst trace)", length(worstSd), "predicted_sd_mm"] : null,
      r.spacing_mm ? ["Spacing", length(r.spacing_mm), "spacing_mm"] : null];
    const perTrace = (r.traces || []).map((t, i) => ({ trace: traces.find((x) => x.id === t.trace_id)?.name || t.trace_id,
      stations: t.stations ?? t.count, predicted_sd_um: Number.isFinite(t.predicted_sd_mm) ? t.predicted_sd_mm * 1000 : null, index: i }));
    const drawn = topView({ bounds: part?.bounds ? [part.bounds[0], part.bounds[1]] : null,
      traces: traces.map((t) => ({ points: t.nominal.points })), stations: r.points || [],
      title: `${r.count} probe stations${worstSd !== null ? `, predicted sd ≤ ${length(worstSd)}` : ""}` });
    const sdChart = perTrace.length > 1 && perTrace.every((t) => t.predicted_sd_um !== null)
      ? chart(perTrace, { x: "index", ys: ["predicted_sd_um"], type: "bars", title: "Predicted sd of the rebuilt deviation per trace" }) : null;
    return [figureList(rows), drawn, sdChart];
  });
  return node;
}

// ---- compensation: standoff along the trace, chord error, segments, time ---------------
function compensateView(job) {
  const { node, body } = box("compensate-view", "Nominal program vs compensated");
  const r = job.result;
  fill(body, async () => {
    const [program, nominal, rebuilt] = await Promise.all([
      get(`jobs/${job.id}/artifacts/print.gcode/summary`).catch(() => null),
      get(`jobs/${job.id}/artifacts/nominal.gcode/summary`).catch(() => null),
      job.params.reconstruct_job_id ? get(`jobs/${job.params.reconstruct_job_id}?include=result`).catch(() => null) : null]);
    const standoff = r.standoff_mm;
    const samples = rebuilt?.result?.deviation?.samples || [];
    const bound = rebuilt?.result?.bound_mm ?? null;
    const rows = standoffRows(samples, standoff, bound);
    const worst = samples.length ? Math.max(...samples.map(([, dz]) => Math.abs(dz))) : null;
    const figures = figureList([
      ["Set standoff", length(standoff), "standoff_mm"],
      worst !== null ? ["Nominal program: worst standoff error (model)", length(worst), "nominal_error_mm"] : null,
      ["Compensated: chord error (proved per segment)", `≤ ${length(r.max_chord_error_mm)}`, "max_chord_error_mm"],
      ["Segments", `${r.segments} (nominal ${r.nominal_segments})`, "segments"],
      ["Length", length(r.length_mm), "length_mm"],
      program ? ["Program time (estimated)", duration(program.time_s), "time_s"] : null,
      program ? ["Program lines", String(program.lines), "lines"] : null,
      nominal ? ["Nominal program time", duration(nominal.time_s), "nominal_time_s"] : null]);
    const plot = rows.length > 1 ? chart(rows, { x: "s_mm", ys: ["nominal_program_um", "compensated_um"], band: standoffBand(bound),
      title: `Standoff along the trace from the reconstructed surface: the nominal program vs the compensated one (± ${length(r.max_chord_error_mm)} chord error)`
        + bandNote(bound), xUnit: "mm", yUnit: "µm" }) : el("p", { class: "small" }, "no reconstruction samples to compare with");
    if (plot.tagName === "FIGURE") plot.id = "standoff-plot";
    return [figures, plot];
  });
  return node;
}

// ---- five-axis: A/C and tip speed along the path -----------------------------------------
function fiveAxisView(job) {
  const { node, body } = box("five-axis-view", "Five-axis program along the path");
  fill(body, async () => {
    const summary = await get(`jobs/${job.id}/artifacts/five_axis.gcode/summary`);
    const p = summary.rotary;
    if (!p) return [el("p", { class: "small" }, "the program has no A/C motion")];
    const rows = p.s_mm.map((s, i) => ({ s_mm: s, a_deg: p.a_deg[i], c_deg: p.c_deg[i], tip_speed_mm_s: p.tip_speed_mm_s[i] }));
    const angles = chart(rows, { x: "s_mm", ys: ["a_deg", "c_deg"], title: "A and C angles along the path", xUnit: "mm", yUnit: "°" });
    const speed = chart(rows, { x: "s_mm", ys: ["tip_speed_mm_s"], title: "Nozzle tip speed along the path (workpiece coordinates)", xUnit: "mm", yUnit: "mm/s" });
    if (angles) angles.id = "angles-plot";
    if (speed) speed.id = "tip-speed-plot";
    return [figureList([["Program time (feed lines)", duration(summary.time_s), "time_s"], ["Program lines", String(summary.lines), "lines"],
      ["Path length", length(p.s_mm[p.s_mm.length - 1]), "path_mm"], ["Top tip speed", `${round(p.tip_speed_max_mm_s, 4)} mm/s`, "tip_speed_max"]]),
    angles, speed];
  });
  return node;
}

// ---- board compensation: every trace, worst first (web/js/board_view.js, loaded on use) ----
function boardCompensateView(job) {
  const { node, body } = box("compensate-board-view", `Board: ${job.result.traces.length} traces, nominal program vs compensated`);
  fill(body, async () => (await import("./board_view.js")).boardCompensateContents(job));
  return node;
}

// ---- circuit program: every printed item on the measured surface, largest bound first -----
function circuitSurfaceView(job) {
  const { node, body } = box("circuit-surface-view", "Every printed point on the measured surface");
  const s = job.result.surface;
  if (!s) {
    body.replaceChildren(el("p", { class: "small" }, "this program reports no surface"));
    return node;
  }
  const um = (mm) => (Number.isFinite(mm) ? `${round(mm * 1000, 2)} µm` : "—");
  const items = Object.entries(s.items || {}).map(([name, i]) => ({ item: name, kind: i.kind, points: i.points,
    sd_um: Number.isFinite(i.sd_mm) ? i.sd_mm * 1000 : null, bound_um: Number.isFinite(i.bound_mm) ? i.bound_mm * 1000 : null,
    clearance_min_um: Number.isFinite(i.clearance_min_mm) ? i.clearance_min_mm * 1000 : null,
    standoff_um: i.standoff_mm * 1000 }));
  items.sort((a, b) => (b.bound_um ?? 0) - (a.bound_um ?? 0));
  const risky = s.bound_over_standoff || [];
  body.replaceChildren(figureList([
    ["Surface", s.model === "field" ? "the loop's fitted field (posterior mean)" : "interpolated between probe stations", "model"],
    s.verified ? ["Field", s.verified, "verified"] : null,
    ["Printed points", String(s.points), "points"],
    ["Worst predicted error (sd)", um(s.sd_mm), "sd_mm"],
    ["Its bound", um(s.bound_mm), "bound_mm"],
    ["Smallest nozzle clearance over the surface", um(s.clearance_min_mm), "clearance_min_mm"],
    ["Bound reaches the standoff", risky.length ? risky.join(", ") : "none", "bound_over_standoff"]]),
  recordsTable(items, 50));
  return node;
}

// ---- reconstruction: what the probes measured along the trace, with the bound -----------
function reconstructView(job) {
  const r = job.result;
  const { node, body } = box("reconstruct-view", "Reconstruction: measured − nominal along the trace");
  const samples = (r.deviation?.samples || []).map(([s, dz]) => ({ s_mm: s, deviation_mm: dz }))
    .sort((a, b) => a.s_mm - b.s_mm);
  if (!samples.length) {
    body.replaceChildren(el("p", { class: "small" }, "this reconstruction reports no samples"));
    return node;
  }
  const um = (mm) => (Number.isFinite(mm) ? `${round(mm * 1000, 3)} µm` : "—");
  const band = r.bound_mm != null ? { half: r.bound_mm } : null;
  const plot = chart(samples, { x: "s_mm", ys: ["deviation_mm"], xUnit: "mm", points: samples, band,
    title: `Measured − nominal height at each kept probe point along the trace` +
      (band ? `; shaded: ± the reconstruction's bound (${um(r.bound_mm)}, under the fitted model)` : "") });
  body.replaceChildren(figureList([
    ["Method", r.method, "method"],
    ["Probe points used", String(r.points_used), "points_used"],
    ["Deviation max / rms", `${um(r.deviation.max_mm)} / ${um(r.deviation.rms_mm)}`, "deviation"],
    r.bound_mm != null ? ["Bound", `± ${um(r.bound_mm)}`, "bound_mm"] : null,
    ["Outliers excluded", r.outliers?.length ? r.outliers.join(", ") : "none", "outliers"],
    r.field_check?.verdict?.line ? ["Verified", r.field_check.verdict.line, "verdict"] : null]), plot);
  return node;
}

export const VIEWS = { probe_plan: planView, reconstruct: reconstructView, five_axis: fiveAxisView, circuit_program: circuitSurfaceView,
  compensate: (job) => (job.result.board ? boardCompensateView(job) : compensateView(job)) };
