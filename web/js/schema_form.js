// A form generated from a job kind's JSON schema (pydantic): numbers, integers, strings,
// enums, booleans; lists and objects as JSON text.  Ids get suggestions (datalists).
// What the parameter models declare (app/jobs/form_hints.py) shapes it: the field's title
// and unit (x-unit) label it, advanced fields (x-advanced) are folded in a <details>, a
// mode's fields (x-when: {mode: [values]}) show only while that mode is chosen, and the
// alternatives of a choice (x-choice: one trace or several) show one at a time.  Hidden
// fields are not submitted (the server's defaults apply).
import { el } from "./ui.js";

function resolve(schema, defs) {
  if (schema && schema.$ref) return { ...resolve(defs[schema.$ref.split("/").pop()] || {}, defs), ...strip(schema) };
  if (schema && (schema.anyOf || schema.oneOf)) {
    const branches = (schema.anyOf || schema.oneOf).filter((b) => b.type !== "null");
    const base = branches.length === 1 ? resolve(branches[0], defs) : { type: "json" };
    return { ...base, ...schema, anyOf: undefined, oneOf: undefined, type: base.type, enum: base.enum, nullable: true };
  }
  if (schema && schema.const !== undefined && !schema.enum) return { ...schema, enum: [schema.const] };
  return schema || {};
}
// a $ref's own keys (title, default, description, x-...) without the $ref
function strip(schema) { const { $ref, ...rest } = schema; return rest; }

function hintOf(s) {
  const bounds = [];
  if (s.minimum !== undefined) bounds.push(`≥ ${s.minimum}`);
  if (s.exclusiveMinimum !== undefined) bounds.push(`> ${s.exclusiveMinimum}`);
  if (s.maximum !== undefined) bounds.push(`≤ ${s.maximum}`);
  if (s.exclusiveMaximum !== undefined) bounds.push(`< ${s.exclusiveMaximum}`);
  return [s.description, bounds.join(", ")].filter(Boolean).join(" · ");
}

