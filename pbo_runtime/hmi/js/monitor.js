// The monitor drawer, on both levels: the run's tasks by RTPU with their errors and Clear/On/Off,
// the illegal-configuration flag, a configuration switch, parameters tunable live, the bus load
// predicted beside measured, live plots of chosen state variables and the arm drawn as it moves.
// Each part is its own module under js/monitor/; this one fetches what the file says and lays them out.
import { html, useState, useEffect, useCallback } from "./html.js";
import { get } from "./api.js";
import { TasksByRtpu, IllegalNote } from "./monitor/tasks.js";
import { ConfigurationSwitch } from "./monitor/switch.js";
import { Tunables } from "./monitor/tune.js";
import { PlayedDevices } from "./monitor/trackball.js";
import { BusLoad } from "./monitor/bus.js";
import { Plots } from "./monitor/plot.js";
import { ArmView } from "./monitor/arm.js";

/** What the file says of the run (tasks' modules and tunable parameters, configurations, variables), fetched once per run. */
function useLayout(status) {
  const [layout, setLayout] = useState(null);
  const run = status ? status.run_id : null;
  useEffect(() => {
    if (!run) { setLayout(null); return; }
    let live = true;
    get("monitor/layout").then((reply) => live && setLayout(reply), () => live && setLayout(null));
    return () => { live = false; };
  }, [run]);
  return layout;
}

/** One line saying what the last verb did, or why it was refused (the API's one-line error). */
function useOutcome() {
  const [outcome, setOutcome] = useState(null);
  const report = useCallback((ok, text) => setOutcome({ ok, text }), []);
  const line = outcome && html`
    <p class=${"outcome " + (outcome.ok ? "outcome-ok" : "error")} role=${outcome.ok ? "status" : "alert"}
       data-test="monitor-outcome">${outcome.text}</p>`;
  return [line, report];
}

export function Monitor({ status }) {
  const [open, setOpen] = useState(true);
  const layout = useLayout(status);
  const [outcome, report] = useOutcome();
  return html`
    <section class="monitor" aria-label="monitor">
      <button class="drawer-handle" aria-expanded=${open} onClick=${() => setOpen(!open)}>Monitor</button>
      ${open && (status ? html`
        <div class="monitor-body">
          <div class="monitor-column">
            <${IllegalNote} status=${status} />
            ${outcome}
            <${TasksByRtpu} status=${status} report=${report} />
            <div class="monitor-row">
              <${ConfigurationSwitch} status=${status} layout=${layout} report=${report} />
              <${Tunables} status=${status} layout=${layout} report=${report} />
              <${PlayedDevices} status=${status} layout=${layout} report=${report} />
            </div>
            <${BusLoad} status=${status} />
          </div>
          <div class="monitor-column">
            <${Plots} status=${status} layout=${layout} />
            <${ArmView} status=${status} layout=${layout} />
          </div>
        </div>`
      : html`<p class="no-run">The monitor shows a run once one is attached.</p>`)}
    </section>`;
}
