// Home: what the service is, whether it is healthy, and where to go.
import { get } from "./api.js";
import { el, guarded, initPage, markReady } from "./ui.js";

const main = initPage("index.html");
const health = el("p", { id: "health" }, "Checking the API…");
main.append(
  el("h1", {}, "Conforma"),
  el("section", {},
    el("p", {}, "Plan, measure and compensate toolpaths for printing electronics onto curved parts."),
    health,
    el("ol", {},
      el("li", {}, el("a", { href: "parts.html" }, "Upload a part"), " (STL, OBJ, PLY, OFF, 3MF, GLB)."),
      el("li", {}, el("a", { href: "traces.html" }, "Draw or import traces"), " on it."),
      el("li", {}, el("a", { href: "jobs.html" }, "Run jobs"), ": probe plans, reconstruction, compensation, slicing…"),
      el("li", {}, el("a", { href: "machines.html" }, "Drive machines"), " (mock or real), with an emergency stop.")),
    el("p", { class: "small" }, "API reference: ", el("a", { href: "/docs" }, "/docs"), " · ",
      el("a", { href: "/openapi.json" }, "/openapi.json"))),
  el("section", { id: "counts" }, el("h2", {}, "At a glance"), el("div", { id: "count-body" }, "—")));

const ready = [guarded("Health", async () => {
  const h = await get("health");
  health.textContent = `API ${h.status}, version ${h.version}, database ${h.database}, queue ${h.queue}.`;
}), guarded("Summary", async () => {
  const [parts, jobs] = await Promise.all([get("parts?limit=1"), get("jobs?limit=1")]);
  document.getElementById("count-body").textContent = `${parts.total} part(s), ${jobs.total} job(s).`;
})];
Promise.all(ready).then(markReady);
