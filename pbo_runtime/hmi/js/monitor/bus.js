// The bus load of the running configuration (TR eq. 1-2): each task's Z_j predicted from the file
// beside measured from the run's task rates now, and their sum B as a share of the bandwidth.
import { html, useState, useEffect, useRef } from "../html.js";
import { get } from "../api.js";

const POLL_MS = 2000;  // the status stream comes twice a second: the bus every other one
const kB = (bytesPerSecond) => (bytesPerSecond / 1e3).toFixed(1);
const percent = (share) => (share == null ? "–" : (share * 100).toFixed(3) + " %");

export function BusLoad({ status }) {
  const [bus, setBus] = useState(null);
  const [error, setError] = useState("");
  const asked = useRef(0);
  // Asked again when a status arrives at least POLL_MS after the last ask, never on a timer of its own:
  // when the server or the run is gone, the status stream stops and so does this.
  useEffect(() => {
    const now = Date.now();
    if (now - asked.current < POLL_MS) return;
    asked.current = now;
    get("monitor/bus").then((reply) => { setBus(reply); setError(""); }, (e) => setError(e.message));
  }, [status]);
  if (error) return html`<p class="error" role="alert" data-test="bus-error">${error}</p>`;
  if (!bus) return null;
  const measured = Object.fromEntries(bus.measured.tasks.map((t) => [t.task, t]));
  return html`
    <table class="bus" aria-label="bus load" data-test="bus">
      <caption>Bus load of '${bus.configuration}' (kB/s)</caption>
      <thead><tr><th scope="col">Task</th><th scope="col">RTPU</th><th scope="col">Predicted</th><th scope="col">Measured</th></tr></thead>
      <tbody>${bus.predicted.tasks.map((t) => html`
        <tr data-task=${t.task}><th scope="row">${t.task}</th><td>${t.rtpu}</td>
          <td class="predicted">${kB(t.rate_bytes_per_s)}</td>
          <td class="measured">${measured[t.task] ? kB(measured[t.task].rate_bytes_per_s) : "–"}</td></tr>`)}
      </tbody>
      <tfoot><tr data-task="B"><th scope="row">B</th><td>${percent(bus.predicted.share)} / ${percent(bus.measured.share)} of ${(bus.predicted.bandwidth / 1e6).toFixed(0)} MB/s</td>
        <td class="predicted">${kB(bus.predicted.total)}</td><td class="measured">${kB(bus.measured.total)}</td></tr></tfoot>
    </table>`;
}
