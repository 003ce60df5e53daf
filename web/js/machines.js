// Machines: register (mock or real port), connect, live state, homed and position, the
// running program's line, elapsed time and time left, pause / resume, rename, manual control
// with a live console (machine_console.js), the head on the path in 3-D while it prints
// (machine_view.js), and a big emergency stop.  Buttons follow the machine's state.  The page polls the machines' status once a second.
import { ApiError, get, patch, post } from "./api.js";
import { dispenseSection } from "./machine_dispense.js";
import { manualControls } from "./machine_console.js";
import { loadPrograms, programList } from "./machine_programs.js";
import { headView } from "./machine_view.js";
import { duration } from "./results.js";
import { el, guarded, initPage, markReady, showError, showInfo } from "./ui.js";

const POLL_MS = 1000;
const PROGRAMS_MS = 15000;
const main = initPage("machines.html");
const unavailable = el("section", { id: "machines-unavailable", hidden: true });
const list = el("div", { id: "machines-list" });
main.append(el("h1", {}, "Machines"), unavailable);

// ---- register -------------------------------------------------------------------------
const f = {
  name: el("input", { id: "m-name", value: "mock-1", required: true, maxlength: 200 }),
  port: el("input", { id: "m-port", value: "mock://", required: true }),
  dialect: el("select", { id: "m-dialect" }, el("option", { value: "marlin" }, "marlin"), el("option", { value: "grbl" }, "grbl")),
  baudrate: el("input", { id: "m-baud", type: "number", value: 115200 }),
  truePart: el("select", { id: "m-true-part" }, el("option", { value: "" }, "(none)")),
  noise: el("input", { id: "m-noise", type: "number", step: "any", value: 0, min: 0 }),
  timeScale: el("input", { id: "m-time-scale", type: "number", step: "any", value: 0, min: 0 }),
};
const wrap = (id, label, input) => el("div", { class: "field" }, el("label", { for: id }, label), input);
const mockBox = el("fieldset", { id: "mock-settings" }, el("legend", {}, "Mock machine (port mock://)"),
  el("div", { class: "row" }, wrap("m-true-part", "as-made part", f.truePart), wrap("m-noise", "probe noise (mm)", f.noise),
    wrap("m-time-scale", "time scale (1 = real time, 0 = fast)", f.timeScale)));
const registerForm = el("form", { id: "register-form", onsubmit: onRegister },
  el("div", { class: "row" }, wrap("m-name", "name", f.name), wrap("m-port", "port", f.port),
    wrap("m-dialect", "dialect", f.dialect), wrap("m-baud", "baud rate", f.baudrate)),
  mockBox, el("button", { type: "submit", class: "primary", id: "register-machine" }, "Register machine"));
const registerSection = el("section", {}, el("h2", {}, "Register a machine"), registerForm);
main.append(registerSection, list);
const head = headView(main);
f.port.addEventListener("input", () => { mockBox.hidden = !f.port.value.startsWith("mock://"); });

async function onRegister(event) {
  event.preventDefault();
  const body = { name: f.name.value, port: f.port.value.trim(), dialect: f.dialect.value, baudrate: Number(f.baudrate.value) };
  if (body.port.startsWith("mock://")) {
    body.mock = { probe_noise_mm: Number(f.noise.value), time_scale: Number(f.timeScale.value) };
    if (f.truePart.value) body.mock.true_part_id = f.truePart.value;
  }
  await guarded("Register", async () => {
    const m = await post("machines", body);
    showInfo(`Machine "${m.name}" registered.`);
    await refresh();
  });
}

// ---- cards with live status --------------------------------------------------------------
const cards = new Map();

function position(m) {
  if (!m.position && m.state === "error") return "position unknown — after an emergency stop or a fault: Connect, then Home";
  if (!m.position) return "position unknown";
  return ["X", "Y", "Z"].map((a, i) => `${a} ${Number(m.position[i] ?? 0).toFixed(3)}`).join("   ") +
    (m.position.length > 3 ? `   ${m.position.slice(3).map((v) => Number(v).toFixed(2)).join(" ")}` : "");
}

function act(m, action, label) {
  return el("button", { type: "button", class: `act-${action}`, onclick: () => guarded(`${label} ${m.name}`, async () => {
    const fresh = await post(`machines/${m.id}/${action}`);
    update(fresh);
    if (action === "stop") showInfo(`EMERGENCY STOP sent to ${m.name}: state ${fresh.state}.`, 10000);
  }) }, label);
}

