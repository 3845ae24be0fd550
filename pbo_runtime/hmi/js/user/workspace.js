// The application workspace (Onika §4.4.2, Fig. 4): one row of interlocking icons. Icons come from
// the dictionary by drag and drop or by keyboard; a step that needs an object shows the object that
// fills it or a gap of its type; non-interlocking icons are refused with the reason. Steps are
// removed and moved with their objects. Save writes the row to the YAML file as an application
// (with gaps too: an incomplete one, reused as an icon); Run runs it on the attached run, refused
// while gaps remain or no run is attached, and the running job is highlighted from the status stream.
// A step that decides (if, try, repeat, wait) is drawn as an icon with its settings and its rows of
// steps, each row with the same places, gaps, drag and drop and keys as the workspace's own row.
import { html, useState, useEffect } from "../html.js";
import { post } from "../api.js";
import { IconSvg } from "./edges.js";
import { DRAG_ICON, iconLabel } from "./dictionary.js";
import { DECISIONS, iconOf, gaps, gapsSentence, rowBody } from "./row.js";

const DRAG_STEP = "application/x-pbo-step";

function dragged(event) {
  const types = Array.from(event.dataTransfer.types || []);
  if (types.includes(DRAG_STEP)) return { step: JSON.parse(event.dataTransfer.getData(DRAG_STEP)) };
  if (types.includes(DRAG_ICON)) return { icon: event.dataTransfer.getData(DRAG_ICON) };
  return null;
}

/** A drop target that takes dictionary icons and (for places) the row's own steps. */
export function dropProps(onDropIcon, onDropStep, setOver) {
  return {
    onDragOver: (e) => { e.preventDefault(); setOver(true); },
    onDragLeave: () => setOver(false),
    onDrop: (e) => {
      e.preventDefault();
      e.stopPropagation();
      setOver(false);
      const what = dragged(e);
      if (!what) return;
      if (what.icon !== undefined) onDropIcon(what.icon);
      else if (onDropStep) onDropStep(what.step);
    },
  };
}

/** A place between steps (or at either end): where an icon goes; Enter or a click puts the selected icon there. */
export function Place({ before, count, onInsert, onMove, path = [], where = "" }) {
  const [over, setOver] = useState(false);
  const label = (count === 0 ? "insert the first step here" : before === count ? "insert at the end of the row"
                                                             : `insert before step ${before + 1}`) + where;
  const sameRow = (from) => { if (JSON.stringify(from.path) === JSON.stringify(path)) onMove(from.index, before, path); };
  return html`
    <button class=${"place" + (over ? " over" : "")} aria-label=${label} data-place=${before}
            onClick=${() => onInsert({ path, before })}
            ...${dropProps((icon) => onInsert({ path, before }, icon), sameRow, setOver)}>
      <span aria-hidden="true">${count === 0 ? (path.length ? "Drop steps here" : "Drop jobs here") : "+"}</span>
    </button>`;
}

/** Step `index`'s slot: the object that fills it, or its gap. */
function Slot({ step, index, icon, onInsert, onRemoveObject, onEditObject, path = [] }) {
  const [over, setOver] = useState(false);
  const drop = dropProps((name) => onInsert({ path, slot: index }, name), null, setOver);
  const type = icon.object_type;
  if (step.object) {
    return html`
      <button class=${"icon slot-object" + (over ? " over" : "")} data-object=${step.object}
              aria-label=${`object ${step.object} (${type}) of step ${index + 1} ${step.name}: Enter edits its values, Delete takes it out`}
              onClick=${() => onEditObject(step.object)}
              onKeyDown=${(e) => { if (e.key === "Delete" || e.key === "Backspace") { e.preventDefault(); onRemoveObject(index, path); } }}
              ...${drop}>
        <${IconSvg} edges=${{ left: { shape: "tab", object_type: type }, right: { shape: "flat" } }} kind="object"
                    title=${step.object} subtitle=${type} />
      </button>`;
  }
  return html`
    <button class=${"icon gap" + (over ? " over" : "")} data-gap-type=${type}
            aria-label=${`gap: an object of type ${type} for step ${index + 1} ${step.name}`}
            onClick=${() => onInsert({ path, slot: index })} ...${drop}>
      <${IconSvg} edges=${{ left: { shape: "tab", object_type: type }, right: { shape: "flat" } }} kind="gap"
                  title="gap" subtitle=${type} />
    </button>`;
}

