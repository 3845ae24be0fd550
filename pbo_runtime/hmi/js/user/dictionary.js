// The job dictionary (Onika §4.4.1): actions, actions requiring an object, objects, and the
// applications saved from the workspace (an incomplete one whose gaps take one type is an action
// requiring an object, reusable). Each is an icon with its edges by type, to drag into the
// workspace, or to pick with the keyboard: Enter appends it to the row, Space selects it for a slot.
import { html } from "../html.js";
import { IconSvg, TypeSwatch, typeStyle } from "./edges.js";
import { DECISIONS, iconOf } from "./row.js";

export { DictionaryIcon };
export const DRAG_ICON = "application/x-pbo-icon";

const SUBTITLES = {
  action: () => "action",
  action_requiring_object: (entry) => `needs ${entry.object_type}`,
  incomplete: () => "gaps of several types",
};

/** What a screen reader says of an icon. */
export function iconLabel(name, entry, what) {
  if (what === "decision") return `${name}: a step that decides: ${entry.doc}`;
  if (what === "object") return `${name}: object of type ${entry.type}`;
  const kind = what === "application" ? "application" : "job";
  if (entry.class === "action_requiring_object") return `${name}: ${kind}, an action requiring an object of type ${entry.object_type}`;
  if (entry.class === "incomplete") return `${name}: ${kind} with gaps of several object types`;
  return `${name}: ${kind}, an action`;
}

/** One icon of the dictionary: a button, draggable; aria-pressed when selected. */
function DictionaryIcon({ name, entry, what, selected, onSelect, onAppend, prefix = "", note = null, label = null }) {
  const id = prefix + name;  // an application file's workspace: `subsystem:name`, the icon of that subsystem
  const kind = what === "object" ? "object" : what === "decision" ? "decision" : entry.class;
  const subtitle = note ? note : what === "object" ? entry.type : what === "decision" ? "decides"
                 : (what === "application" ? "app · " : "") + SUBTITLES[entry.class](entry);
  return html`
    <button class=${"icon dictionary-icon" + (selected ? " selected" : "")} draggable="true" aria-pressed=${selected}
            aria-label=${label || iconLabel(name, entry, what)} data-icon=${name} data-class=${kind}
            title=${entry.doc || label || iconLabel(name, entry, what)}
            onDragStart=${(e) => { e.dataTransfer.setData(DRAG_ICON, id); e.dataTransfer.setData("text/plain", id);
                                   e.dataTransfer.effectAllowed = "copy"; onSelect(id, true); }}
            onClick=${() => onSelect(id)}
            onKeyDown=${(e) => { if (e.key === "Enter") { e.preventDefault(); onAppend(id); } }}>
      <${IconSvg} edges=${entry.edges} kind=${kind} title=${name} subtitle=${subtitle} application=${what === "application"} />
    </button>`;
}

function Section({ title, items, selected, onSelect, onAppend, onEdit, onOpen, test, prefix = "" }) {
  if (!items.length) return null;
  return html`
    <section class="dictionary-section" data-test=${test}>
      <h3>${title}</h3>
      <ul class="icon-list" aria-label=${title}>
        ${items.map(([name, entry, what]) => html`
          <li key=${name}>
            <${DictionaryIcon} name=${name} entry=${entry} what=${what} selected=${selected === prefix + name}
                               onSelect=${onSelect} onAppend=${onAppend} prefix=${prefix} />
            ${what === "object" && onEdit ? html`<button class="icon-action" aria-label=${`edit the values of ${name}`}
                                               onClick=${() => onEdit(name)}>Edit values</button>` : null}
            ${what === "application" && onOpen ? html`<button class="icon-action" aria-label=${`open application ${name} in the workspace`}
                                                    onClick=${() => onOpen(name)}>Open</button>` : null}
          </li>`)}
      </ul>
    </section>`;
}

/** The dictionary pane: the object types' legend, then the icons by class. */
export function Dictionary({ dictionary, selected, onSelect, onAppend, onEdit, onOpen, prefix = "" }) {
  const jobs = Object.entries(dictionary.jobs).map(([name, entry]) => [name, entry, "job"]);
  const applications = Object.entries(dictionary.applications).map(([name, entry]) => [name, entry, "application"]);
  const all = [...jobs, ...applications];
  const objects = Object.entries(dictionary.objects).map(([name, entry]) => [name, entry, "object"]);
  const common = { selected, onSelect, onAppend, onEdit, onOpen, prefix };
  return html`
    <div class="dictionary" aria-label="job dictionary">
      ${prefix ? null : html`<p class="hint">Drag an icon into the workspace, or press Enter on it to append it. Click (or Space)
        selects it; then Enter on a place or a gap of the row puts it there.</p>`}
      ${Object.keys(dictionary.object_types).length ? html`
        <section class="type-legend" aria-label="object types">
          <h3>Object types</h3>
          <ul>
            ${Object.entries(dictionary.object_types).map(([type, spec]) => html`
              <li data-type=${type} data-shape=${typeStyle(type).shape}>
                <${TypeSwatch} type=${type} />
                <span><strong>${type}</strong> ${spec.type}${spec.shape.length ? ` [${spec.shape.join(", ")}]` : ""}${spec.unit ? `, ${spec.unit}` : ""}</span>
              </li>`)}
          </ul>
        </section>` : null}
      <${Section} title="Actions" test="actions" items=${all.filter(([, e]) => e.class === "action")} ...${common} />
      <${Section} title="Actions requiring an object" test="actions-requiring-object"
                  items=${all.filter(([, e]) => e.class === "action_requiring_object")} ...${common} />
      <${Section} title="Incomplete applications (gaps of several types)" test="incomplete"
                  items=${all.filter(([, e]) => e.class === "incomplete")} ...${common} />
      <${Section} title="Objects" test="objects" items=${objects} ...${common} />
      <${Section} title="Steps that decide" test="decisions" ...${common}
                  items=${Object.keys(DECISIONS).filter((name) => iconOf(dictionary, name).what === "decision")
                            .map((name) => [name, { ...iconOf(dictionary, name), doc: DECISIONS[name].doc }, "decision"])} />
    </div>`;
}
