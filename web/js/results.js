// Job results for people: every figure with its unit, read from the field name's suffix
// (_mm, _um, _s, _ms, _deg, _mm_min, _mm3, _mm2), durations as "2 h 18 min", lengths in
// µm when they are below a millimetre, and lists summarised by their length.  The raw
// JSON stays one click away on the job page.
import { el } from "./ui.js";

const UNITS = [
  ["_mm_min", (v) => `${round(v, 4)} mm/min`],
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
  const text = name.replace(/_(mm_min|mm3|mm2|um|mm|ms|s|deg|c)$/, "").replace(/_/g, " ");
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