function card(m) {
  const state = el("span", { class: `badge ${m.state}`, "data-state": m.state }, m.state);
  const homed = el("span", { class: "badge homed" });
  const title = el("span", { class: "machine-name" }, m.name);
  const rename = el("button", { type: "button", class: "act-rename small", "aria-label": `rename ${m.name}`,
    onclick: () => guarded(`Rename ${m.name}`, async () => {
      const name = window.prompt(`New name for ${m.name}`, m.name);
      if (!name || name === m.name) return;
      const fresh = await patch(`machines/${m.id}`, { name });
      m.name = fresh.name;
      title.textContent = fresh.name;
      update(fresh);
    }) }, "Rename");
  const pos = el("div", { class: "pos" }, position(m));
  const prog = el("div", { class: "small program" });
  const outputs = el("div", { class: "small outputs" });
  const controller = el("div", { class: "small controller", "aria-live": "polite" });
  const unlock = el("button", { type: "button", class: "act-unlock", hidden: true,
    onclick: () => guarded(`Unlock ${m.name}`, async () => {
      if (!window.confirm(`Clear the alarm lock of ${m.name} ($X)? Check the machine first: after an alarm its position may be wrong (home when you can).`)) return;
      update(await post(`machines/${m.id}/unlock`, { confirm: true }));
    }) }, "Unlock ($X)");
  const estop = el("button", { class: "estop", "data-machine": m.id, title: "Emergency stop (out of band: M112 / grbl reset)",
    onclick: () => guarded(`EMERGENCY STOP ${m.name}`, async () => {
      const fresh = await post(`machines/${m.id}/stop`);
      update(fresh);
      showInfo(`EMERGENCY STOP sent to ${m.name}: state ${fresh.state}.`, 10000);
    }) }, "■ Emergency stop");
  const bar = el("progress", { class: "print-progress", max: 1, value: 0, hidden: true, "aria-label": `print progress on ${m.name}` });
  const programs = el("div", { class: "programs-body" }, programList(m, shownPrograms, () => refresh()));
  const buttons = { connect: act(m, "connect", "Connect"), disconnect: act(m, "disconnect", "Disconnect"),
    pause: act(m, "pause", "Pause"), resume: act(m, "resume", "Resume") };
  const manual = manualControls(m, { update, onRemoved: () => forget(m.id) });
  const dispense = dispenseSection(m, update);
  const node = el("section", { class: "machine-card", "data-id": m.id },
    el("h2", {}, title, " ", state, " ", homed, " ", rename),
    el("div", { class: "small mono", title: m.id }, `${m.port} · ${m.dialect}${m.firmware ? ` · ${m.firmware}` : ""}`),
    pos, controller, unlock, prog, outputs, bar, estop,
    el("div", { class: "row" }, ...Object.values(buttons)),
    el("details", { class: "programs", open: true }, el("summary", {}, "Programs"), programs),
    dispense.node, manual.node);
  cards.set(m.id, { node, state, homed, pos, prog, outputs, bar, programs, controller, unlock, buttons, manual, dispense,
    machine: m, actedAt: -Infinity });
  update(m, performance.now());
  return node;
}

function forget(id) {
  const c = cards.get(id);
  if (!c) return;
  c.manual.dispose();
  c.node.remove();
  cards.delete(id);
}

