// A configuration switch: the file's configurations, the running one selected; Switch asks the run
// (verb switch) to turn the leaving tasks off and the entering ones on at one cycle boundary.
import { html, useState, useEffect } from "../html.js";
import { verb } from "../api.js";

export function ConfigurationSwitch({ status, layout, report }) {
  const names = layout ? Object.keys(layout.configurations) : [];
  const [chosen, setChosen] = useState(status.configuration);
  const [busy, setBusy] = useState(false);
  useEffect(() => setChosen(status.configuration), [status.configuration]);
  const submit = async (event) => {
    event.preventDefault();
    setBusy(true);
    try {
      const reply = await verb("switch", { configuration: chosen });
      report(true, reply.message || `switched to '${reply.configuration}'`);
    } catch (e) {
      report(false, e.message);
    } finally {
      setBusy(false);
    }
  };
  return html`
    <form class="switch" aria-label="configuration switch" onSubmit=${submit}>
      <h3>Configuration</h3>
      <label>Switch to <select value=${chosen} onChange=${(e) => setChosen(e.target.value)} aria-label="configuration">
        ${names.map((name) => html`<option value=${name}>${name}${name === status.configuration ? " (running)" : ""}</option>`)}
      </select></label>
      <button type="submit" disabled=${busy || !names.length || chosen === status.configuration}>Switch</button>
    </form>`;
}
