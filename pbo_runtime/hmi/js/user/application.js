// An application file's workspace (`pbo hmi APP.yaml`): its `run:` as a row of `parallel` steps, one
// a stage, each with one arm (a row of steps) for every subsystem of the file. An arm's steps are
// that subsystem's jobs, applications, objects and steps that decide, with the same icons, edges,
// gaps, drag and drop and keys as a subsystem's workspace; the dictionary groups the icons by
// subsystem, and an icon dropped in another subsystem's arm is refused: its edges interlock with
// its own subsystem's objects, and the arm runs on the other subsystem's table. Save writes `run:`
// back (checked like `pbo check APP.yaml` first); Run starts `pbo run APP.yaml`, and each
// subsystem's status stream lights its running step in its arm and names where it is.
import { html, useState, useEffect, useRef } from "../html.js";
import { get, post, stream } from "../api.js";
import { IconSvg } from "./edges.js";
import { Dictionary, DictionaryIcon } from "./dictionary.js";
import { Place, RowView, dropProps, runOrder } from "./workspace.js";
import { DECISIONS, FLAT_EDGES, entriesToSteps, gaps, gapsSentence, insert, move, newStep, remove, removeObject,
         rowBody, setSetting } from "./row.js";

const PARALLEL_DOC = "runs each subsystem's arm at once, and goes on when every arm is done (the join)";

/** The file's stages as the row: parallel steps with one arm per subsystem, in the file's order of subsystems. */
function stagesToSteps(workspace) {
  const keys = Object.keys(workspace.subsystems);
  return workspace.stages.map((stage) => newStep({
    name: "parallel", kind: "parallel", arms: keys,
    rows: keys.map((key) => (stage.arms[key] ? entriesToSteps(stage.arms[key].steps, [], key) : [])) }));
}

/** `subsystem:name` of the dictionary of an application file, or a bare name (parallel). */
function parseIcon(id) {
  const at = id.indexOf(":");
  return at < 0 ? { key: null, name: id } : { key: id.slice(0, at), name: id.slice(at + 1) };
}

/**
 * Where each subsystem's run is, as a place in the row ([stage, arm, step, ...]), from its status. The
 * stage: the status's path names it when its steps decide (`stage_3 > then > reach`), or names the
 * application of an `{app: NAME}` stage (`wave > repeat 1/2 > reach`: the first such stage from the
 * last join); else it is the first stage from the last join whose arm runs the job. The last join: the
 * stages the run said the subsystem has done, or its status path while it joins (`stage N > join`).
 * The step: the status's place in a row that decides, or the running job among the arm's jobs in order
 * (`progress` keeps where it was, for a job that comes twice).
 */
function placeOf(status, key, keys, stages, joined, dictionary, progress) {
  if (!status || !status.job) return null;
  const arm = keys.indexOf(key);
  const head = (status.path || "").split(" > ")[0];
  const staged = /^stage_(\d+)$/.exec(head);
  const runs = (i) => runOrder(dictionary, stages[i].rows[arm]).some(([job]) => job === status.job);
  const fits = (i) => { const row = stages[i].rows[arm]; return row.length === 1 && row[0].name === head; };
  const from = (test) => { const i = stages.findIndex((_, k) => k >= joined && test(k)); return i >= 0 ? i : stages.findIndex((_, k) => test(k)); };
  if (head && !staged) { const stage = from(fits); return stage >= 0 ? [stage, arm, 0] : null; }
  const stage = staged ? Number(staged[1]) - 1 : from(runs);
  if (!stages[stage]) return null;
  if (status.place && status.place.length) return [stage, arm, ...status.place];
  const order = runOrder(dictionary, stages[stage].rows[arm]);
  const was = progress[key] && progress[key].stage === stage ? progress[key].position : -1;
  let position = was >= 0 && order[was][0] === status.job ? was : order.findIndex(([job], i) => i > was && job === status.job);
  if (position < 0) position = order.findIndex(([job]) => job === status.job);
  progress[key] = { stage, position };
  return position >= 0 ? [stage, arm, order[position][1]] : null;
}

/** Each subsystem's status stream (by its own name), side by side: {key: status or null}. */
function useStatuses(workspace) {
  const [statuses, setStatuses] = useState({});
  const joined = useRef({});  // key -> stages joined (the status path says "stage N > join" while it waits)
  const names = workspace ? Object.entries(workspace.subsystems).map(([key, s]) => [key, s.name]) : [];
  useEffect(() => {
    const streams = names.map(([key, name]) => stream("status", { rate: 4, subsystem: name }, (message) => {
      const status = message.ok === false ? null : message;
      const join = status && /^stage (\d+) > join$/.exec(status.path || "");
      if (join) joined.current[key] = Number(join[1]);
      if (!status) joined.current[key] = 0;
      setStatuses((before) => ({ ...before, [key]: status }));
    }));
    return () => streams.forEach((s) => s.close());
  }, [names.map(([, n]) => n).join(",")]);
  return { statuses, joined: joined.current };
}

