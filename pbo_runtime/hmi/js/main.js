// The HMI's frame: a header with the run (subsystem, configuration, job, the illegal-configuration
// flag, Stop), two working levels as tabs (Engineer: lexicon and job canvas; User: job dictionary
// and application workspace), and the monitor drawer below both. Each part is its own module.
// Given an application file, the page is that file's workspace: its stages and its subsystems' runs.
import { html, render, useState, useEffect } from "./html.js";
import { get, stream, verb } from "./api.js";
import { Engineer } from "./engineer.js";
import { User } from "./user.js";
import { Monitor } from "./monitor.js";
import { ApplicationUser } from "./user/application.js";

// The printed URL carries ?token=...; the server set the cookie from it, so the address bar forgets it.
if (new URLSearchParams(location.search).has("token")) history.replaceState(null, "", location.pathname);

/** The run's status, live (null while no run is attached): the status stream at 2 Hz. */
function useRunStatus() {
  const [status, setStatus] = useState(null);
  useEffect(() => {
    const status = stream("status", { rate: 2 }, (message) => setStatus(message.ok === false ? null : message));
    return () => status.close();
  }, []);
  return status;
}

function RunHeader({ status }) {
  const [stopping, setStopping] = useState(false);
  const illegal = status && (status.flags || []).includes("ILLEGAL_CONFIGURATION");
  const stop = async () => {
    if (!confirm(`Stop the run of '${status.subsystem}'? Its tasks are turned off and killed.`)) return;
    setStopping(true);
    try { await verb("stop"); } finally { setStopping(false); }
  };
  return html`
    <header class="run-header">
      <h1>pbo hmi</h1>
      ${status ? html`
        <dl class="run-facts" aria-label="the run">
          <div><dt>Subsystem</dt><dd data-test="subsystem">${status.subsystem}</dd></div>
          <div><dt>Run</dt><dd>${status.run_id}</dd></div>
          <div><dt>Configuration</dt><dd data-test="configuration">${status.configuration || "none"}</dd></div>
          <div><dt>Job</dt><dd data-test="job">${status.job || "none"}${status.path ? ` (${status.path})` : status.application ? ` (application ${status.application})` : ""}</dd></div>
        </dl>
        <span class=${"flag " + (illegal ? "flag-on" : "flag-off")} data-test="illegal" role="status">
          ${illegal ? "Configuration illegal: critical tasks hold" : "Configuration legal"}</span>
        <button class="danger" onClick=${stop} disabled=${stopping}>Stop run</button>`
      : html`<p class="no-run" data-test="no-run">No run attached: edit and check files; start one with pbo run FILE.</p>`}
    </header>`;
}

/** `pbo hmi APP.yaml`: the application file's stages, its subsystems' runs side by side (user/application.js). */
function ApplicationFile({ first }) {
  const [workspace, setWorkspace] = useState(first);
  return html`<${ApplicationUser} workspace=${workspace} setWorkspace=${setWorkspace} />`;
}

/** A subsystem file (or a run): the two levels and the monitor; an application file: its workspace. */
function Page() {
  const [application, setApplication] = useState(undefined);  // undefined: not asked yet; null: a subsystem's file
  useEffect(() => { get("application").then(setApplication, () => setApplication(null)); }, []);
  if (application === undefined) return html`<p>Loading…</p>`;
  return application ? html`<${ApplicationFile} first=${application} />` : html`<${App} />`;
}

function App() {
  const status = useRunStatus();
  const [level, setLevel] = useState("engineer");
  const tab = (name, label) => html`
    <button role="tab" id=${"tab-" + name} aria-selected=${level === name} aria-controls=${"pane-" + name}
            onClick=${() => setLevel(name)}>${label}</button>`;
  return html`
    <${RunHeader} status=${status} />
    <nav class="levels" role="tablist" aria-label="working level">
      ${tab("engineer", "Engineer: jobs from tasks")}
      ${tab("user", "User: applications from jobs")}
    </nav>
    <main>
      <section id="pane-engineer" role="tabpanel" aria-labelledby="tab-engineer" hidden=${level !== "engineer"}>
        <${Engineer} status=${status} />
      </section>
      <section id="pane-user" role="tabpanel" aria-labelledby="tab-user" hidden=${level !== "user"}>
        <${User} status=${status} />
      </section>
    </main>
    <${Monitor} status=${status} />`;
}

const root = document.getElementById("app");
root.textContent = "";  // the "Loading" line, for browsers that never get this far
render(html`<${Page} />`, root);
