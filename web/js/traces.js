// Traces: create one from a form, import many (JSON array or SVG), list, open in 3D.
import { del, get, post, upload } from "./api.js";
import { circuitImportSection } from "./circuit_import.js";
import { el, fmt, guarded, initPage, latest, markReady, query, showError, showInfo, viewerPanel } from "./ui.js";

const main = initPage("traces.html");
const left = el("div");
const right = el("section", { id: "viewer-panel" });
main.append(el("h1", {}, "Traces"), el("div", { class: "layout" }, left, right));
const viewer = viewerPanel(right);

const partSelect = el("select", { id: "trace-part", "aria-label": "part" });
left.append(el("section", {}, el("h2", {}, "Part"), partSelect,
  el("span", { class: "small" }, " traces are drawn on this part")));
partSelect.addEventListener("change", () => {
  history.replaceState(null, "", `?part=${encodeURIComponent(partSelect.value)}`);
  refresh();
});

// ---- form ---------------------------------------------------------------------------
function field(id, label, input, hint) {
  input.id = id;
  input.name = id;
  return el("div", { class: "field", "data-field": id }, el("label", { for: id }, label), input,
    hint ? el("div", { class: "hint" }, hint) : null, el("div", { class: "error-text" }));
}
const num = (value, extra = {}) => el("input", { type: "number", step: "any", value, ...extra });
const inputs = {
  name: el("input", { type: "text", required: true, maxlength: 200, value: "trace-1" }),
  type: el("select", {}, ["line", "arc", "polyline", "nurbs"].map((t) => el("option", { value: t }, t))),
  frame: el("select", {}, el("option", { value: "xy" }, "xy (drawn in top view, draped)"), el("option", { value: "3d" }, "3d (points on the surface)")),
  x0: num(0), y0: num(0), x1: num(10), y1: num(0),
  cx: num(0), cy: num(0), radius: num(5, { min: 0 }), start_deg: num(0), end_deg: num(90),
  points: el("textarea", { placeholder: "x, y[, z] per line" }, "0, 0\n5, 2\n10, 0"),
  degree: num(3, { min: 1, max: 10, step: 1 }),
  standoff_mm: num(0.1, { min: 0 }), width_mm: num("", { min: 0 }), feed_mm_min: num("", { min: 0 }),
};
const groups = {
  line: el("div", { class: "row" }, field("x0", "start x", inputs.x0), field("y0", "start y", inputs.y0),
    field("x1", "end x", inputs.x1), field("y1", "end y", inputs.y1)),
  arc: el("div", { class: "row" }, field("cx", "centre x", inputs.cx), field("cy", "centre y", inputs.cy),
    field("radius", "radius (mm)", inputs.radius), field("start_deg", "start (deg)", inputs.start_deg),
    field("end_deg", "end (deg, CCW)", inputs.end_deg)),
  points: el("div", {}, field("points", "points (mm)", inputs.points, "one point per line: x, y or x, y, z")),
  degree: el("div", {}, field("degree", "NURBS degree", inputs.degree)),
};
function showGroups() {
  const t = inputs.type.value;
  groups.line.hidden = t !== "line";
  groups.arc.hidden = t !== "arc";
  groups.points.hidden = !(t === "polyline" || t === "nurbs");
  groups.degree.hidden = t !== "nurbs";
}
inputs.type.addEventListener("change", showGroups);
showGroups();

const form = el("form", { id: "trace-form", onsubmit: onCreate },
  el("div", { class: "row" }, field("name", "name", inputs.name), field("type", "geometry", inputs.type),
    field("frame", "frame", inputs.frame)),
  groups.line, groups.arc, groups.points, groups.degree,
  el("div", { class: "row" }, field("standoff_mm", "standoff (mm)", inputs.standoff_mm),
    field("width_mm", "width (mm)", inputs.width_mm), field("feed_mm_min", "feed (mm/min)", inputs.feed_mm_min)),
  el("button", { type: "submit", class: "primary", id: "create-trace" }, "Create trace"));
left.append(el("section", {}, el("h2", {}, "New trace"), form));

