// Job results for people: every figure with its unit, read from the field name's suffix
// (_mm, _um, _s, _ms, _deg, _mm_min, _mm3, _mm2), durations as "2 h 18 min", lengths in
// µm when they are below a millimetre, and lists summarised by their length.  The raw
// JSON stays one click away on the job page.
import { VIEWS } from "./result_views.js";
import { el } from "./ui.js";

const UNITS = [
  ["_mm_min", (v) => `${round(v, 4)} mm/min`],
  ["_mm_s", (v) => `${round(v, 4)} mm/s`],
  ["_mm3", (v) => `${round(v, 4)} mm³`],
  ["_mm2", (v) => `${round(v, 4)} mm²`],
  ["_um", (v) => `${round(v, 3)} µm`],
  ["_mm", (v) => length(v)],
  ["_ms", (v) => `${round(v, 3)} ms`],
  ["_s", (v) => duration(v)],
  ["_deg", (v) => `${round(v, 4)}°`],
  ["_c", (v) => `${round(v, 3)} °C`],
];

// `digits` significant digits, no exponent for ordinary magnitudes, no trailing noise.
export function round(value, digits = 4) {
  const v = Number(value);
  if (!Number.isFinite(v)) return String(value);
  if (v === 0) return "0";
  if (Math.abs(v) >= 1e-3 && Math.abs(v) < 1e7) return String(Number(v.toPrecision(digits)));
  return v.toExponential(digits - 1);
}

// A length in mm, shown in µm below 1 mm (the scale standoff errors live at).
export function length(mm) {
  const v = Number(mm);
  if (!Number.isFinite(v)) return "—";
  return Math.abs(v) < 1 && v !== 0 ? `${round(v * 1000, 4)} µm` : `${round(v, 5)} mm`;
}

// Seconds as "850 ms", "42.3 s", "3 min 05 s" or "2 h 18 min".
export function duration(seconds) {
  const s = Number(seconds);
  if (!Number.isFinite(s)) return "—";
  if (s < 1) return `${round(s * 1000, 3)} ms`;
  if (s < 60) return `${round(s, 3)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(Math.round(s % 60)).padStart(2, "0")} s`;
  const minutes = Math.round(s / 60);
  return `${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, "0")} min`;
}

// One value with the unit its name implies.
export function formatValue(name, value) {
  if (value === null || value === undefined) return "—";
  if (typeof value === "boolean") return value ? "yes" : "no";
  if (typeof value === "string") return value.length > 80 ? `${value.slice(0, 77)}…` : value;
  if (Array.isArray(value)) return `${value.length} item${value.length === 1 ? "" : "s"}`;
  if (typeof value === "number") {
    const unit = UNITS.find(([suffix]) => name.endsWith(suffix));
    if (unit) return unit[1](value);
    return Number.isInteger(value) ? String(value) : round(value, 5);
  }
  return "";
}

function label(name) {
  const text = name.replace(/_(mm_min|mm_s|mm3|mm2|um|mm|ms|s|deg|c)$/, "").replace(/_/g, " ");
  return text.charAt(0).toUpperCase() + text.slice(1);
}

// [[label, formatted, key], ...] for the scalar figures of `result` (one level of nesting,
// as "deviation · max"); big arrays and NURBS internals are left to the raw JSON.
export function headlineFigures(result) {
  const rows = [];
  const skip = /^(knots|control_points|weights|points|samples|surface|curve|records|layers|arrays|grid)$/;
  for (const [key, value] of Object.entries(result || {})) {
    if (value && typeof value === "object" && !Array.isArray(value)) {
      if (skip.test(key)) continue;
      for (const [inner, v] of Object.entries(value)) {
        if (v !== null && typeof v === "object") continue;
        rows.push([`${label(key)} · ${label(inner).toLowerCase()}`, formatValue(inner, v), `${key}.${inner}`]);
      }
    } else if (Array.isArray(value)) {
      if (value.length) rows.push([label(key), formatValue(key, value), key]);
    } else {
      rows.push([label(key), formatValue(key, value), key]);
    }
  }
  return rows;
}

// The figures as a definition table (each row keeps its JSON key for tests and scripts).
export function figuresTable(result) {
  const rows = headlineFigures(result);
  if (!rows.length) return null;
  return el("table", { class: "figures", id: "result-figures" },
    el("tbody", {}, rows.map(([name, value, key]) =>
      el("tr", { "data-key": key }, el("th", { scope: "row" }, name), el("td", {}, value)))));
}