// Build the form body; returns {node, values(), markErrors(fieldErrors), set(name, value), names}.
export function schemaForm(schema, { suggestions = {}, prefill = {} } = {}) {
  const defs = schema.$defs || {};
  const required = new Set(schema.required || []);
  const fields = {};
  const node = el("div", { class: "schema-form" });
  const advancedBody = el("div", { class: "advanced-fields" });
  const advanced = el("details", { class: "advanced", id: "advanced-params" }, el("summary", {}, "Advanced"), advancedBody);
  const choices = {};  // group -> {select, names: []}
  for (const [name, raw] of Object.entries(schema.properties || {})) {
    const s = resolve(raw, defs);
    const id = `param-${name}`;
    let input;
    let kind = s.type;
    if (s.enum) {
      kind = "enum";
      input = el("select", { id, name },
        !required.has(name) && (s.default === undefined || s.default === null) ? el("option", { value: "" }, "(default)") : null,
        s.enum.map((v) => el("option", { value: JSON.stringify(v), selected: v === s.default }, String(v))));
    } else if (kind === "boolean") {
      input = el("input", { id, name, type: "checkbox", checked: s.default === true });
    } else if (kind === "integer" || kind === "number") {
      input = el("input", { id, name, type: "number", step: kind === "integer" ? 1 : "any",
        value: s.default ?? "", placeholder: s.default === null || s.default === undefined ? "(optional)" : "" });
    } else if (kind === "string") {
      const list = suggestions[name] ? `${id}-list` : null;
      input = el("input", { id, name, type: "text", value: s.default ?? "", list, autocomplete: "off" });
      if (list) node.append(el("datalist", { id: list }, suggestions[name].map(([v, label]) => el("option", { value: v }, label))));
    } else {
      kind = "json";
      input = el("textarea", { id, name, placeholder: "JSON" }, s.default !== undefined && s.default !== null ? JSON.stringify(s.default) : "");
    }
    if (prefill[name] !== undefined) setValue(input, kind, prefill[name]);
    const unit = s["x-unit"];
    const label = `${s.title || name}${unit ? ` (${unit})` : ""}${required.has(name) ? " *" : ""}`;
    const wrap = el("div", { class: "field", "data-field": name },
      el("label", { for: id, title: name }, label), input,
      el("div", { class: "hint" }, hintOf(s)), el("div", { class: "error-text" }));
    fields[name] = { input, kind, required: required.has(name), wrap, when: s["x-when"] || null, choice: s["x-choice"] || null };
    if (s["x-choice"]) {
      const group = s["x-choice"];
      if (!choices[group]) {
        const select = el("select", { id: `choice-${group}`, "aria-label": `${group}: which to give`, class: "choice" });
        choices[group] = { select, names: [] };
        node.append(el("div", { class: "field choice-field", "data-choice": group }, el("label", { for: `choice-${group}` }, "Give"), select));
      }
      choices[group].names.push(name);
      choices[group].select.append(el("option", { value: name }, s["x-choice-label"] || s.title || name));
    }
    (s["x-advanced"] ? advancedBody : node).append(wrap);
  }
  if (advancedBody.children.length) node.append(advanced);

  function setValue(input, kind, value) {
    if (kind === "boolean") input.checked = value === true || value === "true";
    else if (kind === "enum") input.value = JSON.stringify(value);
    else if (kind === "json") input.value = typeof value === "string" ? value : JSON.stringify(value);
    else input.value = value;
  }

  // The value a mode field has now (an enum's "(default)" is null), for x-when.
  function current(name) {
    const f = fields[name];
    if (!f) return undefined;
    if (f.kind === "boolean") return f.input.checked;
    if (f.kind === "enum") return f.input.value === "" ? null : JSON.parse(f.input.value);
    return f.input.value;
  }

  function shown(name) {
    const f = fields[name];
    if (f.choice && choices[f.choice].select.value !== name) return false;
    if (!f.when) return true;
    return Object.entries(f.when).every(([other, allowed]) => allowed.some((v) => v === current(other)));
  }

  function update() {
    for (const [name, f] of Object.entries(fields)) f.wrap.hidden = !shown(name);
    advanced.hidden = ![...advancedBody.children].some((c) => !c.hidden);
  }

  // a prefilled alternative is the one shown
  for (const { select, names } of Object.values(choices)) {
    const given = names.find((n) => prefill[n] !== undefined && prefill[n] !== null);
    if (given) select.value = given;
  }
  node.addEventListener("change", update);
  update();

  function values() {
    const out = {};
    for (const [name, f] of Object.entries(fields)) {
      if (!shown(name)) continue;
      const { input, kind } = f;
      if (kind === "boolean") { out[name] = input.checked; continue; }
      const text = input.value.trim();
      if (text === "") { if (f.required) throw Object.assign(new Error(`${name} is required`), { field: name }); continue; }
      if (kind === "integer" || kind === "number") out[name] = Number(text);
      else if (kind === "enum") out[name] = JSON.parse(text);
      else if (kind === "json") {
        try { out[name] = JSON.parse(text); } catch (err) {
          throw Object.assign(new Error(`${name} must be JSON: ${err.message}`), { field: name });
        }
      } else out[name] = text;
    }
    return out;
  }

  function markErrors(errors) {
    for (const f of Object.values(fields)) { f.wrap.classList.remove("invalid"); f.wrap.querySelector(".error-text").textContent = ""; }
    for (const { loc, msg } of errors || []) {
      const parts = loc.split(".");
      const name = parts[0] === "params" ? parts[1] : parts.find((p) => fields[p]);
      const f = fields[name];
      if (f) {
        f.wrap.classList.add("invalid"); f.wrap.querySelector(".error-text").textContent = msg;
        if (advancedBody.contains(f.wrap)) advanced.open = true;  // an error is never folded away
      }
    }
  }

  function set(name, value) {
    if (!fields[name]) return false;
    setValue(fields[name].input, fields[name].kind, value);
    update();
    return true;
  }

  return { node, values, markErrors, set, names: Object.keys(fields) };
}