function parsePoints(text) {
  return text.split(/\n+/).map((l) => l.trim()).filter(Boolean).map((line, i) => {
    const values = line.split(/[\s,;]+/).filter(Boolean).map(Number);
    if (values.length < 2 || values.length > 3 || values.some((v) => !Number.isFinite(v))) {
      throw new Error(`points line ${i + 1} ("${line}") must be "x, y" or "x, y, z" numbers`);
    }
    return values;
  });
}
const optional = (input) => (input.value === "" ? undefined : Number(input.value));

function geometry() {
  const t = inputs.type.value;
  if (t === "line") return { type: t, start: [+inputs.x0.value, +inputs.y0.value], end: [+inputs.x1.value, +inputs.y1.value] };
  if (t === "arc") return { type: t, center: [+inputs.cx.value, +inputs.cy.value], radius: +inputs.radius.value, start_deg: +inputs.start_deg.value, end_deg: +inputs.end_deg.value };
  if (t === "polyline") return { type: t, points: parsePoints(inputs.points.value) };
  return { type: t, degree: +inputs.degree.value, control_points: parsePoints(inputs.points.value) };
}

function markFields(err) {
  form.querySelectorAll(".field").forEach((f) => { f.classList.remove("invalid"); f.querySelector(".error-text").textContent = ""; });
  for (const { loc, msg } of err?.fieldErrors || []) {
    const key = loc.split(".").find((p) => inputs[p]) || (loc.includes("geometry") ? { line: "x0", arc: "radius" }[inputs.type.value] || "points" : null);
    const f = key && form.querySelector(`.field[data-field="${key}"]`);
    if (f) { f.classList.add("invalid"); f.querySelector(".error-text").textContent = msg; }
  }
}

async function onCreate(event) {
  event.preventDefault();
  await partsListed;  // a trace created while the page still loads waits for the parts, not "upload a part first"
  if (!partSelect.value) { showError(new Error("upload a part first (Parts page)"), "New trace"); return; }
  let body;
  try {
    body = { name: inputs.name.value, frame: inputs.frame.value, geometry: geometry(),
      standoff_mm: Number(inputs.standoff_mm.value), width_mm: optional(inputs.width_mm), feed_mm_min: optional(inputs.feed_mm_min) };
  } catch (err) { showError(err, "New trace"); return; }
  try {
    const trace = await post(`parts/${partSelect.value}/traces`, body);
    markFields(null);
    showInfo(`Trace "${trace.name}" created: ${trace.length_mm.toFixed(2)} mm long.`);
    await refresh(trace.id);
  } catch (err) {
    markFields(err);
    showError(err, "New trace");
  }
}

// ---- import -------------------------------------------------------------------------
const importFile = el("input", { type: "file", id: "import-file", "aria-label": "traces file to import (JSON or SVG)", accept: ".json,.svg,application/json,image/svg+xml" });
left.append(el("section", {}, el("h2", {}, "Import traces"),
  el("p", { class: "small" }, "A JSON array of traces (the API's trace objects) or an SVG drawing (read by the server: "
    + "transforms, viewBox and units honoured, y up from the page's bottom edge)."),
  el("form", { id: "import-form", onsubmit: onImport }, el("div", { class: "row" }, importFile,
    el("button", { type: "submit", id: "import-button" }, "Import")))));

async function onImport(event) {
  event.preventDefault();
  const file = importFile.files[0];
  if (!file) { showError(new Error("choose a .json or .svg file"), "Import"); return; }
  await partsListed;  // as in onCreate
  if (!partSelect.value) { showError(new Error("upload a part first"), "Import"); return; }
  const text = await file.text();
  let items;
  if (/\.svg$/i.test(file.name) || text.trimStart().startsWith("<")) {
    await guarded(`Import of ${file.name}`, async () => {
      const body = new FormData();
      body.append("files", file, file.name);
      // a drawing in the part's own coordinates: its (0, 0) is the part's
      body.append("options", JSON.stringify({ format: "svg", anchor: "file_origin" }));
      const result = await upload(`parts/${partSelect.value}/circuits:import`, body);
      showInfo(`${result.traces.length} trace(s) imported from ${file.name}.`);
      await refresh();
    });
    return;
  }
  try {
    if (/\.json$/i.test(file.name)) {
      const doc = JSON.parse(text);
      items = Array.isArray(doc) ? doc : Array.isArray(doc.items) ? doc.items : [doc];
    } else {
      throw new Error(`wrong file type "${file.name}": expected .json or .svg`);
    }
  } catch (err) {
    showError(err instanceof SyntaxError ? new Error(`"${file.name}" is not valid JSON: ${err.message}`) : err, "Import");
    return;
  }
  await guarded(`Import of ${file.name}`, async () => {
    const page = await post(`parts/${partSelect.value}/traces:import`, items);
    showInfo(`${page.total} trace(s) imported from ${file.name}.`);
    await refresh();
  });
}