/** The row's jobs in the order they run, each with the row step it belongs to: [[job, step index], ...]. */
export function runOrder(dictionary, steps) {
  const expand = (name, index, seen) => {
    const application = dictionary.applications[name];
    if (!application || seen.includes(name)) return [[name, index]];
    return application.steps.flatMap((s) => expand(s.job, index, [...seen, name]));
  };
  return steps.flatMap((step, index) => expand(step.name, index, []));
}

/**
 * Which step of the row runs now: the status stream names the job, and the same job may come twice,
 * so each new job is looked for after the one before it. null while nothing of this row runs.
 */
function useRunningStep(dictionary, steps, job, active) {
  const [position, setPosition] = useState(-1);  // in runOrder
  useEffect(() => {
    if (!active || !job) { setPosition(-1); return; }
    const order = runOrder(dictionary, steps);
    setPosition((before) => {
      if (before >= 0 && order[before] && order[before][0] === job) return before;
      const after = order.findIndex(([name], i) => i > before && name === job);
      return after >= 0 ? after : order.findIndex(([name]) => name === job);
    });
  }, [job, active]);
  const order = runOrder(dictionary, steps);
  return active && position >= 0 && order[position] ? order[position][1] : null;
}

/**
 * Whether the step at `at` ([...row path, index]) runs now: the status's place is where the running
 * job is, as positions ([step, row, step, ...]: step 2, its fallback row 1, step 0 of it), so two
 * identical rows (two `then: [hold]`) are told apart; a step that uses an application runs while
 * any job inside it does.
 */
function runsAt(statusPlace, at) {
  return Boolean(statusPlace) && statusPlace.length >= at.length && at.every((value, i) => statusPlace[i] === value);
}

/** A step that decides: its icon and settings, then each of its rows of steps. */
function DecisionUnit({ dictionary, step, index, count, actions, path, statusPlace, keys }) {
  const spec = DECISIONS[step.kind];
  const where = ` of step ${index + 1} ${step.kind}`;
  // onInput, not onChange: a render between typing and leaving the field (the run's status arrives
  // several times a second) would put the model's old value back into the field and lose what was typed.
  const setting = (key, label, props = {}) => html`
    <label class="decision-setting">${label}
      <input aria-label=${`${label}${where}`} value=${step[key] === undefined || step[key] === null ? "" : step[key]} ...${props}
             onInput=${(e) => actions.setSetting(path, index, key, props.type === "number" ? Number(e.currentTarget.value)
                                                                                            : e.currentTarget.value)} />
    </label>`;
  return html`
    <div class=${"unit decision kind-" + step.kind} role="listitem" data-step=${index + 1} data-kind=${step.kind}>
      <div class="decision-head">
        <button class="icon step-icon" data-name=${step.kind}
                aria-label=${`step ${index + 1}: ${step.kind}, a step that decides: ${spec.doc}; Delete removes it, Alt+arrows move it`}
                onKeyDown=${keys}>
          <${IconSvg} edges=${iconOf(dictionary, step.kind).edges} kind="decision" title=${step.kind} subtitle="decides" />
        </button>
        ${step.kind === "if" || step.kind === "wait" ? setting("condition", "condition", { placeholder: "max(abs(q_m - q_d)) < 0.01", size: 26 }) : null}
        ${step.kind === "repeat" && step.until === undefined ? setting("times", "times", { type: "number", min: 1, size: 3 }) : null}
        ${step.kind === "repeat" && step.until !== undefined ? html`${setting("until", "until", { size: 22 })}${
          setting("max", "max", { type: "number", min: 1, size: 3 })}` : null}
        ${step.kind === "wait" ? setting("timeout", "timeout", { size: 5 }) : null}
        <span class="step-tools">
          <button aria-label=${`remove step ${index + 1} ${step.kind}`} onClick=${() => actions.remove(index, path)}>✕</button>
        </span>
      </div>
      ${spec.rows.map((label, which) => html`
        <div class="decision-row" key=${label}>
          <span class="decision-label">${label}</span>
          <${RowView} dictionary=${dictionary} steps=${step.rows[which]} actions=${actions} path=${[...path, index, which]}
                      statusPlace=${statusPlace} name=${`${label}${where}`} />
        </div>`)}
    </div>`;
}

