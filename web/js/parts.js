// Parts: upload a mesh (with progress), list, open in 3D, delete.
import { del, download, get, upload } from "./api.js";
import { el, fmt, guarded, initPage, markReady, showError, showInfo, viewerPanel } from "./ui.js";

const FORMATS = ["stl", "obj", "ply", "off", "3mf", "glb"];
const main = initPage("parts.html");
const left = el("div");
const right = el("section", { id: "viewer-panel" });
main.append(el("h1", {}, "Parts"), el("div", { class: "layout" }, left, right));
const viewer = viewerPanel(right);

// ---- upload -------------------------------------------------------------------------
const fileInput = el("input", { type: "file", id: "part-file", name: "file", accept: FORMATS.map((f) => `.${f}`).join(","), required: true });
const nameInput = el("input", { type: "text", id: "part-name", name: "name", maxlength: 200, placeholder: "optional" });
const UNITS = [["", "as the file says (else mm)"], ["mm", "mm"], ["cm", "cm"], ["m", "m"], ["um", "µm"], ["inch", "inch"], ["ft", "ft"]];
const UPS = [["", "as the file says (+Z; GLB +Y)"], ["+z", "+Z"], ["-z", "−Z"], ["+y", "+Y"], ["-y", "−Y"], ["+x", "+X"], ["-x", "−X"]];
const unitsSelect = el("select", { id: "part-units", name: "units" }, ...UNITS.map(([v, t]) => el("option", { value: v }, t)));
const upSelect = el("select", { id: "part-up", name: "up" }, ...UPS.map(([v, t]) => el("option", { value: v }, t)));
const progress = el("progress", { id: "upload-progress", max: 1, value: 0, hidden: true });
const progressText = el("span", { id: "upload-status", class: "small" });
const uploadButton = el("button", { type: "submit", class: "primary", id: "upload-button" }, "Upload");
const form = el("form", { id: "upload-form", onsubmit: onUpload },
  el("div", { class: "row" },
    el("div", { class: "field" }, el("label", { for: "part-file" }, "Mesh file"), fileInput),
    el("div", { class: "field" }, el("label", { for: "part-name" }, "Name"), nameInput),
    el("div", { class: "field" }, el("label", { for: "part-units" }, "File units"), unitsSelect),
    el("div", { class: "field" }, el("label", { for: "part-up" }, "Up axis"), upSelect),
    uploadButton),
  progress, progressText);
left.append(el("section", {}, el("h2", {}, "Upload a part"),
  el("p", { class: "small" }, `Accepted: ${FORMATS.map((f) => f.toUpperCase()).join(", ")}. Parts are stored in mm with +Z up.`), form));

function extensionOf(name) {
  const dot = name.lastIndexOf(".");
  return dot < 0 ? "" : name.slice(dot + 1).toLowerCase();
}

async function onUpload(event) {
  event.preventDefault();
  const file = fileInput.files[0];
  if (!file) { showError(new Error("choose a mesh file first"), "Upload"); return; }
  const ext = extensionOf(file.name);
  if (!FORMATS.includes(ext)) {
    showError(new Error(`wrong file type "${file.name}": expected a mesh file (${FORMATS.map((f) => `.${f}`).join(", ")})`), "Upload");
    return;
  }
  const data = new FormData();
  data.append("file", file, file.name);
  if (nameInput.value.trim()) data.append("name", nameInput.value.trim());
  if (unitsSelect.value) data.append("units", unitsSelect.value);
  if (upSelect.value) data.append("up", upSelect.value);
  progress.hidden = false;
  progress.value = 0;
  uploadButton.disabled = true;
  progressText.textContent = `uploading ${file.name} (${fmt.bytes(file.size)})…`;
  try {
    const part = await upload("parts", data, (f) => {
      progress.value = f;
      progressText.textContent = f < 1 ? `uploading… ${(100 * f).toFixed(0)} %` : "checking the mesh…";
    });
    progressText.textContent = `uploaded: ${part.name} (${part.faces} faces)`;
    const notes = (part.warnings || []).length ? ` Note: ${part.warnings.join(" ")}` : "";
    showInfo(`Part "${part.name}" uploaded (${part.id}), read in ${part.units}.${notes}`);
    form.reset();
    await refresh(part.id);
  } catch (err) {
    progressText.textContent = "upload failed";
    showError(err, `Upload of ${file.name}`);
  } finally {
    uploadButton.disabled = false;
  }
}

// ---- list ---------------------------------------------------------------------------
const tbody = el("tbody", { id: "parts-body" });
const total = el("span", { class: "small", id: "parts-total" });
left.append(el("section", {}, el("h2", {}, "Parts ", total),
  el("table", { id: "parts-table" },
    el("thead", {}, el("tr", {}, ["Name", "Size (mm)", "Faces", "Watertight", "Created", ""].map((h) => el("th", {}, h)))),
    tbody)));

function size(bounds) {
  const [lo, hi] = bounds;
  return hi.map((v, i) => (v - lo[i]).toFixed(1)).join(" × ");
}

function row(part) {
  let armed = false;
  const delButton = el("button", { class: "danger", onclick: async () => {
    if (!armed) { armed = true; delButton.textContent = "Confirm delete"; setTimeout(() => { armed = false; delButton.textContent = "Delete"; }, 4000); return; }
    await guarded(`Delete ${part.name}`, async () => {
      await del(`parts/${part.id}`);
      showInfo(`Part "${part.name}" deleted.`);
      await refresh();
    });
  } }, "Delete");
  const tr = el("tr", { "data-id": part.id },
    el("td", { title: part.id }, el("strong", {}, part.name)),
    el("td", {}, size(part.bounds)),
    el("td", {}, part.faces),
    el("td", {}, part.watertight ? "yes" : "no"),
    el("td", { class: "small" }, fmt.time(part.created_at)),
    el("td", {},
      el("button", { class: "open3d", onclick: () => { select(tr); viewer.show({ part_id: part.id }); } }, "3D"), " ",
      el("a", { href: `traces.html?part=${encodeURIComponent(part.id)}` }, "Traces"), " ",
      el("button", { onclick: () => guarded("Download", () => download(`/api/v1/parts/${part.id}/mesh?format=stl`, `${part.name}.stl`)) }, "STL"), " ",
      delButton));
  return tr;
}

function select(tr) {
  tbody.querySelectorAll("tr.selected").forEach((r) => r.classList.remove("selected"));
  tr.classList.add("selected");
}

async function refresh(openId) {
  await guarded("Parts", async () => {
    const page = await get("parts?limit=200");
    total.textContent = `(${page.total})`;
    tbody.replaceChildren(...page.items.map(row));
    if (!page.items.length) tbody.append(el("tr", {}, el("td", { colspan: 6, class: "small" }, "No parts yet: upload one above.")));
    if (openId) {
      const tr = tbody.querySelector(`tr[data-id="${openId}"]`);
      if (tr) { select(tr); viewer.show({ part_id: openId }); }
    }
  });
}

document.addEventListener("conforma:key", () => refresh());
refresh().then(markReady);