// ---- list ---------------------------------------------------------------------------
const tbody = el("tbody", { id: "traces-body" });
left.append(circuitImportSection({ partSelect, partsListed: () => partsListed, getPart: (id) => get(`parts/${id}`),
  onDone: () => refresh(), viewer, viewerBox: right }));

left.append(el("section", {}, el("h2", {}, "Traces on this part"),
  el("table", { id: "traces-table" }, el("thead", {}, el("tr", {},
    ["Name", "Net", "Length", "z range (mm)", "Standoff", ""].map((h) => el("th", {}, h)))), tbody)));

// What a trace carries: its net (imported copper), "pad probe ring" (probed, never printed), else "—".
const netOf = (trace) => trace.source?.net || (trace.source?.role === "pad_probe" ? "pad probe ring" : "—");

function row(trace) {
  const tr = el("tr", { "data-id": trace.id },
    el("td", { title: trace.id }, el("strong", {}, trace.name)),
    el("td", { class: "net" }, netOf(trace)),
    el("td", {}, fmt.mm(trace.length_mm, 2)),
    el("td", {}, trace.z_range.map((z) => z.toFixed(3)).join(" … ")),
    el("td", {}, fmt.mm(trace.standoff_mm, 2)),
    el("td", {},
      el("a", { href: `jobs.html?kind=probe_plan&trace_id=${encodeURIComponent(trace.id)}` }, "Probe plan"), " ",
      el("button", { onclick: () => viewer.show({ part_id: trace.part_id }) }, "3D"), " ",
      el("button", { class: "danger", onclick: () => guarded(`Delete ${trace.name}`, async () => {
        await del(`traces/${trace.id}`); showInfo(`Trace "${trace.name}" deleted.`); await refresh();
      }) }, "Delete")));
  return tr;
}

async function loadParts() {
  await guarded("Parts", async () => {
    const [page, machines] = await Promise.all([get("parts?limit=500"), get("machines").catch(() => ({ items: [] }))]);
    // a mock's as-made part is the hidden truth it probes, not where traces are drawn: never the default
    const asMade = new Set(machines.items.map((m) => m.mock?.true_part_id).filter(Boolean));
    const wanted = query("part") || page.items.find((p) => !asMade.has(p.id))?.id;
    const repeated = new Set(page.items.map((p) => p.name).filter((n, i, all) => all.indexOf(n) !== i));
    partSelect.replaceChildren(...page.items.map((p) => el("option", { value: p.id, selected: p.id === wanted, title: p.id },
      (repeated.has(p.name) ? `${p.name} (uploaded ${fmt.time(p.created_at)})` : p.name) + (asMade.has(p.id) ? " — a mock's as-made part" : ""))));
    if (!page.items.length) partSelect.append(el("option", { value: "" }, "no parts yet: upload one first"));
  });
}

const tracesLatest = latest();  // the part changed quickly: only the newest part's traces are shown

async function refresh(highlight) {
  const current = tracesLatest();
  if (!partSelect.value) { tbody.replaceChildren(); return; }
  await guarded("Traces", async () => {
    const page = await get(`parts/${partSelect.value}/traces?limit=1000`);
    if (!current()) return;
    tbody.replaceChildren(...page.items.map(row));
    if (!page.items.length) tbody.append(el("tr", {}, el("td", { colspan: 6, class: "small" }, "No traces yet.")));
    if (highlight) tbody.querySelector(`tr[data-id="${highlight}"]`)?.classList.add("selected");
  });
}

document.addEventListener("conforma:key", async () => { await loadParts(); await refresh(); });
const partsListed = loadParts();
await partsListed;
await refresh();
markReady();
