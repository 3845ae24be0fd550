// Parameters tunable live (verb set): for each running task, the parameters its module declares
// tunable (its TUNABLE), with the file's value to start from. A value is YAML, as on the command
// line: one number, or several (one per joint) separated by spaces.
import { html, useState } from "../html.js";
import { verb } from "../api.js";

const text = (value) => (Array.isArray(value) ? value.join(" ") : value == null ? "" : String(value));

function Tunable({ task, param, initial, report }) {
  const [value, setValue] = useState(text(initial));
  const [busy, setBusy] = useState(false);
  const submit = async (event) => {
    event.preventDefault();
    const values = value.trim().split(/[\s,]+/).filter(Boolean);
    if (!values.length) { report(false, `give ${task} ${param} a value`); return; }
    setBusy(true);
    try {
      const reply = await verb("set", { task, param, values });
      report(true, reply.message || `'${param}' of task '${task}' is ${values.join(" ")}`);
    } catch (e) {
      report(false, e.message);
    } finally {
      setBusy(false);
    }
  };
  const id = `tune-${task}-${param}`;
  return html`
    <form class="tunable" onSubmit=${submit} data-tunable=${`${task}.${param}`}>
      <label for=${id}>${task} ${param}</label>
      <input id=${id} value=${value} onInput=${(e) => setValue(e.target.value)} size="10" />
      <button type="submit" disabled=${busy} aria-label=${`Set ${task} ${param}`}>Set</button>
    </form>`;
}

export function Tunables({ status, layout, report }) {
  if (!layout) return null;
  const running = status.tasks.filter((t) => layout.tasks[t.task] && Object.keys(layout.tasks[t.task].tunable).length);
  return html`
    <section class="tunables" aria-label="tunable parameters">
      <h3>Tune live</h3>
      ${running.length ? running.map((t) => Object.entries(layout.tasks[t.task].tunable).map(([param, value]) => html`
        <${Tunable} key=${t.task + param} task=${t.task} param=${param} initial=${value} report=${report} />`))
      : html`<p class="no-run">No running task has a parameter tunable live.</p>`}
    </section>`;
}
