// Engineer level (Onika §4.3): the task lexicon, the job canvas and the side panel (modifiers, the
// checker's verdict, Save as job). The canvas is checked by the project's checker on every change
// (POST /api/canvas/check: the canvas composed onto the file's base); the lexicon is dimmed from the
// placement query it answers with. Attached to a run, a dropped task is spawned live and on/off,
// delete, replace and modifier changes go to the run as the operator's verbs (spawn, on, off, kill,
// replace, set); each refusal is shown with the API's own words.
import { html, useState, useEffect, useRef, useMemo } from "./html.js";
import { announceFileChanged, get, onFileChanged, post, verb } from "./api.js";
import { Lexicon } from "./engineer/lexicon.js";
import { JobCanvas } from "./engineer/canvas.js";
import { LexiconModifiers, TaskPanel, CheckerList, SaveJob } from "./engineer/panel.js";
import { BLOCK_WIDTH, blockHeight, links, newTask, nextFreeSpot, payload, pinsOf, taskName } from "./engineer/model.js";

const CHECK_DELAY = 120;  // ms: a burst of edits (typing a value) is checked once it pauses

/** A refusal as the user reads it: the API's one-line error (a checker's refusal lists the rest below). */
function Notice({ notice, onClose }) {
  if (!notice) return null;
  const [first, ...rest] = notice.text.split("\n");
  return html`
    <div class=${"notice " + (notice.error ? "error" : "ok")} role=${notice.error ? "alert" : "status"} data-test="notice">
      <span>${first}</span>
      ${rest.length ? html`<details><summary>details</summary><pre>${rest.join("\n")}</pre></details>` : ""}
      <button type="button" class="close" aria-label="dismiss" onClick=${onClose}>×</button>
    </div>`;
}

function layout(names, entries) {
  return names.map((name, i) => ({ ...entries[name], x: 20 + (i % 3) * (BLOCK_WIDTH + 50), y: 20 + Math.floor(i / 3) * 210 }));
}

/** The options of `pbo spawn`/`pbo replace` for a canvas task (values stay YAML text). */
function spawnArguments(task) {
  const args = { module: task.module, rtpu: task.fields.rtpu, period: task.fields.period };
  const assigned = (values) => Object.entries(values).filter(([, v]) => String(v).trim()).map(([k, v]) => `${k}=${v}`);
  if (assigned(task.params).length) args.params = assigned(task.params);
  if (assigned(task.ports).length) args.ports = assigned(task.ports);
  const resources = String(task.fields.resources || "").replace(/[\[\]]/g, "").split(",").map((d) => d.trim()).filter(Boolean);
  if (resources.length) args.resources = resources;  // the devices it opens: a robot interface can be spawned too
  return args;
}

