// SVG -> trace geometries: every <path>, <polyline>, <polygon>, <line>, <circle>,
// <ellipse> and <rect> becomes a polyline sampled by the browser's own geometry
// (getPointAtLength), in SVG user units taken as mm, y flipped (SVG is y-down, the
// part's top view is y-up).  Transforms of ancestor groups are not applied.  Returns [{name, geometry, frame: "xy"}].
const SHAPES = "path, polyline, polygon, line, circle, ellipse, rect";
const SVG_NS = "http://www.w3.org/2000/svg";

export function svgToTraces(text, { stepMm = 0.5, maxPoints = 5000, offset = [0, 0], prefix = "svg" } = {}) {
  const doc = new DOMParser().parseFromString(text, "image/svg+xml");
  if (doc.querySelector("parsererror") || doc.documentElement.nodeName.toLowerCase() !== "svg") {
    throw new Error("the file is not valid SVG (an <svg> document was expected)");
  }
  // Measure inside a live, hidden SVG so that the browser computes path lengths.
  const host = document.createElementNS(SVG_NS, "svg");
  host.style.cssText = "position:absolute;width:0;height:0;visibility:hidden";  // CSSOM: allowed by the CSP
  document.body.append(host);
  const traces = [];
  try {
    doc.querySelectorAll(SHAPES).forEach((shape, index) => {
      const node = document.importNode(shape, false);
      host.append(node);
      const length = node.getTotalLength();
      if (!(length > 0)) { node.remove(); return; }
      const n = Math.min(maxPoints, Math.max(2, Math.ceil(length / stepMm) + 1));
      const points = [];
      for (let i = 0; i < n; i += 1) {
        const p = node.getPointAtLength((length * i) / (n - 1));
        const q = [Number((p.x + offset[0]).toFixed(4)), Number((-p.y + offset[1]).toFixed(4))];
        const last = points[points.length - 1];
        if (!last || last[0] !== q[0] || last[1] !== q[1]) points.push(q);
      }
      node.remove();
      if (points.length >= 2) {
        const name = shape.getAttribute("id") || `${prefix}-${index + 1}`;
        traces.push({ name, frame: "xy", geometry: { type: "polyline", points } });
      }
    });
  } finally {
    host.remove();
  }
  if (!traces.length) throw new Error("the SVG has no drawable path, line or shape");
  return traces;
}
