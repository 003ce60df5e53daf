// Circuit import (KiCad, Gerber, Excellon, DXF, SVG): preview with a dry run, then accept.
// The preview draws the mapped circuit in 3-D on the part (the page's viewer: draped traces,
// warned traces in red, pads and areas as patches, the pads' probe rings) and in top view
// over the part's outline, and lists each trace's length, stretch and the warnings, a page
// of PAGE_ROWS at a time (Prev / Next with "a-b of N": a real board has thousands of each);
// nothing is stored until "Accept".
import { upload } from "./api.js";
import { el, fmt, guarded, showError, showInfo } from "./ui.js";

const SVG_NS = "http://www.w3.org/2000/svg";
export const PAGE_ROWS = 50;   // warnings and trace rows shown at a time

function svgEl(tag, attrs = {}) {
  const node = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  return node;
}

// Top-view drawing (mm, y up) of the dry run: traces as polylines, pads and areas as outlines.
function previewDrawing(result, bounds) {
  const [[x0, y0], [x1, y1]] = bounds;
  const pad = 0.05 * Math.max(x1 - x0, y1 - y0, 1);
  const svg = svgEl("svg", { id: "circuit-preview", viewBox: `${x0 - pad} ${-(y1 + pad)} ${x1 - x0 + 2 * pad} ${y1 - y0 + 2 * pad}`,
    width: "100%", height: "260", class: "circuit-preview" });
  svg.append(svgEl("rect", { x: x0, y: -y1, width: x1 - x0, height: y1 - y0, fill: "#eef", stroke: "#99a", "stroke-width": pad / 20 }));
  for (const t of result.traces) {
    const pts = t.trace?.nominal?.points || null;
    const path = pts ? pts.map(([x, y]) => `${x},${-y}`).join(" ") : null;
    if (path) svg.append(svgEl("polyline", { points: path, fill: "none", stroke: t.on_part ? "#c60" : "#d00",
      "stroke-width": Math.max(t.source.width_mm || 0.2, pad / 40) }));
  }
  for (const p of result.pads) {
    svg.append(svgEl("polygon", { points: p.outline_xy_mm.map(([x, y]) => `${x},${-y}`).join(" "),
      fill: p.on_part ? "#c60" : "#d00", "fill-opacity": 0.6 }));
  }
  for (const a of result.areas) {
    // the exterior and its holes as one path, filled even-odd: the holes stay empty
    const rings = [a.exterior_xy_mm, ...(a.holes_xy_mm || [])];
    const d = rings.map((r) => "M" + r.map(([x, y]) => `${x},${-y}`).join("L") + "Z").join(" ");
    svg.append(svgEl("path", { d, fill: "#c60", "fill-opacity": 0.3, "fill-rule": "evenodd" }));
  }
  return svg;
}

// One paged list: "<label> a-b of N" with Prev / Next; render(items) draws the rows of one page
// into the container made by wrap(rows). ids: `${id}-count`, `${id}-prev`, `${id}-next`.
function pagedList(id, label, items, total, wrap, render) {
  const count = el("span", { id: `${id}-count`, class: "small" });
  const prev = el("button", { type: "button", id: `${id}-prev` }, "Prev");
  const next = el("button", { type: "button", id: `${id}-next` }, "Next");
  const holder = el("div");
  let offset = 0;
  function draw() {
    const page = items.slice(offset, offset + PAGE_ROWS);
    count.textContent = items.length
      ? `${label} ${offset + 1}–${offset + page.length} of ${total}` : `${label}: none`;
    prev.disabled = offset === 0;
    next.disabled = offset + PAGE_ROWS >= items.length;
    holder.replaceChildren(wrap(page.map(render)));
  }
  prev.addEventListener("click", () => { offset = Math.max(0, offset - PAGE_ROWS); draw(); });
  next.addEventListener("click", () => { offset += PAGE_ROWS; draw(); });
  draw();
  return el("div", { id: `${id}-pages`, class: "paged" }, el("div", { class: "row" }, count, " ", prev, " ", next), holder);
}