export function Engineer({ status }) {
  const [modules, setModules] = useState(null);
  const [file, setFile] = useState(null);
  const [tasks, setTasks] = useState([]);
  const [loadedFrom, setLoadedFrom] = useState(null);
  const [touched, setTouched] = useState(false);
  const [defaults, setDefaults] = useState({});
  const [selected, setSelected] = useState(null);  // {kind: "module" | "task", name}
  const [checked, setChecked] = useState(null);
  const [pending, setPending] = useState(false);
  const [notice, setNotice] = useState(null);
  const [busy, setBusy] = useState(false);
  const sequence = useRef(0);
  const pane = useRef(null);
  const live = Boolean(status);
  const say = (text, error = false) => setNotice({ text, error });

  const loadFile = () => get("canvas").then(setFile, (e) => say(e.message, true));
  useEffect(() => {
    get("lexicon").then((reply) => setModules(reply.modules), (e) => say(e.message, true));
    loadFile();
    return onFileChanged(loadFile);  // an application or object saved on the user level
  }, []);

  const load = (name) => {
    setLoadedFrom(name || null);
    setTasks(name ? layout(file.configurations[name], file.tasks) : []);
    setSelected(null);
  };
  // Until the user edits it, the canvas shows the running configuration, or else the file's first.
  const running = status && status.configuration;
  useEffect(() => {
    if (!file || touched) return;
    const names = Object.keys(file.configurations);
    const target = running && names.includes(running) ? running : names[0] || null;
    if (target !== loadedFrom) load(target);
  }, [file, running, touched]);

  // The checker, on every change of what the canvas holds (not of where its blocks sit).
  const sent = JSON.stringify({ configuration: loadedFrom, tasks: tasks.map(payload) });
  useEffect(() => {
    if (!file) return undefined;
    const mine = ++sequence.current;
    setPending(true);
    const timer = setTimeout(() => {
      post("canvas/check", JSON.parse(sent)).then(
        (reply) => { if (mine === sequence.current) { setChecked({ ...reply, key: sent }); setPending(false); } },
        (e) => { if (mine === sequence.current) { setPending(false); say(e.message, true); } });
    }, CHECK_DELAY);
    return () => clearTimeout(timer);
  }, [sent, file]);

  const lexicon = modules || [];
  const pins = useMemo(() => Object.fromEntries(tasks.map((t) => [t.name, pinsOf(t, checked, lexicon)])), [tasks, checked, modules]);
  const drawn = useMemo(() => links(tasks, pins), [tasks, pins]);
  const fresh = Boolean(checked && checked.key === sent);  // the verdicts are of the canvas as it is now
  const verdicts = Object.fromEntries(((checked && checked.placement && checked.placement.modules) || []).map((v) => [v.module, v]));
  const diagnostics = {};
  for (const d of (checked && checked.diagnostics) || []) if (d.task) (diagnostics[d.task] = diagnostics[d.task] || []).push(d);
  const states = Object.fromEntries(((status && status.tasks) || []).map((t) => [t.task, t.state]));
  const taken = () => new Set([...tasks.map((t) => t.name), ...Object.keys((file && file.tasks) || {}), ...Object.keys(states)]);
  const edit = (next) => { setTasks(next); setTouched(true); };

  const act = async (what, call) => {
    setBusy(true);
    try {
      const reply = await call();
      if (reply && reply.message) say(reply.message);
      return reply || true;
    } catch (e) {
      say(`${what}: ${e.message}`, true);
      return null;
    } finally {
      setBusy(false);
    }
  };

  const place = async (name, x, y) => {
    const module = lexicon.find((m) => m.name === name);
    if (!module || !file) return;
    const verdict = verdicts[name];
    if (fresh && verdict && !verdict.legal) { say(`cannot place ${name}: ${verdict.code}: ${verdict.reason}`, true); return; }
    const task = newTask(module, taskName(name, taken()), { rtpus: file.rtpus, devices: file.devices, defaults: defaults[name] || {},
                                                            x: Math.max(0, x - BLOCK_WIDTH / 2), y: Math.max(0, y - 20) });
    if (live && !(await act(`spawn ${task.name}`, () => verb("spawn", { task: task.name, ...spawnArguments(task) })))) return;
    edit([...tasks, task]);
    setSelected({ kind: "task", name: task.name });
  };
  const placeNext = (name) => {
    const width = pane.current ? pane.current.clientWidth : 700;
    const spot = nextFreeSpot(tasks, width, (t) => blockHeight(pins[t.name] || []));
    place(name, spot.x + BLOCK_WIDTH / 2, spot.y + 20);
  };
  const move = (name, x, y) => setTasks((now) => now.map((t) => (t.name === name ? { ...t, x: Math.round(x), y: Math.round(y) } : t)));
  const toggle = async (task) => {
    if (live && states[task.name]) {
      await act(`${states[task.name] === "ON" ? "off" : "on"} ${task.name}`, () => verb(states[task.name] === "ON" ? "off" : "on", { task: task.name }));
      return;
    }
    edit(tasks.map((t) => (t.name === task.name ? { ...t, on: !t.on } : t)));
  };
  const remove = async (task) => {
    if (live && states[task.name] && !(await act(`kill ${task.name}`, () => verb("kill", { task: task.name })))) return;
    edit(tasks.filter((t) => t.name !== task.name));
    setSelected(null);
  };
  const replace = async (task, moduleName) => {
    const module = lexicon.find((m) => m.name === moduleName);
    const names = taken();
    names.delete(task.name);
    const fresh = newTask(module, taskName(moduleName, names), { rtpus: file.rtpus, devices: file.devices,
                                                               defaults: defaults[moduleName] || {}, x: task.x, y: task.y });
    fresh.fields = { ...fresh.fields, rtpu: task.fields.rtpu || fresh.fields.rtpu, period: task.fields.period || fresh.fields.period };
    if (live && states[task.name] &&
        !(await act(`replace ${task.name}`, () => verb("replace", { task: task.name, new: fresh.name, ...spawnArguments(fresh) })))) return;
    edit(tasks.map((t) => (t.name === task.name ? fresh : t)));
    setSelected({ kind: "task", name: fresh.name });
  };
  const apply = async (task, draft) => {
    if (live && states[task.name]) {
      const changed = Object.entries(draft.params).filter(([k, v]) => (task.params[k] || "") !== v && v.trim());
      for (const [param, value] of changed) {
        if (!(await act(`set ${task.name} ${param}`, () => verb("set", { task: task.name, param, values: [value] })))) return;
      }
      edit(tasks.map((t) => (t.name === task.name ? { ...t, params: draft.params } : t)));
      return;
    }
    const name = draft.name.trim();
    if (name !== task.name && tasks.some((t) => t.name === name)) { say(`a task named '${name}' is on the canvas already: choose another name`, true); return; }
    edit(tasks.map((t) => (t.name === task.name ? { ...draft, name, x: t.x, y: t.y } : t)));
    setSelected({ kind: "task", name });
    setNotice(null);
  };
  const saveJob = async (name, object) => {
    const reply = await act(`save job ${name}`, () => post("canvas/job", { name, object, configuration: loadedFrom, tasks: tasks.map(payload) }));
    if (reply && reply.configuration) { setLoadedFrom(reply.configuration); setTouched(true); announceFileChanged(); }
  };
  const keyOnBlock = (event, task) => {
    const step = event.shiftKey ? 50 : 10;
    const arrows = { ArrowLeft: [-step, 0], ArrowRight: [step, 0], ArrowUp: [0, -step], ArrowDown: [0, step] };
    if (arrows[event.key]) { event.preventDefault(); move(task.name, Math.max(0, task.x + arrows[event.key][0]), Math.max(0, task.y + arrows[event.key][1])); }
    else if (event.key === "Delete") { event.preventDefault(); remove(task); }
  };

  const chosenTask = selected && selected.kind === "task" && tasks.find((t) => t.name === selected.name);
  const chosenModule = selected && selected.kind === "module" && lexicon.find((m) => m.name === selected.name);
  const configurations = file ? Object.keys(file.configurations) : [];
  return html`
    <div class="engineer-level">
      <aside class="lexicon-pane"><h2>Task lexicon</h2>
        <${Lexicon} modules=${modules} verdicts=${verdicts} busy=${!fresh} note=${checked && checked.placement && checked.placement.error}
                    selected=${selected && selected.kind === "module" ? selected.name : null} defaults=${defaults}
                    onSelect=${(name) => setSelected({ kind: "module", name })} onPlace=${placeNext} />
      </aside>
      <div class="canvas-pane" ref=${pane}>
        <div class="canvas-bar">
          <h2>Job canvas</h2>
          <label>Configuration
            <select data-test="configuration-choice" value=${loadedFrom || ""} disabled=${busy}
                    onChange=${(e) => { setTouched(true); load(e.currentTarget.value); }}>
              ${configurations.map((c) => html`<option value=${c}>${c}</option>`)}
              <option value="">new (empty canvas)</option>
            </select></label>
          ${live ? html`<span class="live-flag" data-test="live">live: drops are spawned in ${status.subsystem}</span>` : ""}
          ${file ? html`<span class="muted file-name" title=${file.file}>${file.file.split("/").pop()}</span>` : ""}
        </div>
        <${Notice} notice=${notice} onClose=${() => setNotice(null)} />
        <${JobCanvas} tasks=${tasks} pins=${pins} drawn=${drawn} jobWritten=${new Set((checked && checked.job_written) || [])}
                      diagnostics=${diagnostics} states=${states} selected=${chosenTask ? chosenTask.name : null}
                      onDrop=${place} onMove=${move} onKey=${keyOnBlock}
                      onSelect=${(name) => setSelected({ kind: "task", name })} />
      </div>
      <aside class="side-pane">
        ${chosenTask ? html`<${TaskPanel} task=${chosenTask} module=${lexicon.find((m) => m.name === chosenTask.module)}
                                          rtpus=${(file && file.rtpus) || []} live=${live && Boolean(states[chosenTask.name])}
                                          state=${states[chosenTask.name]} modules=${lexicon}
                                          onApply=${apply} onToggle=${toggle} onDelete=${remove} onReplace=${replace} />`
          : chosenModule ? html`<${LexiconModifiers} module=${chosenModule} defaults=${defaults[chosenModule.name]}
                                                     onChange=${(name, params) => setDefaults({ ...defaults, [name]: { params } })} />`
          : html`<p class="muted">Select a lexicon block to set its modifiers for the next drop, or a task on the canvas to edit it.</p>`}
        <${CheckerList} checked=${checked} pending=${pending} />
        <${SaveJob} disabled=${busy || !file} onSave=${saveJob} />
      </aside>
    </div>`;
}
