// The program preview beside the 3-D view, like a slicer's: a layer slider that draws the
// layers up to k and nothing above (POST /viewer/layer), the legend of move types in the
// view's colours with how many moves of each are drawn, and every layer's z, height and
// estimated time (the one G-code estimator), the current layer marked.
import { duration } from "./results.js";
import { el, guarded } from "./ui.js";

const mm = (v) => (v === null || v === undefined ? "—" : `${Number(v).toFixed(3)} mm`);

function layerText(p, k) {
  const lay = p.layers[k];
  if (!lay) return "";
  return `Layer ${lay.index} (${k + 1} of ${p.layer_count}): z ${mm(lay.z_mm)} · height ${mm(lay.height_mm)} · `
    + `time ${duration(lay.time_s)} · ${lay.moves} moves`;
}

// box: the panel's element; scene: the view's scene (GET /viewer/scene); setLayer(k) -> new scene.
export function renderPreview(box, scene, setLayer) {
  const entries = Object.entries(scene.previews || {});
  if (!entries.length) { box.replaceChildren(); return; }
  const [name, p] = entries[0];
  const k = p.layer;
  const slider = el("input", { type: "range", id: "preview-layer", min: 0, max: Math.max(p.layer_count - 1, 0), step: 1,
    value: k, disabled: p.layer_count < 2, "aria-label": "show the layers up to" });
  const info = el("div", { id: "preview-layer-info", "data-layer": k }, layerText(p, k));
  slider.addEventListener("input", () => { info.textContent = layerText(p, Number(slider.value)); });
  slider.addEventListener("change", () => guarded("Layer", async () => {
    const next = await setLayer(Number(slider.value));
    if (next) renderPreview(box, next, setLayer);
    box.querySelector("#preview-layer")?.focus({ preventScroll: true });
  }));
  const legend = el("ul", { id: "preview-legend", class: "preview-legend", "aria-label": "move types" },
    p.legend.filter((row) => row.moves > 0).map((row) => {
      const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
      swatch.style.backgroundColor = row.color;      // CSSOM: allowed by the pages' style-src 'self'
      return el("li", { "data-type": row.type, "data-color": row.color }, swatch, ` ${row.label}: `,
        el("span", { class: "shown" }, `${row.shown}`), ` of ${row.moves}`);
    }));
  const rows = p.layers.map((lay, i) => el("tr", { "data-layer": i, class: i === k ? "current" : i > k ? "above" : "" },
    el("td", {}, String(lay.index)), el("td", {}, mm(lay.z_mm)), el("td", {}, mm(lay.height_mm)),
    el("td", {}, duration(lay.time_s)), el("td", {}, String(lay.moves))));
  const table = el("div", { class: "preview-layers-box", tabindex: 0, role: "region", "aria-label": "layers of the program" }, el("table", { id: "preview-layers" },
    el("caption", {}, "Layers (greyed: above the slider, not drawn)"),
    el("thead", {}, el("tr", {}, ["layer", "z", "height", "time", "moves"].map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, rows)));
  box.replaceChildren(
    el("h3", {}, `Program preview: ${name}`),
    el("p", { class: "small", id: "preview-total" }, `${p.layer_count} layer(s), estimated ${duration(p.time_s)} in all`),
    el("label", { class: "preview-slider" }, "Layers up to ", slider), info, legend, table);
  const current = box.querySelector(`tr[data-layer="${k}"]`);   // the table scrolls, never the page
  if (current) table.scrollTop = Math.max(0, current.offsetTop - table.clientHeight / 2);
}