/** A row of steps at `path` (the workspace's own, or one of a step that decides), with places between them. */
export function RowView({ dictionary, steps, actions, path, statusPlace, runningStep = null, name }) {
  const where = path.length ? ` in ${name}` : "";
  return html`
    <div class="nested-row" role="list" aria-label=${name} data-path=${path.join(".")}>
      <${Place} before=${0} count=${steps.length} onInsert=${actions.insert} onMove=${actions.move} path=${path} where=${where} />
      ${steps.map((step, index) => html`
        <${Unit} key=${step.id} dictionary=${dictionary} step=${step} index=${index} count=${steps.length}
                 running=${runningStep === index || (!step.kind && runsAt(statusPlace, [...path, index]))}
                 actions=${actions} path=${path} statusPlace=${statusPlace} />
        <${Place} key=${"place" + step.id} before=${index + 1} count=${steps.length} onInsert=${actions.insert}
                  onMove=${actions.move} path=${path} where=${where} />`)}
    </div>`;
}

/** One step of the row: its icon (focusable: Delete removes it, Alt+arrows move it), its slot, its tools. */
function Unit({ dictionary, step, index, count, running, actions, path = [], statusPlace = null }) {
  const keys = (e) => {
    if (e.key === "Delete" || e.key === "Backspace") { e.preventDefault(); actions.remove(index, path); }
    else if (e.altKey && e.key === "ArrowLeft" && index > 0) { e.preventDefault(); actions.move(index, index - 1, path); }
    else if (e.altKey && e.key === "ArrowRight" && index < count - 1) { e.preventDefault(); actions.move(index, index + 2, path); }
  };
  if (step.kind) {
    return html`<${DecisionUnit} dictionary=${dictionary} step=${step} index=${index} count=${count} actions=${actions}
                                 path=${path} statusPlace=${statusPlace} keys=${keys} />`;
  }
  const icon = iconOf(dictionary, step.name);
  if (!icon) {
    return html`<div class="unit unknown" role="listitem" data-step=${index + 1}>
      <span class="error">'${step.name}' is gone from the file</span>
      <button onClick=${() => actions.remove(index, path)} aria-label=${`remove step ${index + 1}`}>Remove</button></div>`;
  }
  const entry = icon.what === "application" ? dictionary.applications[step.name] : dictionary.jobs[step.name];
  const subtitle = icon.class === "action_requiring_object" ? `needs ${icon.object_type}`
                 : icon.class === "incomplete" ? "gaps inside" : "action";
  return html`
    <div class=${"unit" + (running ? " running" : "")} role="listitem" data-step=${index + 1} data-name=${step.name}
         aria-current=${running ? "step" : null}>
      <div class="unit-icons">
        <button class="icon step-icon" draggable="true" data-name=${step.name}
                aria-label=${`step ${index + 1}: ${iconLabel(step.name, entry, icon.what)}${running ? " (running)" : ""}; `
                             + "Delete removes it, Alt+arrows move it"}
                onDragStart=${(e) => { e.dataTransfer.setData(DRAG_STEP, JSON.stringify({ path, index })); e.dataTransfer.effectAllowed = "move"; }}
                onKeyDown=${keys}>
          <${IconSvg} edges=${icon.edges} kind=${icon.class} title=${step.name}
                      subtitle=${(icon.what === "application" ? "app · " : "") + subtitle} application=${icon.what === "application"} />
        </button>
        ${icon.class === "action_requiring_object" ? html`
          <${Slot} step=${step} index=${index} icon=${icon} onInsert=${actions.insert} path=${path}
                   onRemoveObject=${actions.removeObject} onEditObject=${actions.editObject} />` : null}
      </div>
      <div class="step-tools">
        <button aria-label=${`move step ${index + 1} left`} disabled=${index === 0} onClick=${() => actions.move(index, index - 1, path)}>◀</button>
        <button aria-label=${`remove step ${index + 1} ${step.name}`} onClick=${() => actions.remove(index, path)}>✕</button>
        <button aria-label=${`move step ${index + 1} right`} disabled=${index === count - 1} onClick=${() => actions.move(index, index + 2, path)}>▶</button>
      </div>
    </div>`;
}

/**
 * The workspace: the row, its message line, Save and Run. `steps` and `actions` (insert, remove, move,
 * removeObject, editObject, clear) are the User level's, and `name` the application's; `onSaved(reply)`
 * takes a save's new dictionary.
 */
