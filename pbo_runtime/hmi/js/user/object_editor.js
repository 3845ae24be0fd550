// A named object's values (Onika §4.4.1, "the values of objects are edited"): one typed field per
// element of the object type's shape, labelled by element, checked here for numbers of the type
// and then by the file's own checker when saved (POST /api/workspace/objects writes the YAML file).
import { html, useState, useEffect, useRef } from "../html.js";
import { post } from "../api.js";

const INTEGER = /^u?int/;

/** Every index of a shape, row-major: [[0], [1], ...] or [[0, 0], [0, 1], ...]; [[]] for a scalar. */
function indices(shape) {
  let all = [[]];
  for (const size of shape) all = all.flatMap((prefix) => Array.from({ length: size }, (_, i) => [...prefix, i]));
  return all;
}

function elementOf(value, index) {
  return index.reduce((v, i) => (Array.isArray(v) ? v[i] : v), value);
}

/** The flat field texts back into the object's nested value; {error} naming the first field that is no number of the type. */
function valueOf(texts, shape, dtype, name) {
  const numbers = [];
  for (const [i, text] of texts.entries()) {
    const label = `${name}${shape.length ? indices(shape)[i].map((k) => `[${k}]`).join("") : ""}`;
    const number = Number(text);
    if (text.trim() === "" || !Number.isFinite(number)) return { error: `${label} must be a finite number, got '${text}'` };
    if (INTEGER.test(dtype) && !Number.isInteger(number)) return { error: `${label} must be a whole number (${dtype}), got '${text}'` };
    numbers.push(number);
  }
  const build = (depth, offset) => {
    if (depth === shape.length) return [numbers[offset], 1];
    const items = [];
    let used = 0;
    for (let i = 0; i < shape[depth]; i++) {
      const [item, count] = build(depth + 1, offset + used);
      items.push(item);
      used += count;
    }
    return [items, used];
  };
  return { value: build(0, 0)[0] };
}

/**
 * The editor of object `name`: fields, Save (Enter saves), Close. `onSaved(reply)` gets the API's
 * reply (with the new dictionary); `where` names the pane it was opened from, for its label.
 */
export function ObjectEditor({ dictionary, name, where, onSaved, onClose }) {
  const obj = dictionary.objects[name];
  const type = obj ? dictionary.object_types[obj.type] : null;
  const shape = type ? type.shape : [];
  const dtype = type ? type.type : "float64";
  const fresh = () => (obj ? indices(shape).map((index) => String(elementOf(obj.value, index))) : []);
  const [texts, setTexts] = useState(fresh);
  const [message, setMessage] = useState({ text: "", error: false });
  const [saving, setSaving] = useState(false);
  // The fields start from the file's values (useState above) and go back to them only when the object
  // or its saved value changes: an effect that ran after the first paint too could overwrite what was
  // typed in the meantime, and Save then wrote the old values.
  const shown = useRef({ name, value: obj && JSON.stringify(obj.value) });
  const value = obj && JSON.stringify(obj.value);
  useEffect(() => {
    const before = shown.current;
    if (before.name === name && before.value === value) return;
    shown.current = { name, value };
    setTexts(fresh());
    if (before.name !== name) setMessage({ text: "", error: false });
  }, [name, value]);
  if (!obj) return null;

  const save = async (event) => {
    event.preventDefault();
    const parsed = valueOf(texts, shape, dtype, name);
    if (parsed.error) { setMessage({ text: `Not saved: ${parsed.error}`, error: true }); return; }
    setSaving(true);
    try {
      const reply = await post("workspace/objects", { name, value: parsed.value });
      setMessage({ text: reply.message, error: false });
      onSaved(reply);
    } catch (e) {
      setMessage({ text: `Not saved: ${e.message}`, error: true });
    } finally {
      setSaving(false);
    }
  };
  const unit = type && type.unit ? ` (${type.unit})` : "";
  return html`
    <form class="object-editor" aria-label=${`values of object ${name}`} data-test=${`object-editor-${where}`} onSubmit=${save}>
      <h3>Object <strong>${name}</strong>: ${obj.type}${unit}</h3>
      ${obj.doc ? html`<p class="object-doc">${obj.doc}</p>` : null}
      <div class=${"object-fields" + (shape.length === 2 ? " object-grid" : "")}
           style=${shape.length === 2 ? `grid-template-columns: repeat(${shape[1]}, 1fr)` : ""}>
        ${indices(shape).map((index, i) => {
          const label = `${name}${index.map((k) => `[${k}]`).join("")}`;
          return html`
            <label class="object-field">
              <span>${label}</span>
              <input type="number" step=${INTEGER.test(dtype) ? "1" : "any"} value=${texts[i]}
                     onInput=${(e) => setTexts(texts.map((t, k) => (k === i ? e.currentTarget.value : t)))} />
            </label>`;
        })}
      </div>
      <div class="object-actions">
        <button type="submit" disabled=${saving}>Save values to the file</button>
        <button type="button" onClick=${() => setTexts(fresh())}>Revert</button>
        <button type="button" onClick=${onClose}>Close</button>
      </div>
      ${message.text ? html`<p class=${message.error ? "error" : "saved"} role=${message.error ? "alert" : "status"}
                              data-test="object-message">${message.text}</p>` : null}
    </form>`;
}
