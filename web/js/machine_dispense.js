// A machine card's dispense profile: what the machine dispenses (a paste or an ink), at what
// pressure, with which on/off delays, standoff and speed.  The summary is always shown; the
// form opens on demand, built from the parameter model's schema (the print kind's
// DispenseProfile: its labels and units come from the server), with a preset picker
// (GET /materials).  Saved with PATCH /machines/{id} {dispense} any time no program holds
// the machine; a print applies the delays and records the profile.
import { get, patch } from "./api.js";
import { schemaForm } from "./schema_form.js";
import { el, guarded, showInfo } from "./ui.js";

let schema = null;
const profileSchema = () => (schema ??= get("job-kinds").then((kinds) => {
  const print = kinds.find((k) => k.name === "print").params_schema;
  return { ...print.$defs.DispenseProfile, $defs: print.$defs };
}));
let presets = null;
const dispensed = () => (presets ??= get("materials").then((all) => all.filter((m) => m.dispense)));

// "Silver paste · 250 kPa · on 120 ms / off 80 ms · standoff 0.1 mm · 300 mm/min"
export function dispenseSummary(d, names = {}) {
  if (!d) return "none: programs are streamed as written";
  const what = d.material ? names[d.material] || d.material.replaceAll("_", " ") : "own profile";
  return `${what} · ${d.pressure_kpa} kPa · on ${d.on_delay_ms} ms / off ${d.off_delay_ms} ms · ` +
    `standoff ${d.standoff_mm} mm · ${d.feed_mm_min} mm/min`;
}

export function dispenseSection(machine, onSaved) {
  const summary = el("span", { class: "dispense-summary" }, dispenseSummary(machine.profile?.dispense));
  const body = el("div", { class: "dispense-body" });
  const details = el("details", { class: "dispense" }, el("summary", {}, "Dispense profile: ", summary), body);
  let current = machine;
  let names = {};
  dispensed().then((list) => {
    names = Object.fromEntries(list.map((m) => [m.name, m.label]));
    summary.textContent = dispenseSummary(current.profile?.dispense, names);
  }).catch(() => {});

  async function build() {
    const [s, list] = await Promise.all([profileSchema(), dispensed()]);
    const form = schemaForm(s, { prefill: current.profile?.dispense || {} });
    const picker = el("select", { class: "dispense-preset", "aria-label": `material preset for ${current.name}` },
      el("option", { value: "" }, "(as the fields say)"), list.map((m) => el("option", { value: m.name }, m.label)));
    picker.value = current.profile?.dispense?.material || "";
    picker.addEventListener("change", () => {
      const preset = list.find((m) => m.name === picker.value);
      if (preset) for (const [k, v] of Object.entries(preset.dispense)) form.set(k, v);
      else form.set("material", "");
    });
    const save = el("button", { type: "submit", class: "primary dispense-save" }, "Save the profile");
    const clear = el("button", { type: "button", class: "dispense-clear", onclick: () => guarded(`Dispense profile of ${current.name}`, async () => {
      onSaved(await patch(`machines/${current.id}`, { clear_dispense: true }));
      showInfo(`${current.name}: no dispense profile.`);
    }) }, "Remove");
    const formNode = el("form", { class: "dispense-form", onsubmit: (e) => {
      e.preventDefault();
      guarded(`Dispense profile of ${current.name}`, async () => {
        const values = form.values();
        // a preset's values changed by hand: the machine's own profile of that material (kept for it)
        if (!list.some((m) => m.name === values.material)) values.material = null;
        try {
          onSaved(await patch(`machines/${current.id}`, { dispense: values }));
        } catch (err) {
          form.markErrors(err.fieldErrors);
          throw err;
        }
        form.markErrors([]);
        showInfo(`${current.name} dispenses ${dispenseSummary(values, names)}.`);
      });
    } }, el("div", { class: "field" }, el("label", {}, "Material ", picker)), form.node, el("div", { class: "row" }, save, clear));
    body.replaceChildren(formNode);
  }
  details.addEventListener("toggle", () => {
    if (details.open && !body.dataset.built) { body.dataset.built = "1"; guarded("Dispense profile", build); }
  });
  return {
    node: details,
    update(m) {
      const changed = JSON.stringify(m.profile?.dispense) !== JSON.stringify(current.profile?.dispense);
      current = m;
      summary.textContent = dispenseSummary(m.profile?.dispense, names);
      if (changed && body.dataset.built) { delete body.dataset.built; body.replaceChildren(); if (details.open) { body.dataset.built = "1"; guarded("Dispense profile", build); } }
    },
  };
}
