// Programs: the uploaded G-code programs and the programs jobs generated, and the warp of
// one onto the probed part (warp_program on a surface_fit or a probe_run): progress, the
// result (pieces, worst chord error against the height model, the model's own error, the fixed-length split beside it) and the
// warped program; a refusal (a printing move outside the measured region) names the line.
import { ApiError, download, get, getKey, post, streamEvents, upload } from "./api.js";
import { el, fmt, guarded, initPage, markReady, showError, showInfo } from "./ui.js";

const main = initPage("programs.html");
const left = el("div");
const right = el("section", { id: "warp-panel" });
main.append(el("h1", {}, "Programs"), el("div", { class: "layout" }, left, right));

// ---- upload -------------------------------------------------------------------------------
const fileInput = el("input", { type: "file", id: "program-file", accept: ".gcode,.nc,.ngc,.tap,.txt",
  "aria-label": "G-code program file" });
left.append(el("section", {}, el("h2", {}, "Upload a program"),
  el("form", { id: "program-upload", onsubmit: (e) => { e.preventDefault(); onUpload(); } },
    fileInput, " ", el("button", { type: "submit", id: "program-upload-button" }, "Upload"))));

async function onUpload() {
  await guarded("Upload", async () => {
    if (!fileInput.files.length) throw new Error("choose a G-code file");
    const form = new FormData();
    form.append("file", fileInput.files[0], fileInput.files[0].name);
    const program = await upload("programs", form);
    showInfo(`Program ${program.name} uploaded (${program.lines} lines).`);
    await refresh();
    choose(program.id);
  });
}

// ---- lists --------------------------------------------------------------------------------
const uploadedBody = el("tbody");
const generatedBody = el("tbody");
left.append(
  el("section", {}, el("h2", {}, "Uploaded programs"),
    el("table", { id: "programs-table" }, el("thead", {}, el("tr", {},
      ["name", "lines", "x range (mm)", "y range (mm)", "uploaded", ""].map((h) => el("th", {}, h)))), uploadedBody)),
  el("section", {}, el("h2", {}, "Generated programs"),
    el("p", { class: "small" }, "G-code written by jobs (compensated traces, circuits, slices). "
      + "\"Warp\" copies one to the uploaded programs first."),
    el("table", { id: "generated-table" }, el("thead", {}, el("tr", {},
      ["program", "artifact", "size", ""].map((h) => el("th", {}, h)))), generatedBody)));

const range = (b, i) => (b ? `${fmt.num(b[0][i], 2)} … ${fmt.num(b[1][i], 2)}` : "—");

async function refresh() {
  const [programs, jobs] = await Promise.all([get("programs?limit=100"), get("jobs?status=succeeded&limit=100")]);
  uploadedBody.replaceChildren(...programs.items.map((p) => el("tr", { "data-program": p.id },
    el("td", { title: p.id }, p.name), el("td", {}, String(p.lines)),
    el("td", {}, range(p.bounds, 0)), el("td", {}, range(p.bounds, 1)), el("td", {}, fmt.time(p.created_at)),
    el("td", {},
      el("button", { class: "warp-choose", onclick: () => choose(p.id) }, "Warp onto the probed part"), " ",
      el("button", { class: "program-download", onclick: () => guarded("Download",
        () => download(`/api/v1/programs/${p.id}/file`, p.name)) }, "Download")))));
  programSelect.replaceChildren(...programs.items.map((p) => el("option", { value: p.id, title: p.id }, `${p.name} (${p.lines} lines)`)));
  const generated = jobs.items.flatMap((j) => (j.artifacts || []).filter((a) => /\.(gcode|nc|ngc)$/i.test(a.name))
    .map((a) => ({ job: j, artifact: a })));
  generatedBody.replaceChildren(...generated.map(({ job, artifact }) => el("tr", {},
    el("td", { title: job.id }, job.title || job.kind.replaceAll("_", " ")), el("td", {}, artifact.name),
    el("td", {}, fmt.bytes(artifact.bytes)),
    el("td", {},
      el("button", { class: "generated-warp", onclick: () => guarded("Copy for a warp", () => adopt(job, artifact)) },
        "Warp"), " ",
      el("button", { onclick: () => guarded("Download", () => download(artifact.url, artifact.name)) }, "Download")))));
  surfaceSelect.replaceChildren(...jobs.items.filter((j) => j.kind === "surface_fit" || j.kind === "probe_run")
    .map((j) => el("option", { value: `${j.kind}:${j.id}`, title: j.id }, `${j.title || j.kind} · ${fmt.time(j.created_at)}`)));
}

// A generated program becomes an uploaded one (its text fetched with the key, then uploaded).
async function adopt(job, artifact) {
  const response = await fetch(artifact.url, { headers: { Authorization: `Bearer ${getKey()}` } });
  if (!response.ok) throw new ApiError(`could not read ${artifact.name} (HTTP ${response.status})`, { status: response.status });
  const form = new FormData();
  form.append("file", new Blob([await response.text()], { type: "text/x-gcode" }), `${job.kind}-${job.id}-${artifact.name}`);
  const program = await upload("programs", form);
  showInfo(`${artifact.name} of ${job.title || job.kind} copied to the uploaded programs as ${program.name}.`);
  await refresh();
  choose(program.id);
}

