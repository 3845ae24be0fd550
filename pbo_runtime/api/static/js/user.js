// User level (Onika §4.4): the job dictionary (actions, actions requiring an object, objects, each
// icon's edges shaped by type) and the application workspace, one row of interlocking icons.
import { html, useState, useEffect } from "./html.js";
import { get } from "./api.js";

export function User({ status }) {
  const [dictionary, setDictionary] = useState(null);
  const [error, setError] = useState("");
  useEffect(() => { get("dictionary").then(setDictionary, (e) => setError(e.message)); }, []);
  return html`
    <div class="user">
      <aside class="dictionary-pane"><h2>Job dictionary</h2>
        ${error ? html`<p class="error" role="alert">${error}</p>` : !dictionary ? html`<p>Loading…</p>` : html`
          <ul aria-label="job dictionary">
            ${Object.keys(dictionary.jobs).map((name) => html`<li data-job=${name}>${name}</li>`)}
          </ul>`}
      </aside>
      <div class="workspace-pane"><h2>Application workspace</h2></div>
    </div>`;
}
