// The monitor drawer, on both levels: tasks by RTPU, live, from the status stream.
import { html, useState } from "./html.js";

const ms = (seconds) => (seconds == null ? "–" : (seconds * 1e3).toFixed(3));

function TasksByRtpu({ status }) {
  const byRtpu = {};
  for (const t of status.tasks) (byRtpu[t.rtpu] = byRtpu[t.rtpu] || []).push(t);
  return Object.entries(byRtpu).map(([rtpu, tasks]) => html`
    <table class="tasks" aria-label=${"tasks on " + rtpu}>
      <caption>${rtpu}</caption>
      <thead><tr><th scope="col">Task</th><th scope="col">State</th><th scope="col">Rate (Hz)</th>
        <th scope="col">Jitter p99 (ms)</th><th scope="col">Overruns</th><th scope="col">Exec p99 (ms)</th></tr></thead>
      <tbody>${tasks.map((t) => html`
        <tr data-task=${t.task}><th scope="row">${t.task}</th><td class=${"state state-" + t.state}>${t.state}</td>
          <td>${t.rate.toFixed(1)}</td><td>${ms(t.jitter_p99)}</td><td>${t.overruns}</td><td>${ms(t.exec_p99)}</td></tr>`)}
      </tbody>
    </table>`);
}

export function Monitor({ status }) {
  const [open, setOpen] = useState(true);
  return html`
    <section class="monitor" aria-label="monitor">
      <button class="drawer-handle" aria-expanded=${open} onClick=${() => setOpen(!open)}>Monitor</button>
      ${open && (status ? html`<div class="monitor-body"><${TasksByRtpu} status=${status} /></div>`
                        : html`<p class="no-run">The monitor shows a run once one is attached.</p>`)}
    </section>`;
}