// ---- the warp -----------------------------------------------------------------------------
const programSelect = el("select", { id: "warp-program", "aria-label": "program to warp" });
const surfaceSelect = el("select", { id: "warp-surface", "aria-label": "probed surface (surface_fit or probe_run)" });
const num = (id, value, extra = {}) => el("input", { type: "number", step: "any", id, value, class: "narrow", ...extra });
const standoff = num("warp-standoff", 0.1, { min: 0 });
const chord = num("warp-chord", 0.002, { min: 0 });
const outside = el("input", { type: "checkbox", id: "warp-allow-outside" });
const progress = el("progress", { id: "warp-progress", max: 1, value: 0, "aria-label": "warp progress" });
const output = el("div", { id: "warp-result" });
right.append(el("h2", {}, "Warp onto the probed part"),
  el("p", { class: "small" }, "Every printing move is moved onto the measured surface at the standoff and split so "
    + "that a bound on its chord error against the height model holds (the model's own cross-validated error is shown beside it); travel is lifted. A printing move outside the probed area is "
    + "refused (naming its line) unless allowed."),
  el("form", { id: "warp-form", onsubmit: (e) => { e.preventDefault(); onWarp(); } },
    el("div", { class: "row" }, el("label", {}, "program ", programSelect)),
    el("div", { class: "row" }, el("label", {}, "surface ", surfaceSelect)),
    el("div", { class: "row" }, el("label", {}, "standoff (mm) ", standoff), el("label", {}, " chord error (mm) ", chord),
      el("label", {}, " allow outside ", outside)),
    el("div", { class: "row" }, el("button", { type: "submit", id: "warp-submit" }, "Warp onto the probed part"), " ",
      progress)),
  output);

function choose(programId) {
  programSelect.value = programId;
  programSelect.focus();
}

function showResult(job) {
  const r = job.result;
  const warped = (job.artifacts || []).find((a) => a.name === "warped.gcode");
  output.replaceChildren(el("table", { id: "warp-figures" }, el("tbody", {},
    [["lines in / out", `${r.lines_in} / ${r.lines_out}`], ["printing moves", r.printing_moves],
      ["pieces", r.pieces], ["worst chord error (against the height model)", `${fmt.num(r.max_chord_bound_mm * 1000, 3)} µm`],
      ["height model error (cross-validated max)", r.model_error_mm == null ? "not measurable"
        : `± ${fmt.num(r.model_error_mm * 1000, 3)} µm`],
      ["height model", r.height_model ? `${r.height_model.kind.replaceAll("_", " ")}, ${r.height_model.cv.replaceAll("_", " ")} `
        + (r.height_model.cv_max_mm == null ? "not measurable" : `max ${fmt.num(r.height_model.cv_max_mm * 1000, 3)} µm, `
        + `rms ${fmt.num(r.height_model.cv_rms_mm * 1000, 3)} µm`)
        + (r.height_model.posterior_sd_max_mm == null ? "" : `, posterior sd ≤ ${fmt.num(r.height_model.posterior_sd_max_mm * 1000, 3)} µm`)
        + (r.height_model.kriging ? ` (kriging: wavelength ${fmt.num(r.height_model.kriging.wavelength_mm, 3)} mm, leave-one-out max `
          + `${fmt.num(r.height_model.kriging.loo_max_mm * 1000, 3)} µm)` : "") : "—"],
      [`fixed ${fmt.num(r.fixed_split.split_mm, 3)} mm split`, `${r.fixed_split.pieces} pieces, worst `
        + `${fmt.num(r.fixed_split.max_error_mm * 1000, 3)} µm`], ["safe travel z", fmt.mm(r.safe_z_mm, 3)]]
      .map(([k, v]) => el("tr", {}, el("th", {}, k), el("td", { "data-figure": k }, String(v)))))),
  warped ? el("p", {}, el("a", { id: "warped-link", href: `jobs.html?job=${job.id}`, title: job.id }, "the warp job"), " ",
    el("button", { id: "warped-download", onclick: () => guarded("Download", () => download(warped.url, "warped.gcode")) },
      "Download warped.gcode")) : null);
}

function showRefusal(err) {
  const line = err.problem?.errors?.[0]?.value?.line;
  output.replaceChildren(el("p", { id: "warp-refused", class: "error-text", "data-line": line ?? "" },
    `Refused: ${err.message}`));
}

async function onWarp() {
  const [kind, surfaceId] = (surfaceSelect.value || ":").split(":");
  const params = { program_id: programSelect.value, standoff_mm: Number(standoff.value) || null,
    chord_error_mm: Number(chord.value), allow_outside: outside.checked,
    [kind === "probe_run" ? "probe_run_job_id" : "surface_fit_job_id"]: surfaceId };
  output.replaceChildren();
  progress.value = 0;
  let job;
  try {
    if (!programSelect.value) throw new Error("upload or choose a program first");
    if (!surfaceId) throw new Error("probe the part first (a surface_fit or probe_run job)");
    job = await post("jobs", { kind: "warp_program", params });
  } catch (err) {
    if (err instanceof ApiError && err.status === 422) showRefusal(err);
    else showError(err, "Warp");
    return;
  }
  output.replaceChildren(el("p", { id: "warp-running" }, `warp job ${job.id} queued`));
  await new Promise((resolve) => {
    const ctrl = streamEvents(`/api/v1/jobs/${job.id}/events`, (ev) => {
      const data = ev.data || {};
      if (typeof data.progress === "number") progress.value = data.progress;
      if (["succeeded", "failed", "cancelled"].includes(data.status)) { ctrl.abort(); resolve(); }
    }, () => resolve());
  });
  const done = await get(`jobs/${job.id}?include=result&include=artifacts`);
  progress.value = 1;
  if (done.status === "succeeded") {
    showResult(done);
    showInfo(`Warped: ${done.result.pieces} pieces, worst ${fmt.num(done.result.max_chord_bound_mm * 1000, 3)} µm.`);
  } else {
    output.replaceChildren(el("p", { id: "warp-refused", class: "error-text" },
      `Warp ${done.status}: ${done.error?.detail || done.message || ""}`));
  }
}

refresh().then(markReady, (err) => { showError(err, "Programs"); markReady(); });