/** One stage: the parallel icon, then one arm for each subsystem, each a row of that subsystem's steps. */
function ParallelUnit({ workspace, step, index, count, actions, places, stagesDone }) {
  const keys = (e) => {
    if (e.key === "Delete" || e.key === "Backspace") { e.preventDefault(); actions.remove(index, []); }
    else if (e.altKey && e.key === "ArrowLeft" && index > 0) { e.preventDefault(); actions.move(index, index - 1, []); }
    else if (e.altKey && e.key === "ArrowRight" && index < count - 1) { e.preventDefault(); actions.move(index, index + 2, []); }
  };
  // the run's output says when each subsystem has done a stage: however short, an arm that ran steps is marked
  const done = (key) => (stagesDone[key] || 0) > index && step.rows[step.arms.indexOf(key)].length > 0;
  return html`
    <div class="unit decision parallel" role="listitem" data-step=${index + 1} data-kind="parallel">
      <div class="decision-head">
        <button class="icon step-icon" data-name="parallel" onKeyDown=${keys}
                aria-label=${`step ${index + 1}: parallel, stage ${index + 1} of run: ${PARALLEL_DOC}; Delete removes it, Alt+arrows move it`}>
          <${IconSvg} edges=${FLAT_EDGES} kind="decision" title="parallel" subtitle=${`stage ${index + 1}, at once`} />
        </button>
        <span class="step-tools">
          <button aria-label=${`remove step ${index + 1} parallel`} onClick=${() => actions.remove(index, [])}>✕</button>
        </span>
      </div>
      ${step.arms.map((key, arm) => html`
        <div class=${"decision-row parallel-arm" + (done(key) ? " arm-done" : "")} key=${key} data-arm=${key}
             data-done=${done(key) ? "true" : null}>
          <span class="decision-label" title=${workspace.subsystems[key].name + (done(key) ? ": done in the last run" : "")}>${key}</span>
          <${RowView} dictionary=${workspace.subsystems[key].dictionary} steps=${step.rows[arm]} actions=${actions}
                      path=${[index, arm]} statusPlace=${places[key]} name=${`${key} of step ${index + 1} parallel`} />
        </div>`)}
    </div>`;
}

/** The header of an application file: each subsystem's run, where it is, and the run the page started. */
export function ApplicationHeader({ workspace, statuses, places, run, onStop }) {
  return html`
    <header class="run-header">
      <h1>pbo hmi</h1>
      <dl class="run-facts" aria-label="the application's subsystems">
        <div><dt>Application</dt><dd data-test="application">${workspace.application}</dd></div>
        ${Object.entries(workspace.subsystems).map(([key, sub]) => {
          const status = statuses[key];
          const stage = places[key] ? `stage ${places[key][0] + 1}` : "";
          return html`<div key=${key}><dt>${key} (${sub.name})</dt>
            <dd data-test=${"subsystem-path-" + key}>${!status ? "not running" : status.job
              ? `${status.job} (${[stage, status.path].filter(Boolean).join(": ")})` : status.path || status.configuration || "no job"}</dd></div>`;
        })}
      </dl>
      ${run && run.running ? html`<button class="danger" onClick=${onStop}>Stop run</button>` : null}
    </header>`;
}

