// The head on the path: while a machine prints, the page's 3-D view shows the program it
// prints (the print job's scene: the part and the program in the machine's coordinates) and
// draws the machine's head where the server reads it now (POST /viewer/head), once a poll.
// The view is created only when a print runs, so an idle page loads no 3-D view.
import { el, viewerPanel } from "./ui.js";

const RUNNING = ["printing", "paused"];
const xyz = (p) => ["X", "Y", "Z"].map((a, i) => `${a} ${Number(p[i]).toFixed(3)}`).join("   ");

export function headView(main) {
  const section = el("section", { id: "viewer-panel", hidden: true });
  const readout = el("div", { id: "head-readout", class: "pos", "aria-live": "off" });
  main.append(section);
  let viewer = null;
  let shownJob = null;
  let busy = false;

  async function draw(machine) {
    const jobId = machine.program.job_id;
    if (shownJob !== jobId) {
      const scene = await viewer.show({ job_id: jobId });
      if (!scene) return;
      shownJob = jobId;
    }
    const head = await viewer.head(machine.id);
    if (!head) return;
    readout.dataset.machine = machine.id;
    readout.dataset.drawn = head.drawn ? "true" : "false";
    readout.dataset.position = head.position_mm ? head.position_mm.join(",") : "";
    readout.dataset.line = head.line ?? "";
    readout.textContent = `Head of ${machine.name}: ` + (head.position_mm ? xyz(head.position_mm) : `position unknown (${head.source})`)
      + (head.line != null ? ` · line ${head.line} of ${head.total}` : "");
  }

  // machines: the page's latest GET /machines items; the first one running a program is followed.
  async function follow(machines) {
    const running = machines.find((m) => m.program && RUNNING.includes(m.program.state) && m.program.job_id);
    if (!running || busy) return;
    if (!viewer) {
      section.hidden = false;
      viewer = viewerPanel(section);
      section.querySelector("h2").after(readout);
    }
    busy = true;
    try {
      await draw(running);
    } catch {
      // the view is a help, never in the way of the page's controls: the next poll tries again
    } finally {
      busy = false;
    }
  }

  return { follow };
}
