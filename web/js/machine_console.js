// A machine's manual control: home, jog by a chosen step (buttons or the keyboard), the live
// console (every line sent and received, filterable, polled from /console) with a command
// line, and removing the machine.  The server refuses motion while a program holds the
// machine; the buttons follow the machine's state (setState).
import { del, get, post } from "./api.js";
import { el, guarded, showInfo } from "./ui.js";

const CONSOLE_MS = 1000;
const KEEP_LINES = 500;
const STATUS_POLL = /^(\?|<.*>)$/; // grbl's status query and report: hidden unless asked for

export function manualControls(m, { update, onRemoved }) {
  // the machine's manual actions go out one after another, in the order they were asked
  // (Home then X+ must not reach the server as X+ then Home); STOP is not one of them
  let last = Promise.resolve();
  const inOrder = (label, action) => { last = last.then(() => guarded(label, action)); return last; };
  const step = el("select", { class: "jog-step", "aria-label": `jog step for ${m.name}` },
    ["0.01", "0.1", "1", "10"].map((v) => el("option", { value: v, selected: v === "1" }, `${v} mm`)));
  const jogBy = (axis, sign) => inOrder(`Jog ${m.name}`, async () => {
    update(await post(`machines/${m.id}/jog`, { [`d${axis}_mm`]: sign * Number(step.value) }));
  });
  const jog = (axis, sign) => el("button", { type: "button", class: `jog jog-${axis}${sign > 0 ? "p" : "m"}`,
    "aria-label": `jog ${axis.toUpperCase()} ${sign > 0 ? "+" : "-"}`, onclick: () => jogBy(axis, sign) },
  `${axis.toUpperCase()}${sign > 0 ? "+" : "−"}`);
  const home = el("button", { type: "button", class: "act-home", onclick: () => inOrder(`Home ${m.name}`, async () => {
    if (!window.confirm(`Home ${m.name}? Every axis moves to its end stops.`)) return;
    update(await post(`machines/${m.id}/home`));
  }) }, "Home");
  const jogButtons = [jog("x", -1), jog("x", 1), jog("y", -1), jog("y", 1), jog("z", -1), jog("z", 1)];

  // keyboard jog: only while the pad has focus and "keyboard jog" is ticked (a stray key
  // elsewhere on the page never moves the machine)
  const keys = { ArrowLeft: ["x", -1], ArrowRight: ["x", 1], ArrowDown: ["y", -1], ArrowUp: ["y", 1],
    PageDown: ["z", -1], PageUp: ["z", 1] };
  const keyToggle = el("input", { type: "checkbox", class: "keyboard-jog", "aria-label": `keyboard jog for ${m.name}` });
  const pad = el("div", { class: "jog-pad", tabindex: "0", role: "group",
    "aria-label": `jog pad of ${m.name}: with keyboard jog on, arrows move X/Y, Page Up/Down move Z`,
    onkeydown: (e) => {
      const move = keys[e.key];
      if (!move || !keyToggle.checked || jogButtons[0].disabled || e.repeat) return;
      e.preventDefault();
      jogBy(...move);
    } }, home, step, ...jogButtons,
  el("label", { class: "small" }, keyToggle, " keyboard jog (arrows X/Y, Page Up/Down Z)"));

  // the live console
  const log = el("pre", { class: "console-log", "aria-live": "off", "aria-label": `console of ${m.name}` });
  const filter = el("input", { class: "console-filter", placeholder: "filter", "aria-label": `filter the console of ${m.name}` });
  const showPolls = el("input", { type: "checkbox", class: "console-polls", "aria-label": "show status polls" });
  const dropped = el("span", { class: "small console-dropped" });
  let entries = [];
  let after = 0;
  const render = () => {
    const needle = filter.value.trim().toLowerCase();
    const shown = entries.filter((e) => (showPolls.checked || !STATUS_POLL.test(e.text)) &&
      (!needle || e.text.toLowerCase().includes(needle)));
    const atBottom = log.scrollTop + log.clientHeight >= log.scrollHeight - 4;
    log.textContent = shown.map((e) => `${e.direction === "sent" ? ">" : "<"} ${e.text}`).join("\n");
    if (atBottom) log.scrollTop = log.scrollHeight;
  };
  filter.addEventListener("input", render);
  showPolls.addEventListener("change", render);
  // one poll on its way at a time, so a line is never appended twice (the timer's poll and a
  // command's would both ask for what follows the same `after`); at most one more waits
  let polling = Promise.resolve();
  let waiting = 0;
  function poll() {
    if (waiting > 1) return polling;
    waiting += 1;
    polling = polling.then(pollOnce).finally(() => { waiting -= 1; });
    return polling;
  }
  async function pollOnce() {
    if (!details.open || document.hidden) return;
    try {
      const page = await get(`machines/${m.id}/console?after=${after}&limit=1000`);
      after = page.last_seq;
      if (page.dropped) dropped.textContent = `${page.dropped} lines were not shown (too many at once)`;
      if (page.entries.length) {
        entries = entries.concat(page.entries).slice(-KEEP_LINES);
        render();
      }
    } catch (err) {
      if (!err.offline) dropped.textContent = `console: ${err.message}`;
    }
  }
  const line = el("input", { class: "console-line", "aria-label": `console command for ${m.name}`, placeholder: "M114", maxlength: 96 });
  const send = el("button", { type: "submit" }, "Send");
  const consoleForm = el("form", { class: "console", onsubmit: (e) => {
    e.preventDefault();
    const command = line.value.trim();
    if (!command) return;
    inOrder(`Console ${m.name}`, async () => {
      const answer = await post(`machines/${m.id}/command`, { command });
      line.value = "";
      update(answer.machine);
      await poll();
    });
  } }, line, send);
  const remove = el("button", { type: "button", class: "danger act-delete", onclick: () => guarded(`Remove ${m.name}`, async () => {
    if (!window.confirm(`Remove the machine record ${m.name}? (Jobs that used it keep their records.)`)) return;
    await del(`machines/${m.id}`);
    onRemoved();
    showInfo(`Machine ${m.name} removed.`);
  }) }, "Remove");
  const details = el("details", { class: "manual" }, el("summary", {}, "Manual control and console"),
    pad, consoleForm, el("div", { class: "row" }, filter, el("label", { class: "small" }, showPolls, " status polls"), dropped),
    log, el("div", { class: "row" }, remove));
  details.addEventListener("toggle", () => { if (details.open) poll(); });
  const timer = setInterval(poll, CONSOLE_MS);

  // what the machine's state allows: motion and console only idle and not held by a job;
  // remove only when nothing holds it
  function setState(machine) {
    const free = !machine.held_by && !machine.program;
    const motion = machine.state === "idle" && free;
    for (const b of [home, ...jogButtons, send]) b.disabled = !motion;
    line.disabled = !motion;
    remove.disabled = !free || ["printing", "paused", "busy"].includes(machine.state);
  }
  return { node: details, setState, dispose: () => clearInterval(timer) };
}