// A section for the traces page: partSelect gives the part; partsListed() the promise of its
// options (an import sent while the page still lists the parts waits for them, not "upload a
// part first"); onDone(result) after an accepted import.
// viewer / viewerBox (optional): the page's viewerPanel and its container (its view id).
export function circuitImportSection({ partSelect, partsListed = () => Promise.resolve(), getPart, onDone, viewer,
  viewerBox }) {
  const file = el("input", { type: "file", id: "circuit-file", multiple: true, "aria-label": "circuit files (KiCad, Gerber, Excellon, DXF, SVG)",
    accept: ".kicad_pcb,.gbr,.ger,.gtl,.gbl,.drl,.xln,.dxf,.svg" });
  const num = (id, value) => el("input", { type: "number", step: "any", id, value, class: "narrow" });
  const inputs = {
    // empty origin: the board's centre goes over the middle of the part (the server's default)
    ox: Object.assign(num("circuit-origin-x", ""), { placeholder: "part centre" }),
    oy: Object.assign(num("circuit-origin-y", ""), { placeholder: "part centre" }), rot: num("circuit-rotation", 0),
    mirror: el("input", { type: "checkbox", id: "circuit-mirror" }),
    mapping: el("select", { id: "circuit-mapping" }, el("option", { value: "project" }, "project (vertical)"),
      el("option", { value: "wrap" }, "wrap (length-preserving)")),
    layers: el("input", { type: "text", id: "circuit-layers", placeholder: "F.Cu / DXF layers, comma separated" }),
    standoff: num("circuit-standoff", 0.1),
  };
  const output = el("div", { id: "circuit-result" });
  const accept = el("button", { type: "button", id: "circuit-accept", disabled: true }, "Accept (store the traces)");

  function options(dryRun, view) {
    const layers = inputs.layers.value.split(",").map((s) => s.trim()).filter(Boolean);
    const origin = inputs.ox.value !== "" && inputs.oy.value !== ""
      ? { origin_mm: [Number(inputs.ox.value), Number(inputs.oy.value)] } : {};
    return { ...origin, rotation_deg: Number(inputs.rot.value),
      mirror: inputs.mirror.checked, mapping: inputs.mapping.value, standoff_mm: Number(inputs.standoff.value),
      layers: layers.length ? layers : null, dry_run: dryRun, ...(dryRun && view ? { view_id: view } : {}) };
  }

  // The page's 3-D view (opened on demand): its view id, or null when the view is off.
  async function viewId() {
    if (!viewer || !viewerBox) return null;
    try {
      return (await viewer.ensureFrame()) ? viewerBox.dataset.view || null : null;
    } catch {
      return null;
    }
  }

  // Open the 3-D view as soon as files are chosen, so it is connected when the preview draws.
  file.addEventListener("change", () => { viewId(); });

  async function send(dryRun) {
    if (!file.files.length) throw new Error("choose one or more circuit files");
    await partsListed();
    if (!partSelect.value) throw new Error("upload a part first");
    const form = new FormData();
    for (const f of file.files) form.append("files", f, f.name);
    form.append("options", JSON.stringify(options(dryRun, dryRun ? await viewId() : null)));
    return upload(`parts/${partSelect.value}/circuits:import`, form);
  }

  function show(result, part) {
    const warned = new Set(result.warnings.flatMap((w) => w.traces || []));
    const totals = result.totals || {};
    const traceRow = (t) => el("tr", {},
      el("td", { class: "small" }, t.name), el("td", {}, t.source.net || "—"), el("td", {}, fmt.mm(t.source.width_mm, 3)),
      el("td", {}, fmt.mm(t.layout_length_mm, 3)), el("td", {}, fmt.num(t.stretch, 5)), el("td", {}, t.on_part ? "yes" : "NO"),
      el("td", {}, warned.has(t.index) ? "warning" : ""));
    const drawn = result.preview?.drawn;
    const in3d = el("p", { id: "circuit-preview-3d", class: "small", "data-drawn": drawn ? "yes" : "no" }, drawn
      ? `3-D preview in the view on the right: ${result.traces.filter((t) => t.trace).length} traces draped on the part `
        + `(blue; ${warned.size} named by a warning drawn in red), ${result.pads.length} pads and ${result.areas.length} `
        + `areas as patches on the surface (red: off the part), ${result.probe_paths.length} probe rings (grey points).`
      : `No 3-D preview: ${result.preview?.reason || "the 3D view is not open"} (the top view below still shows it).`);
    output.replaceChildren(
      in3d,
      el("p", { class: "small" }, result.files.map((f) => `${f.file}: ${f.format}, ${f.units}, ${f.traces} traces, ${f.pads} pads, ${f.areas} areas`).join("; ")),
      previewDrawing(result, part ? part.bounds.map((b) => b.slice(0, 2)) : [[0, 0], [100, 100]]),
      pagedList("circuit-warnings", "warnings", result.warnings, totals.warnings ?? result.warnings.length,
        (rows) => el("ul", { id: "circuit-warnings" }, rows), (w) => el("li", { class: "small" }, `${w.kind}: ${w.message}`)),
      pagedList("circuit-rows", "traces", result.traces, totals.traces ?? result.traces.length,
        (rows) => el("table", {}, el("thead", {}, el("tr", {}, ["trace", "net", "width", "layout length", "stretch", "on part", "3-D"].map((h) => el("th", {}, h)))),
          el("tbody", {}, rows)), traceRow));
  }

  async function preview(event) {
    event.preventDefault();
    await guarded("Circuit preview", async () => {
      const result = await send(true);
      show(result, getPart ? await getPart(partSelect.value) : null);
      if (viewerBox && result.preview?.drawn) viewerBox.dataset.generation = result.preview.generation;
      accept.disabled = false;
      showInfo(`Preview: ${result.totals?.traces ?? result.traces.length} traces, ${result.totals?.pads ?? result.pads.length} pads, `
        + `${result.totals?.warnings ?? result.warnings.length} warning(s).`);
    });
  }

  accept.addEventListener("click", () => guarded("Circuit import", async () => {
    const result = await send(false);
    accept.disabled = true;
    showInfo(`${result.traces.length} trace(s) stored (import ${result.import_id}).`);
    if (onDone) await onDone(result);
  }).catch((err) => showError(err, "Circuit import")));

  return el("section", {}, el("h2", {}, "Import a circuit"),
    el("p", { class: "small" }, "KiCad .kicad_pcb, Gerber + Excellon, DXF or SVG, placed on the part (origin, rotation, mirror) "
      + "and projected or wrapped. Preview first: nothing is stored until you accept."),
    el("form", { id: "circuit-form", onsubmit: preview },
      el("div", { class: "row" }, file),
      el("div", { class: "row" }, el("label", {}, "origin x ", inputs.ox), el("label", {}, " y ", inputs.oy),
        el("label", {}, " rotation (deg) ", inputs.rot), el("label", {}, " mirror ", inputs.mirror)),
      el("div", { class: "row" }, el("label", {}, "mapping ", inputs.mapping), el("label", {}, " layers ", inputs.layers),
        el("label", {}, " standoff (mm) ", inputs.standoff)),
      el("div", { class: "row" }, el("button", { type: "submit", id: "circuit-preview-button" }, "Preview (dry run)"), " ", accept)),
    output);
}
