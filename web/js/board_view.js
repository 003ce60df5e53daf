// The result of a board compensate job (compensate with trace_ids) at a glance: a summary
// line (traces, the worst of all, how many are over a tolerance the operator types in), a
// table of the traces, worst first (sortable by any column; 20 rows, then all on request)
// with each trace's worst standoff error of the nominal program (the board reconstruct's
// deviation max along the trace) and of the compensated one (the chord error proved per
// segment: the program follows the reconstructed surface), the nozzle body's clearance,
// the program's estimated time and its downloads, and for the selected trace (a click on
// its row; the worst at first) the single view's chart from the trace's rebuilt samples.
import { download, get } from "./api.js";
import { chart, duration, round } from "./results.js";
import { bandNote, standoffBand, standoffRows } from "./standoff.js";
import { el, guarded } from "./ui.js";

const LIMIT = 20;
const um = (mm) => (Number.isFinite(mm) ? mm * 1000 : null);
const showUm = (v) => (v === null || v === undefined ? "—" : `${round(v, 4)} µm`);

// Columns: [key, heading, value of a row for sorting (numbers; null last), what it is].
const COLUMNS = [
  ["trace", "Trace", (r) => r.name, "the trace's name"],
  ["nominal_error_um", "Nominal error", (r) => r.nominal_error_um,
    "the nominal program's worst standoff error: the largest |deviation| of the reconstructed surface along the trace"],
  ["compensated_error_um", "Compensated error", (r) => r.compensated_error_um,
    "the compensated program's worst standoff error: its chord error, proved per segment"],
  ["clearance_mm", "Clearance", (r) => r.clearance_mm, "the nozzle body's smallest gap to the part (— : no nozzle body checked)"],
  ["time_s", "Time", (r) => r.time_s, "the print program's estimated time"],
];

// One row per trace of the result, with what the board reconstruct says of it.
export function boardRows(job, rebuilt) {
  const rebuiltRows = new Map((rebuilt?.result?.traces || []).map((t) => [t.trace_id, t]));
  return job.result.traces.map((t, index) => {
    const deviation = rebuiltRows.get(t.trace_id)?.deviation;
    return { index, trace_id: t.trace_id, name: t.trace_id, row: t, samples: deviation?.samples || [],
      bound_mm: rebuiltRows.get(t.trace_id)?.bound_mm ?? null,
      nominal_error_um: um(deviation?.max_mm), compensated_error_um: um(t.max_chord_error_mm),
      clearance_mm: t.clearance ? t.clearance.min_mm : null, time_s: null, standoff_mm: t.standoff_mm };
  });
}

function compare(key, descending) {
  const value = COLUMNS.find(([k]) => k === key)[2];
  return (a, b) => {
    const x = value(a), y = value(b);
    if (x === null || x === undefined) return y === null || y === undefined ? a.index - b.index : 1;
    if (y === null || y === undefined) return -1;
    const order = typeof x === "string" ? x.localeCompare(y, undefined, { numeric: true }) : x - y;
    return (descending ? -order : order) || a.index - b.index;
  };
}

function summaryLine(rows, toleranceUm) {
  const worst = rows.reduce((w, r) => (r.nominal_error_um !== null && (w === null || r.nominal_error_um > w.nominal_error_um) ? r : w), null);
  const worstComp = Math.max(...rows.map((r) => r.compensated_error_um).filter(Number.isFinite));
  const parts = [`${rows.length} trace${rows.length === 1 ? "" : "s"}`,
    worst ? `worst nominal program error ${showUm(worst.nominal_error_um)} (${worst.name})` : "no reconstruction figures",
    Number.isFinite(worstComp) ? `worst compensated error ${showUm(worstComp)}` : null];
  if (Number.isFinite(toleranceUm)) {
    const over = (key) => rows.filter((r) => r[key] !== null && r[key] > toleranceUm).length;
    parts.push(`over the ${round(toleranceUm, 4)} µm tolerance: ${over("nominal_error_um")} nominal, ${over("compensated_error_um")} compensated`);
  }
  return parts.filter(Boolean).join(" · ");
}

function standoffChart(selected) {
  const rows = standoffRows(selected.samples, selected.standoff_mm, selected.bound_mm);
  if (rows.length < 2) {
    return el("p", { class: "small", id: "board-no-samples" },
      `trace ${selected.name}: the reconstruct job's result has ${rows.length ? "one sample" : "no samples"} of its deviation; no chart`);
  }
  const plot = chart(rows, { x: "s_mm", ys: ["nominal_program_um", "compensated_um"], band: standoffBand(selected.bound_mm),
    title: `Trace ${selected.name}: standoff along the trace from the reconstructed surface, the nominal program vs the compensated one`
      + bandNote(selected.bound_mm), xUnit: "mm", yUnit: "µm" });
  plot.id = "standoff-plot";
  plot.dataset.trace = selected.trace_id;
  return plot;
}