// ---- per-kind curves: what an operator reads first ------------------------------------
// rows: the result's array of per-item records; x: the abscissa; ys: the curves (unit from
// the field name); kind "bars" compares two series side by side (before / after).
const CHARTS = {
  closed_loop: { rows: "table", x: "trace", ys: ["standoff_max_before_um", "standoff_max_after_um"], type: "bars",
    title: "Worst standoff error per trace: nominal program vs compensated" },
  probe_run: { rows: "points", x: "index", ys: ["deviation_mm"], title: "Measured − nominal height at each probe" },
  slice: { rows: "layers", x: "z", ys: ["thickness"], title: "Layer thickness by height", xUnit: "mm", yUnit: "mm" },
  toolpath: { rows: "layers", x: "index", ys: ["time_s"], title: "Estimated time per layer" },
  jetting: { rows: "layers", x: "layer", ys: ["sa_um", "sz_um", "edge_collapse_um"], title: "Surface roughness and edge collapse by layer" },
  jetting_run: { rows: "layers", x: "layer", ys: ["sa_um", "edge_collapse_um"], title: "Measured surface roughness and edge collapse by layer" },
};
const COLORS = ["#cf222e", "#1a7f37", "#1f6feb", "#9a6700"];

function unitOf(name) {
  const unit = UNITS.find(([suffix]) => name.endsWith(suffix));
  return unit ? unit[0].slice(1).replace("mm_s", "mm/s").replace("um", "µm").replace("deg", "°") : "";
}

// Ticks at 1, 2 or 5 x 10^k enclosing [lo, hi]: about `count` of them, with the decimals
// their step needs (no exponents, no 4.522e-4).
export function niceTicks(lo, hi, count = 5) {
  if (!(hi > lo)) return { ticks: [lo], decimals: 0 };
  const raw = (hi - lo) / Math.max(1, count);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((f) => f * mag).find((v) => v >= raw) ?? 10 * mag;
  const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  const ticks = [];
  const first = Math.floor(lo / step + 1e-9), last = Math.ceil(hi / step - 1e-9);  // the ticks enclose [lo, hi]
  for (let k = first; k <= last; k += 1) ticks.push(Number((k * step).toFixed(decimals)));
  return { ticks, decimals };
}

// How a series is shown: lengths in mm that are all below 1 mm (errors, deviations) in µm,
// the unit the page's tables use for them; everything else as its name says.
function displayScale(names, rows, unit) {
  const mm = unit ? unit === "mm" : names.every((k) => k.endsWith("_mm"));
  if (!mm) return { factor: 1, unit: unit || unitOf(names[0]) };
  const big = rows.some((r) => names.some((k) => Number.isFinite(r[k]) && Math.abs(r[k]) >= 1));
  return big ? { factor: 1, unit: "mm" } : { factor: 1000, unit: "µm" };
}

