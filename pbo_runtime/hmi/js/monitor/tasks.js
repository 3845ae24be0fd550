// The run's tasks by RTPU, live from the status stream: state, rate, jitter, overruns, execution
// time, the error a task stopped with, and the operator's buttons (Clear an ERROR, On, Off).
import { html, useState } from "../html.js";
import { verb } from "../api.js";

const ms = (seconds) => (seconds == null ? "–" : (seconds * 1e3).toFixed(3));

/** Which buttons a task in `state` offers: clear its error, turn it on, turn it off. */
function actionsFor(state) {
  if (state === "ERROR") return ["clear"];
  if (state === "OFF" || state === "CREATED") return ["on"];
  if (state === "ON") return ["off"];
  return [];
}
const LABEL = { clear: "Clear", on: "On", off: "Off" };

function TaskRow({ task, report }) {
  const [busy, setBusy] = useState(false);
  const act = async (name) => {
    setBusy(true);
    try {
      const reply = await verb(name, { task: task.task });
      report(true, reply.message || `${name} ${task.task}: ${reply.state || "done"}`);
    } catch (e) {
      report(false, e.message);
    } finally {
      setBusy(false);
    }
  };
  return html`
    <tr data-task=${task.task} data-state=${task.state}>
      <th scope="row">${task.task}</th>
      <td class=${"state state-" + task.state}>${task.state}</td>
      <td>${task.rate.toFixed(1)}</td><td>${ms(task.jitter_p99)}</td><td>${task.overruns}</td><td>${ms(task.exec_p99)}</td>
      <td class="task-error"><span title=${task.error || ""}>${task.error || ""}</span></td>
      <td class="task-actions">${actionsFor(task.state).map((name) => html`
        <button onClick=${() => act(name)} disabled=${busy} aria-label=${`${LABEL[name]} ${task.task}`}
                class=${name === "clear" ? "clear" : ""}>${LABEL[name]}</button>`)}</td>
    </tr>`;
}

export function TasksByRtpu({ status, report }) {
  const byRtpu = {};
  for (const t of status.tasks) (byRtpu[t.rtpu] = byRtpu[t.rtpu] || []).push(t);
  return html`<div class="rtpus">${Object.entries(byRtpu).map(([rtpu, tasks]) => html`
    <table class="tasks" aria-label=${"tasks on " + rtpu}>
      <caption>${rtpu}</caption>
      <thead><tr><th scope="col">Task</th><th scope="col">State</th><th scope="col">Rate (Hz)</th>
        <th scope="col">Jitter p99 (ms)</th><th scope="col">Overruns</th><th scope="col">Exec p99 (ms)</th>
        <th scope="col">Error</th><th scope="col"><span class="sr-only">Actions</span></th></tr></thead>
      <tbody>${tasks.map((t) => html`<${TaskRow} key=${t.task} task=${t} report=${report} />`)}</tbody>
    </table>`)}</div>`;
}

/** While the configuration is illegal: which tasks are in ERROR, and what the operator does about it. */
export function IllegalNote({ status }) {
  const illegal = (status.flags || []).includes("ILLEGAL_CONFIGURATION");
  if (!illegal) return null;
  const failed = status.tasks.filter((t) => t.state === "ERROR").map((t) => t.task);
  return html`<p class="illegal-note" role="alert" data-test="monitor-illegal">
    Configuration '${status.configuration}' is illegal: critical tasks hold.
    ${failed.length ? `In ERROR: ${failed.join(", ")}. Clear the error, then turn the task On.` : ""}</p>`;
}