// The view's contents (the caller puts them in the result-view box).
export async function boardCompensateContents(job) {
  const rebuilt = job.params.reconstruct_job_id ? await get(`jobs/${job.params.reconstruct_job_id}?include=result`).catch(() => null) : null;
  const rows = boardRows(job, rebuilt);
  const urls = new Map((job.artifacts || []).map((a) => [a.name, a.url]));
  const state = { key: "nominal_error_um", descending: true, all: false, tolerance: NaN,
    selected: [...rows].sort(compare("nominal_error_um", true))[0] };
  const named = new Set(), timed = new Set();
  let pending = 0;  // fetches of names and times in flight
  const summary = el("p", { id: "board-summary" });
  const table = el("table", { class: "records", id: "board-traces" });
  const more = el("button", { type: "button", id: "board-all" });
  const chartBox = el("div", { id: "board-chart" });
  const tolerance = el("input", { type: "number", id: "board-tolerance", min: 0, step: "any", placeholder: "µm",
    "aria-label": "tolerance (µm)" });

  async function details(shown) {  // names and program times of the rows on screen, once each
    await Promise.all(shown.map(async (r) => {
      const jobs = [];
      if (!named.has(r.trace_id)) {
        named.add(r.trace_id);
        jobs.push(get(`traces/${r.trace_id}`).then((t) => { r.name = t.name; }).catch(() => null));
      }
      if (!timed.has(r.trace_id)) {
        timed.add(r.trace_id);
        jobs.push(get(`jobs/${job.id}/artifacts/${r.row.print_artifact}/summary`).then((s) => { r.time_s = s.time_s; })
          .catch(() => null));
      }
      await Promise.all(jobs);
    }));
  }

  function downloadButton(name, label) {
    const url = urls.get(name) || `/api/v1/jobs/${job.id}/artifacts/${name}`;
    return el("button", { type: "button", class: "artifact-download", "data-artifact": name, "data-url": url,
      title: `download ${name}`, "aria-label": `download ${name}`,
      onclick: (event) => { event.stopPropagation(); guarded("Download", () => download(url, name)); } }, label);
  }

  function render() {
    const sorted = [...rows].sort(compare(state.key, state.descending));
    const shown = state.all ? sorted : sorted.slice(0, LIMIT);
    summary.textContent = summaryLine(rows, state.tolerance);
    const head = el("tr", {}, COLUMNS.map(([key, heading, , about]) => el("th", { scope: "col", "data-key": key, title: about,
      "aria-sort": key === state.key ? (state.descending ? "descending" : "ascending") : "none" },
    el("button", { type: "button", class: "sort", onclick: () => {
      state.descending = key === state.key ? !state.descending : key !== "trace";
      state.key = key;
      render();
    } }, heading, key === state.key ? (state.descending ? " ▼" : " ▲") : ""))), el("th", { scope: "col" }, "Programs"));
    const over = (v) => Number.isFinite(state.tolerance) && v !== null && v > state.tolerance;
    const body = shown.map((r) => el("tr", { "data-trace": r.trace_id, class: [r === state.selected ? "selected" : "",
      over(r.nominal_error_um) ? "over-nominal" : "", over(r.compensated_error_um) ? "over" : ""].filter(Boolean).join(" ") || null,
    "aria-selected": r === state.selected ? "true" : "false", onclick: () => { state.selected = r; render(); } },
    el("td", { "data-key": "trace" }, r.name),
    el("td", { "data-key": "nominal_error_um" }, showUm(r.nominal_error_um)),
    el("td", { "data-key": "compensated_error_um" }, `≤ ${showUm(r.compensated_error_um)}`),
    el("td", { "data-key": "clearance_mm" }, r.clearance_mm === null ? "—" : `${round(r.clearance_mm, 4)} mm`),
    el("td", { "data-key": "time_s" }, r.time_s === null ? "—" : duration(r.time_s)),
    el("td", { class: "programs" }, downloadButton(r.row.print_artifact, "print"), " ",
      downloadButton(r.row.nominal_artifact, "nominal"))));
    table.replaceChildren(el("thead", {}, head), el("tbody", {}, body));
    table.dataset.sort = `${state.key}:${state.descending ? "desc" : "asc"}`;
    table.dataset.shown = String(shown.length);
    more.hidden = rows.length <= LIMIT;
    more.textContent = state.all ? `show the worst ${LIMIT}` : `show all ${rows.length} traces`;
    chartBox.replaceChildren(standoffChart(state.selected));
    const missing = shown.filter((r) => !named.has(r.trace_id) || !timed.has(r.trace_id));
    if (missing.length) {
      pending += 1;
      details(missing).finally(() => { pending -= 1; render(); });
    }
    // "0" once every row on screen shows its name and time (until then a row shows its id and
    // sorts by it): what a script reading the table waits for
    table.dataset.pending = String(pending);
  }

  more.addEventListener("click", () => { state.all = !state.all; render(); });
  tolerance.addEventListener("input", () => { state.tolerance = tolerance.value === "" ? NaN : Number(tolerance.value); render(); });
  render();
  return [summary, el("label", { class: "small" }, "Tolerance ", tolerance, " µm (counts and marks the traces over it)"),
    table, more, chartBox,
    el("p", { class: "small" }, "Nominal program error: the largest |deviation| of the reconstructed surface along the trace "
      + "(the nominal program keeps the nominal standoff); compensated: the chord error proved per segment of the "
      + "program that follows the reconstructed surface. Click a row for its chart.")];
}