export function Workspace({ dictionary, steps, actions, message, setMessage, status, onSaved, name, setName }) {
  const [replace, setReplace] = useState(false);
  const [busy, setBusy] = useState(false);
  const [runName, setRunName] = useState(null);
  const [over, setOver] = useState(false);
  const open = gaps(dictionary, steps);
  const unknown = steps.filter((s) => !iconOf(dictionary, s.name));
  const running = status && status.application ? status.application : null;

  const save = async (event) => {
    event.preventDefault();
    if (!steps.length) { setMessage({ text: "Not saved: the workspace is empty: drop jobs from the dictionary into it first", error: true }); return; }
    setBusy(true);
    try {
      const reply = await post("workspace/applications", { name, row: rowBody(steps), replace });
      onSaved(reply);
      setMessage({ text: reply.message + (reply.warnings.length ? ` (${reply.warnings.length} warning(s): ${reply.warnings[0]})` : ""), error: false });
    } catch (e) {
      setMessage({ text: `Not saved: ${e.message}`, error: true });
    } finally {
      setBusy(false);
    }
  };
  const run = async () => {
    let reason = "";
    if (!steps.length) reason = "the workspace is empty: drop jobs from the dictionary into it first";
    else if (unknown.length) reason = `'${unknown[0].name}' is no longer in the file: remove it`;
    else if (open.length) reason = gapsSentence(open);
    else if (!status) reason = "no run is attached: start one with pbo run FILE (the HMI attaches to it by itself)";
    else if (running) reason = `application '${running}' is running: wait until it ends`;
    if (reason) { setMessage({ text: `Run refused: ${reason}`, error: true }); return; }
    setBusy(true);
    try {
      const reply = await post("workspace/run", { name, row: rowBody(steps) });
      setRunName(name);
      setMessage({ text: reply.message, error: false });
    } catch (e) {
      setMessage({ text: `Run refused: ${e.message}`, error: true });
    } finally {
      setBusy(false);
    }
  };
  const readiness = !steps.length ? "Empty: drop jobs from the dictionary."
    : open.length ? `Not runnable: ${open.length} gap${open.length === 1 ? "" : "s"} to fill (it can be saved as an incomplete application).`
    : status ? "Complete: ready to run on the attached run." : "Complete: attach a run (pbo run FILE) to run it.";
  const mine = Boolean(running && running === (runName || name));  // the row it runs: started here, or named as it is
  const decides = steps.some((s) => s.kind);
  const runningStep = useRunningStep(dictionary, steps, status ? status.job : null, mine && !decides);
  const statusPlace = mine && decides && status.place && status.place.length ? status.place : null;  // where one that decides is

  return html`
    <div class="workspace">
      <div class=${"row" + (over ? " over" : "")} role="list" aria-label="application workspace" data-test="workspace-row"
           ...${dropProps((icon) => actions.insert({ path: [], before: steps.length }, icon),
                          (from) => { if (!from.path.length) actions.move(from.index, steps.length); }, setOver)}>
        <${Place} before=${0} count=${steps.length} onInsert=${actions.insert} onMove=${actions.move} />
        ${steps.map((step, index) => html`
          <${Unit} key=${step.id} dictionary=${dictionary} step=${step} index=${index} count=${steps.length}
                   running=${runningStep === index || (!step.kind && runsAt(statusPlace, [index]))}
                   actions=${actions} statusPlace=${statusPlace} />
          <${Place} key=${"place" + step.id} before=${index + 1} count=${steps.length} onInsert=${actions.insert} onMove=${actions.move} />`)}
      </div>
      <p class="readiness" data-test="run-readiness">${readiness}</p>
      ${message.text ? html`<p class=${message.error ? "error" : "note"} role=${message.error ? "alert" : "status"}
                              data-test="workspace-message">${message.text}</p>` : null}
      <p class="running-line" data-test="workspace-running" role="status">
        ${running ? html`Running application <strong>${running}</strong>: job <strong data-test="running-job">${status.job || "none"}</strong>${
                    status.path ? html` (<span data-test="running-path">${status.path}</span>)` : null}`
                  : status ? "No application is running." : "No run attached."}
      </p>
      <form class="workspace-actions" onSubmit=${save} aria-label="save or run the application">
        <label>Application name <input name="application" value=${name}
                                      onInput=${(e) => setName(e.currentTarget.value)} /></label>
        <label class="check"><input type="checkbox" checked=${replace} onChange=${(e) => setReplace(e.currentTarget.checked)} />
          replace an application of that name</label>
        <button type="submit" disabled=${busy}>Save application</button>
        <button type="button" class="run" data-test="run" disabled=${busy} onClick=${run}>Run</button>
        <button type="button" onClick=${actions.clear} disabled=${!steps.length}>Clear the row</button>
      </form>
    </div>`;
}
