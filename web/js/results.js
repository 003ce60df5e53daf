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
};
const COLORS = ["#cf222e", "#1a7f37", "#1f6feb", "#9a6700"];

function unitOf(name) {
  const unit = UNITS.find(([suffix]) => name.endsWith(suffix));
  return unit ? unit[0].slice(1).replace("mm_s", "mm/s").replace("um", "µm").replace("deg", "°") : "";
}

// An SVG chart of `rows` (objects): axes with min/max ticks, a legend with units.
export function chart(rows, { x, ys, type = "line", title = "", xUnit = "", yUnit = "" }) {
  const series = ys.filter((k) => rows.length && typeof rows[0][k] === "number");
  if (!series.length || rows.length < 1) return null;
  const w = 640, h = 220, left = 56, right = 12, top = 26, bottom = 34;
  const xs = rows.map((r, i) => (typeof r[x] === "number" ? r[x] : i));
  const all = series.flatMap((k) => rows.map((r) => r[k])).filter(Number.isFinite);
  let y0 = Math.min(0, ...all), y1 = Math.max(0, ...all);
  if (y1 - y0 < 1e-12) y1 = y0 + 1;
  const x0 = Math.min(...xs), x1 = Math.max(...xs) === x0 ? x0 + 1 : Math.max(...xs);
  const X = (v) => left + ((v - x0) / (x1 - x0)) * (w - left - right);
  const Y = (v) => top + (1 - (v - y0) / (y1 - y0)) * (h - top - bottom);
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
  const yu = yUnit || unitOf(series[0]);
  const xu = xUnit || unitOf(x);
  mk("line", { x1: left, x2: w - right, y1: Y(0), y2: Y(0), stroke: "#8c959f" });
  mk("line", { x1: left, x2: left, y1: top, y2: h - bottom, stroke: "#8c959f" });
  for (const v of [y0, y1]) mk("text", { x: left - 4, y: Y(v) + 4, "font-size": 11, "text-anchor": "end" }, `${round(v, 3)}`);
  mk("text", { x: 4, y: top - 10, "font-size": 11 }, yu);
  mk("text", { x: left, y: h - 8, "font-size": 11 }, `${round(x0, 4)}`);
  mk("text", { x: w - right, y: h - 8, "font-size": 11, "text-anchor": "end" }, `${round(x1, 4)} ${xu}`.trim());
  mk("text", { x: (left + w) / 2, y: h - 8, "font-size": 11, "text-anchor": "middle" }, x.replace(/_/g, " "));
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
  return el("figure", { class: "chart", "data-rows": rows.length, "data-series": series.join(",") },
    svg, el("figcaption", { class: "small" }, title));
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
