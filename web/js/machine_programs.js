// The machines page's program list: the print programs the service has written
// (compensated traces, a closed loop's whole-part program, toolpaths, circuit programs,
// five-axis and warped programs), newest first, each with a Print button.  Print asks
// first, naming the machine, the program, its line count and its estimated time; the
// card then shows the print's progress next to the machine's emergency stop.
import { get, post } from "./api.js";
import { dispenseSummary } from "./machine_dispense.js";
import { duration } from "./results.js";
import { el, fmt, guarded, showInfo } from "./ui.js";

// kind -> which of its G-code artifacts are print programs (nominal/probe programs are not)
export const PRINTABLE = {
  closed_loop: (name) => name === "whole_part.gcode",
  compensate: (name) => name === "print.gcode",
  toolpath: (name) => name === "print.gcode",
  circuit_program: (name) => name.endsWith(".gcode"),
  five_axis: (name) => name === "five_axis.gcode",
  warp_program: (name) => name.endsWith(".gcode"),
};
const PER_KIND = 15;
const SHOWN = 40;

// [{job_id, kind, name, created_at, lines, label}], newest first.
export async function loadPrograms() {
  const pages = await Promise.all(Object.keys(PRINTABLE).map((kind) =>
    get(`jobs?kind=${kind}&status=succeeded&limit=${PER_KIND}`).catch(() => ({ items: [] }))));
  const programs = [];
  for (const job of pages.flatMap((p) => p.items)) {
    for (const a of job.artifacts || []) {
      if (a.media_type !== "text/x-gcode" || !PRINTABLE[job.kind](a.name)) continue;
      // named by part · trace (net) · kind (the job's title); the artifact only when a job wrote several
      const several = job.kind === "circuit_program" || job.kind === "warp_program";
      programs.push({ job_id: job.id, kind: job.kind, name: a.name, created_at: job.created_at, lines: a.meta?.lines,
        dialect: job.params?.dialect || null,
        label: `${job.title || job.kind.replaceAll("_", " ")}${several ? ` · ${a.name}` : ""}` });
    }
  }
  programs.sort((a, b) => (a.created_at < b.created_at ? 1 : a.created_at > b.created_at ? -1 : 0));
  return programs.slice(0, SHOWN);
}

// Ask, then submit a print job; returns the job (or null when the operator said no).
export async function confirmAndPrint(machine, program) {
  const summary = await get(`jobs/${program.job_id}/artifacts/${program.name}/summary`);
  const text = `Print on ${machine.name}?\n\nprogram: ${program.label} (${program.name})\n` +
    `${summary.lines} lines, estimated time ${duration(summary.time_s)}\n` +
    `dispense profile: ${dispenseSummary(machine.profile?.dispense)}\n\nThe machine will move.`;
  if (!window.confirm(text)) return null;
  const job = await post("jobs", { kind: "print", params: { machine_id: machine.id, job_id: program.job_id, artifact: program.name } });
  showInfo(`Printing ${program.label} on ${machine.name}: ${summary.lines} lines, about ${duration(summary.time_s)}.`, 8000);
  return job;
}

// The list inside one machine card (rebuilt when the shared list changes).
export function programList(machine, programs, onPrinted) {
  if (!programs.length) {
    return el("p", { class: "small empty-programs" }, "No print programs yet: compensate a trace, run a closed loop or a toolpath.");
  }
  return el("table", { class: "records programs-table" },
    el("thead", {}, el("tr", {}, el("th", { scope: "col" }, "Program"), el("th", { scope: "col" }, "Lines"),
      el("th", { scope: "col" }, "Written"), el("th", { scope: "col" }, ""))),
    el("tbody", {}, programs.map((p) => el("tr", { "data-job": p.job_id, "data-artifact": p.name },
      el("td", { title: `${p.name} of job ${p.job_id}` }, p.label,
        p.dialect && p.dialect !== machine.dialect ? el("div", { class: "small warn" }, `written for ${p.dialect}`) : null),
      el("td", {}, p.lines ?? "?"),
      el("td", { class: "small" }, fmt.time(p.created_at)),
      el("td", {}, el("button", { type: "button", class: "primary print-program",
        "aria-label": `Print ${p.label} (${p.name}) on ${machine.name}`, title: `job ${p.job_id}`,
        onclick: () => guarded(`Print on ${machine.name}`, async () => {
          const job = await confirmAndPrint(machine, p);
          if (job) onPrinted(job);
        }) }, "Print"))))));
}
