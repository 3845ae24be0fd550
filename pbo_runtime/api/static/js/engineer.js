// Engineer level (Onika §4.3): the task lexicon, one block per module made from its own
// declaration, and the job canvas where tasks are placed and their pins joined by variable name.
import { html, useState, useEffect } from "./html.js";
import { get } from "./api.js";

/** The lexicon: every installed module with its pins (in-vars, out-vars, consts) and modifiers. */
export function Lexicon() {
  const [modules, setModules] = useState(null);
  const [error, setError] = useState("");
  useEffect(() => { get("lexicon").then((reply) => setModules(reply.modules), (e) => setError(e.message)); }, []);
  if (error) return html`<p class="error" role="alert">${error}</p>`;
  if (!modules) return html`<p>Loading the lexicon…</p>`;
  return html`
    <ul class="lexicon" aria-label="task lexicon">
      ${modules.map((m) => html`
        <li class="module-block" data-module=${m.name} title=${m.summary || ""}>
          <strong>${m.name}</strong>
          <span class="pins">${m.ports.map((p) => html`<span class=${"pin " + p.kind}>${p.name}</span>`)}</span>
        </li>`)}
    </ul>`;
}

export function Engineer({ status }) {
  return html`
    <div class="engineer">
      <aside class="lexicon-pane"><h2>Task lexicon</h2><${Lexicon} /></aside>
      <div class="canvas-pane"><h2>Job canvas</h2></div>
    </div>`;
}
