// Home: a dashboard — machines (state, position, the job driving them, its progress), the
// jobs running or queued, and recent results with their headline figures.  Refreshed every
// two seconds; the global STOP is in the header of every page.
import { get } from "./api.js";
import { duration, headline } from "./results.js";
import { el, fmt, guarded, initPage, markReady } from "./ui.js";

const main = initPage("index.html");
const health = el("p", { id: "health", class: "small" }, "Checking the API…");
const machinesBox = el("div", { id: "dash-machines" }, "—");
const activeBox = el("div", { id: "dash-active" }, "—");
const recentBox = el("div", { id: "dash-recent" }, "—");
main.append(
  el("h1", {}, "Conforma"),
  health,
  el("div", { class: "dash" },
    el("section", { "aria-labelledby": "h-machines" }, el("h2", { id: "h-machines" }, "Machines"), machinesBox),
    el("section", { "aria-labelledby": "h-active" }, el("h2", { id: "h-active" }, "Running and queued"), activeBox),
    el("section", { "aria-labelledby": "h-recent" }, el("h2", { id: "h-recent" }, "Recent results"), recentBox)),
  el("section", {},
    el("h2", {}, "Start here"),
    el("ol", {},
      el("li", {}, el("a", { href: "parts.html" }, "Upload a part"), " (STL, OBJ, PLY, OFF, 3MF, GLB)."),
      el("li", {}, el("a", { href: "traces.html" }, "Draw or import traces"), " on it."),
      el("li", {}, el("a", { href: "jobs.html" }, "Run jobs"), ": probe plans, reconstruction, compensation, slicing…"),
      el("li", {}, el("a", { href: "machines.html" }, "Drive machines"), " (mock or real), with an emergency stop.")),
    el("p", { class: "small" }, "API reference: ", el("a", { href: "/docs" }, "/docs"), " · ",
      el("a", { href: "/openapi.json" }, "/openapi.json"))));

const position = (p) => (Array.isArray(p) ? `X ${p[0].toFixed(3)} Y ${p[1].toFixed(3)} Z ${p[2].toFixed(3)} mm` : "position unknown");

function machineRow(m) {
  const program = m.program;
  const progress = program && program.total ? program.executed / program.total : null;
  return el("div", { class: "machine", "data-id": m.id },
    el("div", {}, el("strong", {}, el("a", { href: `machines.html#${m.id}` }, m.name)), " ",
      el("span", { class: `badge ${m.state}`, "data-state": m.state }, m.state),
      el("div", { class: "small mono" }, position(m.position))),
    el("div", { class: "small" }, program
      ? [`${program.executed ?? 0} / ${program.total ?? "?"} lines`, progress !== null ? el("progress", { max: 1, value: progress }) : null]
      : "no program"));
}

function jobLine(job, figures = false) {
  const head = figures ? headline(job) : "";  // a large result comes in brief: its summary
  const took = job.started_at && job.finished_at ? duration((new Date(job.finished_at) - new Date(job.started_at)) / 1000) : null;
  return el("div", { class: "machine", "data-id": job.id },
    el("div", {}, el("a", { href: `jobs.html?job=${job.id}`, title: `${job.kind} ${job.id}` }, el("strong", {}, job.title || job.kind)), " ",
      el("span", { class: `badge ${job.status}` }, job.status),
      el("div", { class: "small headline" }, head || job.message || (job.error ? job.error.detail : ""))),
    el("div", { class: "small" }, job.status === "running" ? el("progress", { max: 1, value: job.progress })
      : (took ? `took ${took}` : fmt.time(job.created_at))));
}

async function refresh() {
  await Promise.all([
    guarded("Machines", async () => {
      const machines = (await get("machines")).items;
      machinesBox.replaceChildren(...(machines.length ? machines.map(machineRow)
        : [el("p", { class: "small" }, "No machine yet: ", el("a", { href: "machines.html" }, "register one"), " (a mock machine needs no hardware).")]));
    }),
    guarded("Jobs", async () => {
      const [running, queued, recent] = await Promise.all([get("jobs?status=running&limit=20"),
        get("jobs?status=queued&limit=20"), get("jobs?top_level=true&limit=8")]);
      const active = [...running.items, ...queued.items];
      activeBox.replaceChildren(...(active.length ? active.map((j) => jobLine(j)) : [el("p", { class: "small" }, "Nothing running.")]),
        el("p", { class: "small" }, `${running.total} running, ${queued.total} queued`));
      const done = recent.items.filter((j) => !["running", "queued"].includes(j.status));
      recentBox.replaceChildren(...(done.length ? done.map((j) => jobLine(j, true)) : [el("p", { class: "small" }, "No finished job yet.")]));
    }),
  ]);
}

const first = Promise.all([guarded("Health", async () => {
  const h = await get("health");
  health.textContent = `API ${h.status}, version ${h.version}, database ${h.database}, queue ${h.queue}.`;
}), refresh()]);
first.then(markReady);
setInterval(refresh, 2000);
document.addEventListener("conforma:stopped", refresh);