// `sentAt`: when the poll that read `m` was sent (performance.now() ms); none for an action's
// answer.  A poll sent before an action's answer was shown read the machine as it was before
// the action: it would turn the card back (Connect answered "idle", then "disconnected").
function update(m, sentAt = Infinity) {
  const c = cards.get(m.id);
  if (!c) return;
  if (sentAt < c.actedAt) return;
  if (sentAt === Infinity) c.actedAt = performance.now();
  c.machine = m;
  c.state.className = `badge ${m.state}`;
  c.state.dataset.state = m.state;
  c.state.textContent = m.state;
  // homed: the host's record since the connection (Marlin, grbl), the controller's (LinuxCNC)
  c.homed.hidden = m.homed == null;
  c.homed.dataset.homed = String(m.homed);
  c.homed.className = `badge homed ${m.homed ? "idle" : "paused"}`;
  c.homed.textContent = m.homed ? "homed" : "not homed";
  c.homed.title = m.homed ? "homed since this connection" : "not homed since this connection: positions are not trusted until Home";
  const b = c.buttons;
  const connected = m.state !== "disconnected";
  b.connect.disabled = connected && m.state !== "error";
  b.disconnect.disabled = !connected;
  b.pause.disabled = m.state !== "printing";
  b.resume.disabled = m.state !== "paused";
  c.manual.setState(m);
  c.dispense.update(m);
  c.pos.textContent = position(m);
  // the firmware's own state (grbl): an Alarm, Hold, Door or Check refuses motion until cleared
  const k = m.controller;
  c.controller.textContent = k ? `controller: ${k.detail}${k.reason ? ` (${k.reason})` : ""}${k.clear ? ` — to clear: ${k.clear}` : ""}` : "";
  c.controller.dataset.state = k ? k.state : "";
  c.unlock.hidden = !(k && k.state === "Alarm");
  // process outputs the host could not switch off (a Marlin e-stop leaves fans on until the reconnect)
  const o = m.outputs;
  c.outputs.textContent = o && !o.sent && o.why ? `outputs: ${o.why}` : "";
  const p = m.program;
  const line = p ? (p.executed ?? p.line) : null;
  c.prog.dataset.state = p ? (p.state || "printing") : "";
  if (p && p.state === "interrupted") {
    // the job stopped mid-program (a lost link, a dead process) and holds the machine until an operator decides
    c.prog.textContent = `interrupted at line ${line ?? "?"} of ${p.total ?? "?"} — its print job waits: ` +
      `resume or abandon` + (p.resume_line != null ? ` (a resume starts at line ${p.resume_line})` : "");
    c.prog.title = `${p.message || ""} (job ${p.job_id || "?"})`;
  } else {
    c.prog.textContent = p ? `program: line ${line ?? "?"} of ${p.total ?? "?"}` +
      (p.total ? ` (${Math.round((100 * (line ?? 0)) / p.total)} %)` : "") +
      (p.elapsed_s != null ? ` · elapsed ${duration(p.elapsed_s)} · left ${p.eta_s != null ? `about ${duration(p.eta_s)}` : "estimating…"}` : "") :
      (m.held_by ? "a job holds the machine" : "no program running");
    c.prog.title = p?.job_id ? `job ${p.job_id}` : m.held_by ? `job ${m.held_by}` : "";
  }
  c.bar.hidden = !(p && p.total);
  if (p && p.total) c.bar.value = (line ?? 0) / p.total;
}

// ---- the program list (shared by every card, reloaded every PROGRAMS_MS) ----------------
let shownPrograms = [];
async function refreshPrograms() {
  try {
    shownPrograms = await loadPrograms();
  } catch (err) {
    if (!err.offline) showError(err, "Programs");
    return;
  }
  for (const c of cards.values()) c.programs.replaceChildren(programList(c.machine, shownPrograms, () => refresh()));
}

let available = true;
async function refresh() {
  try {
    const sentAt = performance.now();
    const page = await get("machines");
    available = true;
    unavailable.hidden = true;
    registerSection.hidden = false;
    const ids = new Set(page.items.map((m) => m.id));
    for (const id of [...cards.keys()]) if (!ids.has(id)) forget(id);
    for (const m of page.items) {
      if (cards.has(m.id)) update(m, sentAt);
      else list.append(card(m));
    }
    if (!page.items.length && !list.querySelector(".empty")) list.append(el("p", { class: "small empty" }, "No machines registered yet."));
    if (page.items.length) list.querySelector(".empty")?.remove();
    head.follow(page.items);
  } catch (err) {
    if (err instanceof ApiError && err.status === 404) {
      available = false;
      unavailable.hidden = false;
      registerSection.hidden = true;
      unavailable.replaceChildren(el("h2", {}, "Machines are not available"),
        el("p", {}, "This server has no machines API (/api/v1/machines answered 404)."));
      return;
    }
    if (!err.offline) showError(err, "Machines");
  }
}

async function loadParts() {
  await guarded("Parts", async () => {
    const parts = await get("parts?limit=200");
    f.truePart.append(...parts.items.map((p) => el("option", { value: p.id, title: p.id }, p.name)));
  });
}

document.addEventListener("conforma:key", () => { refresh(); refreshPrograms(); });
await loadParts();
await refreshPrograms();
await refresh();
markReady();
setInterval(() => { if (available) refresh(); }, POLL_MS);
setInterval(() => { if (available) refreshPrograms(); }, PROGRAMS_MS);