/** The workspace of an application file: the dictionary by subsystem, the stages, Save and Run. */
export function ApplicationUser({ workspace, setWorkspace }) {
  const [steps, setSteps] = useState(() => stagesToSteps(workspace));
  const [selected, setSelected] = useState(null);
  const [message, setMessage] = useState({ text: "", error: false });
  const [dirty, setDirty] = useState(false);
  const [busy, setBusy] = useState(false);
  const [clock, setClock] = useState("real");
  const [run, setRun] = useState(workspace.run);
  const { statuses, joined } = useStatuses(workspace);
  const keys = Object.keys(workspace.subsystems);
  useEffect(() => {
    const timer = setInterval(() => get("application/run").then((r) => setRun(r.run), () => {}), 500);
    return () => clearInterval(timer);
  }, []);

  const apply = (result) => {
    if (result.refused) { setMessage({ text: `Refused: ${result.refused}`, error: true }); return false; }
    setSteps(result.steps);
    setDirty(true);
    if (result.message) setMessage({ text: result.message, error: false });
    return true;
  };
  const refuse = (text) => apply({ refused: text });
  const actions = {
    insert(where, id = selected) {
      if (!id) { refuse("select an icon of the dictionary first (click it, or Space), or drag one here"); return; }
      const { key, name } = parseIcon(id);
      const path = where.path || [];
      if (!path.length) {
        if (name !== "parallel") {
          refuse(`'${name}'${key ? ` of subsystem '${key}'` : ""} goes into an arm of a parallel step: the row of an application `
                 + "file holds its stages; drop a parallel step here first, then each subsystem's steps into its arm");
          return;
        }
        if (where.slot !== undefined) { refuse("a parallel step goes between stages, not into a slot"); return; }
        const at = Math.max(0, Math.min(where.before, steps.length));
        const made = newStep({ name: "parallel", kind: "parallel", arms: keys, rows: keys.map(() => []) });
        apply({ steps: [...steps.slice(0, at), made, ...steps.slice(at)],
                message: `'parallel' inserted as stage ${at + 1}: drop each subsystem's steps into its arm (${keys.join(", ")})` });
        return;
      }
      const arm = keys[path[1]];
      if (name === "parallel") {
        refuse(`a parallel step runs the file's subsystems at once: it is a stage of run:, in the application's row, not a step `
               + `inside the arm of '${arm}'`);
        return;
      }
      if (key && key !== arm && !DECISIONS[name]) {
        const what = workspace.subsystems[key].dictionary.objects[name] ? "object" : "job";
        refuse(`'${name}' is ${what === "object" ? "an object" : "a step"} of subsystem '${key}': its edges interlock with `
               + `'${key}''s objects and jobs only, and the arm of '${arm}' runs on '${arm}''s own table; `
               + `drop '${arm}''s icons here, or put '${name}' in the arm of '${key}'`);
        return;
      }
      apply(insert(workspace.subsystems[arm].dictionary, steps, name, { ...where, subsystem: arm }));
    },
    remove: (index, path = []) => apply(remove(steps, path, index)),
    move: (from, before, path = []) => apply(move(steps, path, from, before)),
    removeObject: (index, path = []) => apply(removeObject(steps, path, index)),
    setSetting: (path, index, key, value) => apply(setSetting(steps, path, index, key, value)),
    editObject: (name) => setMessage({ text: `'${name}' is a value of its subsystem's file: edit it there (pbo hmi SUBSYSTEM.yaml)`,
                                       error: false }),
  };
  const select = (id, force = false) => setSelected(force || selected !== id ? id : null);
  const append = (id) => {  // Enter on an icon: a stage at the end, or the step at the end of its subsystem's arm in the last stage
    setSelected(id);
    const { key } = parseIcon(id);
    if (!key || !steps.length) { actions.insert({ path: [], before: steps.length }, id); return; }
    const last = steps.length - 1;
    actions.insert({ path: [last, keys.indexOf(key)], before: steps[last].rows[keys.indexOf(key)].length }, id);
  };

  const open = steps.flatMap((stage, i) => stage.arms.flatMap((key, arm) =>
    gaps(workspace.subsystems[key].dictionary, stage.rows[arm], `${i + 1} (parallel, ${key}): step `)));
  const save = async () => {
    setBusy(true);
    try {
      const body = steps.map((stage) => ({ arms: Object.fromEntries(stage.arms.map((key, arm) => [key, rowBody(stage.rows[arm])])) }));
      const reply = await post("application/stages", { stages: body });
      setWorkspace(reply);
      setSteps(stagesToSteps(reply));
      setDirty(false);
      setMessage({ text: reply.message, error: false });
    } catch (e) {
      setMessage({ text: `Not saved: ${e.message.replace(/^not saved: /, "")}`, error: true });
    } finally {
      setBusy(false);
    }
  };
  const start = async () => {
    const reason = !steps.length ? "the workspace is empty: drop a parallel step into it first"
      : open.length ? gapsSentence(open) : dirty ? "the stages changed since they were saved: Save them first (Run runs the file)"
      : run && run.running ? "the application runs already: stop it first, or wait until it ends" : "";
    if (reason) { setMessage({ text: `Run refused: ${reason}`, error: true }); return; }
    setBusy(true);
    try {
      const reply = await post("application/run", { clock });
      setRun(reply.run);
      setMessage({ text: reply.message, error: false });
    } catch (e) {
      setMessage({ text: `Run refused: ${e.message}`, error: true });
    } finally {
      setBusy(false);
    }
  };
  const stop = async () => {
    try { const reply = await post("application/stop"); setRun(reply.run); } catch (e) { setMessage({ text: e.message, error: true }); }
  };
  const progress = useRef({});
  // a run started here says how many stages each subsystem has done; one started elsewhere, only its joins
  const done = (key) => (run && run.running ? run.stages_done[key] || 0 : 0);
  const places = Object.fromEntries(keys.map((key) => [key, placeOf(statuses[key], key, keys, steps,
    Math.max(joined[key] || 0, done(key)), workspace.subsystems[key].dictionary, progress.current)]));
  const [over, setOver] = useState(false);
  const ended = run && run.started && !run.running;
  const lastLine = run && run.lines.length ? run.lines[run.lines.length - 1] : "";

  return html`
    <${ApplicationHeader} workspace=${workspace} statuses=${statuses} places=${places} run=${run} onStop=${stop} />
    <main>
      <section class="user user-level" aria-label="the application file's workspace">
        <aside class="dictionary-pane" aria-labelledby="dictionary-title"><h2 id="dictionary-title">Job dictionary</h2>
          <p class="hint">Each subsystem's icons go into that subsystem's arm of a parallel step. Drag an icon, or press
            Enter on it to append it (a job to its arm in the last stage); click (or Space) selects it, then Enter on a
            place or a gap puts it there.</p>
          <section class="dictionary-section" data-test="stages">
            <h3>Stages</h3>
            <ul class="icon-list" aria-label="stages"><li>
              <${DictionaryIcon} name="parallel" entry=${{ edges: FLAT_EDGES, doc: PARALLEL_DOC }} what="decision"
                                 selected=${selected === "parallel"} onSelect=${select} onAppend=${append} note="at once"
                                 label=${`parallel: a stage of run: that ${PARALLEL_DOC}`} />
            </li></ul>
          </section>
          ${keys.map((key) => html`
            <section class="subsystem-dictionary" key=${key} data-subsystem=${key} aria-label=${`subsystem ${key}`}>
              <h3>Subsystem ${key} <small>(${workspace.subsystems[key].name})</small></h3>
              <${Dictionary} dictionary=${workspace.subsystems[key].dictionary} selected=${selected} onSelect=${select}
                             onAppend=${append} prefix=${key + ":"} />
            </section>`)}
        </aside>
        <div class="workspace-pane"><h2>Application workspace: ${workspace.application}, its stages (run:)</h2>
          <div class="workspace">
            <div class=${"row" + (over ? " over" : "")} role="list" aria-label="application workspace" data-test="workspace-row"
                 ...${dropProps((id) => actions.insert({ path: [], before: steps.length }, id),
                                (from) => { if (!from.path.length) actions.move(from.index, steps.length); }, setOver)}>
              <${Place} before=${0} count=${steps.length} onInsert=${actions.insert} onMove=${actions.move} />
              ${steps.map((step, index) => html`
                <${ParallelUnit} key=${step.id} workspace=${workspace} step=${step} index=${index} count=${steps.length}
                                 actions=${actions} places=${places} stagesDone=${(run && run.stages_done) || {}} />
                <${Place} key=${"place" + step.id} before=${index + 1} count=${steps.length} onInsert=${actions.insert}
                          onMove=${actions.move} />`)}
            </div>
            <p class="readiness" data-test="run-readiness">${!steps.length ? "Empty: drop a parallel step from the dictionary."
              : open.length ? `Not runnable: ${open.length} gap${open.length === 1 ? "" : "s"} to fill.`
              : dirty ? "Changed: save the stages to run them." : "Saved: ready to run."}</p>
            ${message.text ? html`<p class=${message.error ? "error" : "note"} role=${message.error ? "alert" : "status"}
                                    data-test="workspace-message">${message.text}</p>` : null}
            <p class="running-line" data-test="workspace-running" role="status">
              ${run && run.running ? `Running: pbo run on the ${run.clock === "sim" ? "simulated" : "real"} clock (pid ${run.pid})`
                : ended ? `Ended: ${run.exit === 0 ? "every subsystem ran its stages to the end (exit 0)" : `exit ${run.exit}`}${lastLine ? `; ${lastLine}` : ""}`
                : "Not running."}
            </p>
            <div class="workspace-actions">
              <button type="button" disabled=${busy || !steps.length} onClick=${save}>Save stages</button>
              <label>Clock <select aria-label="clock" value=${clock} onChange=${(e) => setClock(e.currentTarget.value)}>
                <option value="real">real</option><option value="sim">simulated</option></select></label>
              <button type="button" class="run" data-test="run" disabled=${busy} onClick=${start}>Run</button>
            </div>
          </div>
        </div>
      </section>
    </main>`;
}