// An SVG chart of `rows` (objects): nice ticks with grid lines on both axes, values in the
// page's units, a legend; optionally `points` (records with the same x and y keys, drawn as
// dots: probe touches) and a `band` ({ lo, hi } keys or { half } constant: an uncertainty band).
export function chart(rows, { x, ys, type = "line", title = "", xUnit = "", yUnit = "", points = null, band = null }) {
  const series = ys.filter((k) => rows.length && typeof rows[0][k] === "number");
  if (!series.length || rows.length < 1) return null;
  const w = 640, h = 240, left = 60, right = 14, top = 26, bottom = 40;
  const xs = rows.map((r, i) => (typeof r[x] === "number" ? r[x] : i));
  const scale = displayScale(series, rows, yUnit);
  const f = scale.factor;
  const dots = (points || []).filter((p) => Number.isFinite(p[x]) && Number.isFinite(p[series[0]]));
  const bandAt = (r) => (band?.half !== undefined ? [r[series[0]] - band.half, r[series[0]] + band.half]
    : band ? [r[band.lo], r[band.hi]] : null);
  const all = [...series.flatMap((k) => rows.map((r) => r[k])), ...dots.map((p) => p[series[0]]),
    ...(band ? rows.flatMap((r) => bandAt(r)) : [])].filter(Number.isFinite).map((v) => v * f);
  let y0 = Math.min(0, ...all), y1 = Math.max(0, ...all);
  if (y1 - y0 < 1e-12) y1 = y0 + 1;
  const yt = niceTicks(y0, y1);
  y0 = Math.min(y0, yt.ticks[0]); y1 = Math.max(y1, yt.ticks[yt.ticks.length - 1]);
  const allX = [...xs, ...dots.map((p) => p[x])];
  const x0 = Math.min(...allX), x1 = Math.max(...allX) === x0 ? x0 + 1 : Math.max(...allX);
  const xt = niceTicks(x0, x1, 6);
  const X = (v) => left + ((v - x0) / (x1 - x0)) * (w - left - right);
  const Y = (v) => top + (1 - (v * f - y0) / (y1 - y0)) * (h - top - bottom);
  const Yd = (v) => top + (1 - (v - y0) / (y1 - y0)) * (h - top - bottom);  // v already in display units
  const ns = "http://www.w3.org/2000/svg";
  const svg = document.createElementNS(ns, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  svg.setAttribute("role", "img");
  svg.setAttribute("aria-label", title);
  const mk = (tag, attrs, text) => {
    const n = document.createElementNS(ns, tag);
    for (const [k, v] of Object.entries(attrs)) n.setAttribute(k, v);
    if (text !== undefined) n.textContent = text;
    svg.append(n);
    return n;
  };
  const xu = xUnit || unitOf(x);
  for (const v of yt.ticks) {
    mk("line", { x1: left, x2: w - right, y1: Yd(v), y2: Yd(v), stroke: v === 0 ? "#8c959f" : "#eaeef2", class: "grid-y" });
    mk("text", { x: left - 4, y: Yd(v) + 4, "font-size": 11, "text-anchor": "end", class: "tick-y" }, v.toFixed(yt.decimals));
  }
  if (type !== "bars") {
    for (const v of xt.ticks.filter((t) => t >= x0 && t <= x1)) {
      mk("line", { x1: X(v), x2: X(v), y1: top, y2: h - bottom, stroke: "#eaeef2", class: "grid-x" });
      mk("text", { x: X(v), y: h - bottom + 14, "font-size": 11, "text-anchor": "middle", class: "tick-x" }, v.toFixed(xt.decimals));
    }
  }
  mk("line", { x1: left, x2: left, y1: top, y2: h - bottom, stroke: "#8c959f" });
  mk("text", { x: 4, y: top - 10, "font-size": 11, class: "unit-y" }, scale.unit);
  mk("text", { x: (left + w) / 2, y: h - 6, "font-size": 11, "text-anchor": "middle" },
    `${x.replace(/_(mm|s|deg)$/, "").replace(/_/g, " ")}${xu ? ` (${xu})` : ""}`);
  if (band && type !== "bars") {
    const upper = rows.map((r, i) => `${X(xs[i]).toFixed(1)},${Y(bandAt(r)[1]).toFixed(1)}`);
    const lower = rows.map((r, i) => `${X(xs[i]).toFixed(1)},${Y(bandAt(r)[0]).toFixed(1)}`).reverse();
    mk("polygon", { points: [...upper, ...lower].join(" "), fill: "#1f6feb", "fill-opacity": 0.15, stroke: "none", class: "band" });
  }
  series.forEach((key, s) => {
    const color = COLORS[s % COLORS.length];
    if (type === "bars") {
      const slot = (w - left - right) / rows.length;
      const bw = Math.max(2, (slot * 0.8) / series.length);
      rows.forEach((r, i) => {
        const v = r[key];
        const bx = left + i * slot + slot * 0.1 + s * bw;
        mk("rect", { x: bx, y: Math.min(Y(v), Y(0)), width: bw, height: Math.abs(Y(v) - Y(0)), fill: color },);
      });
    } else {
      mk("polyline", { points: rows.map((r, i) => `${X(xs[i]).toFixed(1)},${Y(r[key]).toFixed(1)}`).join(" "),
        fill: "none", stroke: color, "stroke-width": 2 });
    }
    mk("rect", { x: left + 8 + s * 190, y: 6, width: 10, height: 10, fill: color });
    mk("text", { x: left + 22 + s * 190, y: 15, "font-size": 11 }, key.replace(/_(mm_s|um|mm|s|ms|deg)$/, "").replace(/_/g, " "));
  });
  for (const p of dots) mk("circle", { cx: X(p[x]), cy: Y(p[series[0]]), r: 3, fill: "#24292f", class: "probe-point" });
  if (dots.length) {
    const lx = left + 8 + series.length * 190;
    mk("circle", { cx: lx + 5, cy: 11, r: 3, fill: "#24292f" });
    mk("text", { x: lx + 14, y: 15, "font-size": 11 }, "probe points");
  }
  return el("figure", { class: "chart", "data-rows": rows.length, "data-series": series.join(","), "data-unit": scale.unit,
    "data-points": dots.length }, svg, el("figcaption", { class: "small" }, title));
}

// The one line a dashboard shows for a finished job: the figure that matters for its kind
// (the worst standoff error before and after, a deviation and its bound), else its first
// figures.
export function headline(job) {
  const r = job.result || job.result_summary;
  if (!r) return "";
  const um = (mm) => `${round(mm * 1000, 3)} µm`;
  const worst = (rows, key) => Math.max(...rows.map((row) => row[key]).filter(Number.isFinite));
  if (job.kind === "closed_loop" && Array.isArray(r.table) && r.table.length) {
    const before = worst(r.table, "standoff_max_before_um"), after = worst(r.table, "standoff_max_after_um");
    const verified = r.verdict?.line ? ` · ${r.verdict.line}` : "";
    if (Number.isFinite(before) && Number.isFinite(after)) {
      return `worst standoff error ${round(before, 3)} µm → ${round(after, 3)} µm over ${r.table.length} traces${verified}`;
    }
  }
  if (job.kind === "reconstruct" && r.deviation) {
    return `deviation max ${um(r.deviation.max_mm)}, rms ${um(r.deviation.rms_mm)}` +
      (r.bound_mm != null ? ` · bound ±${um(r.bound_mm)}` : "") + (r.points_used != null ? ` · ${r.points_used} points` : "");
  }
  if (job.kind === "compensate" && r.max_chord_error_mm != null) {
    return `chord error ≤ ${um(r.max_chord_error_mm)} · standoff ${length(r.standoff_mm)} · ${length(r.length_mm)}` +
      (r.warnings?.length ? ` · ${r.warnings.length} warning${r.warnings.length === 1 ? "" : "s"}` : "");
  }
  if (job.kind === "toolpath" && r.time_s != null) {
    return `estimated ${duration(r.time_s)}` + (r.layer_count != null ? ` · ${counted(r.layer_count, "layers")}` : "") +
      (r.path_mm != null ? ` · path ${length(r.path_mm)}` : "") + (r.pattern ? ` · ${r.pattern}` : "");
  }
  if (job.kind === "slice" && r.layer_count != null) return `${counted(r.layer_count, "layers")}${r.mode ? ` · ${r.mode}` : ""}`;
  return headlineFigures(r).slice(0, 3).map(([n, v, key]) => {
    const raw = key.split(".").reduce((o, k) => o?.[k], r);
    if (Array.isArray(raw)) return counted(raw.length, n);                      // "7 traces", not "Traces: 7 items"
    if (/_count$/.test(key) && Number.isInteger(raw)) return counted(raw, n.replace(/ count$/i, ""));
    return `${n}: ${v}`;
  }).join(" · ");
}

// "7 traces", "1 trace": a count and what it counts, in words.
export function counted(n, what) {
  const words = what.toLowerCase();
  if (n === 1) return `1 ${words.endsWith("s") ? words.slice(0, -1) : words}`;
  return `${n} ${words.endsWith("s") ? words : `${words}s`}`;
}

// Rows of records as a table with units (at most `limit` rows; the rest one click away).
export function recordsTable(rows, limit = 20) {
  const keys = Object.keys(rows[0] || {}).filter((k) => rows[0][k] === null || typeof rows[0][k] !== "object");
  const body = (list) => list.map((r) => el("tr", {}, keys.map((k) => el("td", {}, formatValue(k, r[k])))));
  const table = el("table", { class: "records" },
    el("thead", {}, el("tr", {}, keys.map((k) => el("th", { scope: "col" }, label(k), unitOf(k) ? ` (${unitOf(k)})` : "")))),
    el("tbody", {}, body(rows.slice(0, limit))));
  if (rows.length <= limit) return table;
  return el("div", {}, table, el("details", {}, el("summary", {}, `all ${rows.length} rows`),
    el("table", { class: "records" }, el("tbody", {}, body(rows)))));
}

// The view of a finished job: its curve (if its kind has one) and its per-item records.
export function kindView(job) {
  const spec = CHARTS[job.kind];
  const out = [];
  if (spec && Array.isArray(job.result?.[spec.rows]) && job.result[spec.rows].length) {
    const figure = chart(job.result[spec.rows], spec);
    if (figure) out.push(figure);
    if (job.kind === "closed_loop") out.push(recordsTable(job.result.table, 50));
  }
  if (VIEWS[job.kind] && ["succeeded", "needs_attention"].includes(job.status) && job.result) out.push(VIEWS[job.kind](job));
  return out;
}
