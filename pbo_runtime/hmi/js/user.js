// User level (Onika §4.4): the job dictionary (actions, actions requiring an object, objects, each
// icon's edges shaped by type) on the left, the application workspace (one row of interlocking
// icons, gaps for missing objects, Save and Run) on the right, and the object values' editor in
// whichever pane it was opened from. The parts are in js/user/; this file holds their shared state:
// the dictionary as the file has it now, the row, the selected icon and the message line.
import { html, useState, useEffect } from "./html.js";
import { announceFileChanged, get, onFileChanged } from "./api.js";
import { Dictionary } from "./user/dictionary.js";
import { Workspace } from "./user/workspace.js";
import { ObjectEditor } from "./user/object_editor.js";
import { fromApplication, insert, move, remove, removeObject, setSetting } from "./user/row.js";

export function User({ status }) {
  const [dictionary, setDictionary] = useState(null);
  const [error, setError] = useState("");
  const [steps, setSteps] = useState([]);
  const [selected, setSelected] = useState(null);
  const [editing, setEditing] = useState(null);  // {name, where: "dictionary" | "workspace"}
  const [message, setMessage] = useState({ text: "", error: false });
  const [name, setName] = useState("workspace");  // the application's name, for Save and Run
  useEffect(() => {
    const read = () => get("dictionary").then((d) => { setDictionary(d); setError(""); }, (e) => setError(e.message));
    read();
    return onFileChanged(read);  // a job saved on the canvas joins the dictionary at once
  }, []);

  const apply = (result) => {
    if (result.refused) { setMessage({ text: `Refused: ${result.refused}`, error: true }); return false; }
    setSteps(result.steps);
    if (result.message) setMessage({ text: result.message, error: false });
    return true;
  };
  const actions = {
    insert(where, name = selected) {
      if (!name) { setMessage({ text: "Select an icon of the dictionary first (click it, or Space), or drag one here", error: true }); return; }
      apply(insert(dictionary, steps, name, where));
    },
    remove: (index, path = []) => apply(remove(steps, path, index)),
    move: (from, before, path = []) => apply(move(steps, path, from, before)),
    removeObject: (index, path = []) => apply(removeObject(steps, path, index)),
    setSetting: (path, index, key, value) => apply(setSetting(steps, path, index, key, value)),
    editObject: (name) => setEditing({ name, where: "workspace" }),
    clear: () => { setSteps([]); setMessage({ text: "The row is empty", error: false }); },
  };
  const select = (name, force = false) => setSelected(force || selected !== name ? name : null);
  const append = (icon) => { setSelected(icon); actions.insert({ before: steps.length }, icon); };
  const open = (application) => { if (apply(fromApplication(dictionary, application))) setName(application); };
  const saved = (reply) => { if (reply.dictionary) setDictionary(reply.dictionary); announceFileChanged(); };
  const editor = (where) => (editing && editing.where === where && dictionary ? html`
    <${ObjectEditor} dictionary=${dictionary} name=${editing.name} where=${where} onSaved=${saved}
                     onClose=${() => setEditing(null)} />` : null);

  return html`
    <div class="user user-level">
      <aside class="dictionary-pane" aria-labelledby="dictionary-title"><h2 id="dictionary-title">Job dictionary</h2>
        ${error ? html`<p class="error" role="alert">${error}</p>` : !dictionary ? html`<p>Loading…</p>` : html`
          <${Dictionary} dictionary=${dictionary} selected=${selected} onSelect=${select} onAppend=${append}
                         onEdit=${(object) => setEditing({ name: object, where: "dictionary" })} onOpen=${open} />
          ${editor("dictionary")}`}
      </aside>
      <div class="workspace-pane"><h2>Application workspace</h2>
        ${dictionary ? html`
          <${Workspace} dictionary=${dictionary} steps=${steps} actions=${actions} message=${message} setMessage=${setMessage}
                        status=${status} onSaved=${saved} name=${name} setName=${setName} />
          ${editor("workspace")}` : null}
      </div>
    </div>`;
}
