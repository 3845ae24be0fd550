// The engineer's side panel: the modifiers of the selected lexicon block (defaults for the next drop)
// or of the selected task (with its name, RTPU, period; on/off, delete, replace), the checker's
// verdict, and "Save as job". Every form works from the keyboard: labels, focus order, Enter submits.
import { html, useState, useEffect } from "../html.js";
import { modifiers, payload, yamlOf } from "./model.js";

function ModifierInputs({ module, values, onChange, prefix }) {
  return modifiers(module).map((p) => html`
    <label class="field" key=${p.name}>
      <span>${p.name} <small>${p.type}${p.required ? ", required" : ""}</small></span>
      <input name=${`${prefix}-${p.name}`} value=${values[p.name] || ""} placeholder=${p.required ? "required" : yamlOf(p.default)}
             title=${p.doc || p.type} aria-label=${`modifier ${p.name}`} onInput=${(e) => onChange(p.name, e.currentTarget.value)} />
    </label>`);
}

/** The modifiers of a lexicon block: the values a task of it gets when next dropped (YAML text, as in the file). */
export function LexiconModifiers({ module, defaults, onChange }) {
  const values = (defaults && defaults.params) || {};
  return html`
    <form class="panel-form" aria-label=${`modifiers of ${module.name} for the next drop`} onSubmit=${(e) => e.preventDefault()}>
      <h3>${module.name}: modifiers for the next drop</h3>
      <p class="muted">${module.summary}</p>
      ${modifiers(module).length ? html`<${ModifierInputs} module=${module} values=${values} prefix="lex"
          onChange=${(key, value) => onChange(module.name, { ...values, [key]: value })} />`
        : html`<p class="muted">No modifiers.</p>`}
    </form>`;
}

/** The selected task: its fields, modifiers and port links, edited as a whole (Apply, or Enter). */
export function TaskPanel({ task, module, rtpus, live, state, modules, onApply, onToggle, onDelete, onReplace }) {
  const [draft, setDraft] = useState(task);
  const [replacement, setReplacement] = useState("");
  useEffect(() => setDraft(task), [JSON.stringify(payload(task))]);  // a move keeps what is being typed
  const set = (section, key, value) => setDraft({ ...draft, [section]: { ...draft[section], [key]: value } });
  const ports = module ? module.ports : [];
  const others = Object.keys(draft.fields).filter((k) => k !== "rtpu" && k !== "period");
  const on = live ? state === "ON" : task.on;
  return html`
    <section class="task-panel" aria-label=${`task ${task.name}`} data-test="task-panel">
      <h3>Task ${task.name} <small>(${task.module})</small></h3>
      <div class="task-actions">
        <button type="button" aria-pressed=${on} data-test="toggle" onClick=${() => onToggle(task)}>
          ${on ? "Turn off" : "Turn on"}</button>
        <button type="button" class="danger" data-test="delete" onClick=${() => onDelete(task)}>Delete</button>
      </div>
      <form class="replace" onSubmit=${(e) => { e.preventDefault(); if (replacement) onReplace(task, replacement); }}>
        <label class="field"><span>Replace by</span>
          <select value=${replacement} onChange=${(e) => setReplacement(e.currentTarget.value)} aria-label="replace by module">
            <option value="">a module…</option>
            ${modules.filter((m) => m.name !== task.module).map((m) => html`
              <option value=${m.name}>${m.name}</option>`)}
          </select></label>
        <button type="submit" disabled=${!replacement}>Replace</button>
      </form>
      <form class="panel-form" aria-label=${`modifiers of task ${task.name}`} onSubmit=${(e) => { e.preventDefault(); onApply(task, draft); }}>
        <label class="field"><span>Name</span>
          <input name="name" value=${draft.name} disabled=${live} onInput=${(e) => setDraft({ ...draft, name: e.currentTarget.value })} /></label>
        <label class="field"><span>RTPU</span>
          <select name="rtpu" value=${draft.fields.rtpu || ""} disabled=${live} onChange=${(e) => set("fields", "rtpu", e.currentTarget.value)}>
            ${rtpus.map((r) => html`<option value=${r}>${r}</option>`)}
          </select></label>
        <label class="field"><span>Period</span>
          <input name="period" value=${draft.fields.period || ""} placeholder="1 ms" disabled=${live}
                 onInput=${(e) => set("fields", "period", e.currentTarget.value)} /></label>
        ${others.map((key) => html`
          <label class="field"><span>${key}</span>
            <input name=${key} value=${draft.fields[key]} disabled=${live} onInput=${(e) => set("fields", key, e.currentTarget.value)} /></label>`)}
        <fieldset><legend>Modifiers</legend>
          <${ModifierInputs} module=${module} values=${draft.params} prefix="task" onChange=${(key, value) => set("params", key, value)} />
        </fieldset>
        ${ports.length ? html`
          <fieldset><legend>Ports (the variable each joins)</legend>
            ${ports.map((p) => html`
              <label class="field"><span>${p.name} <small>${p.kind}</small></span>
                <input name=${`port-${p.name}`} value=${draft.ports[p.name] || ""} placeholder=${p.variable} disabled=${live}
                       aria-label=${`port ${p.name}`} onInput=${(e) => set("ports", p.name, e.currentTarget.value)} /></label>`)}
          </fieldset>` : ""}
        <button type="submit" data-test="apply">${live ? "Set live" : "Apply"}</button>
      </form>
    </section>`;
}

/** The checker's verdict on the canvas: each diagnostic with its E-code, where, message and hint, and its notes: the related places. */
export function CheckerList({ checked, pending }) {
  if (!checked) return html`<p class="muted" data-test="checker">Checking…</p>`;
  const shown = checked.diagnostics;
  const errors = shown.filter((d) => d.severity === "error").length;
  return html`
    <section class="checker" aria-label="checker" aria-live="polite">
      <h3>Checker</h3>
      <p data-test="checker" class=${errors ? "error" : "ok"}>
        ${errors ? `${errors} error${errors > 1 ? "s" : ""}` : "No error"}${pending ? " (checking…)" : ""}</p>
      <ul class="diagnostics">
        ${shown.map((d) => html`
          <li class=${d.severity} data-code=${d.code}>
            <strong>${d.code}</strong> ${d.task ? html`<code>${d.task}${d.port ? "." + d.port : d.key ? " " + d.key : d.section ? " " + d.section : ""}</code>`
              : html`<code>${(d.file || "").split("/").pop()}:${d.line}</code>`}
            ${" "}${d.message}${d.hint ? html`<br /><small>${d.hint}</small>` : ""}
            ${(d.notes || []).length ? html`<ul class="notes">${d.notes.map((n) => html`
              <li><small>note: <code>${n.task || `${(n.file || "").split("/").pop()}:${n.line}`}</code> ${n.message}</small></li>`)}</ul>` : ""}</li>`)}
      </ul>
    </section>`;
}

/** Save as job: its name, and whether its object is inferred by the job model or none. */
export function SaveJob({ disabled, onSave }) {
  const [name, setName] = useState("");
  const [object, setObject] = useState("inferred");
  return html`
    <form class="save-job" aria-label="save as job" onSubmit=${(e) => { e.preventDefault(); onSave(name.trim(), object); }}>
      <h3>Save as job</h3>
      <label class="field"><span>Job name</span>
        <input name="job" value=${name} required pattern="[A-Za-z_][A-Za-z0-9_]*" onInput=${(e) => setName(e.currentTarget.value)} /></label>
      <label class="field"><span>Object</span>
        <select name="object" value=${object} onChange=${(e) => setObject(e.currentTarget.value)}>
          <option value="inferred">as the job model infers it (action, or action requiring an object)</option>
          <option value="none">none: an action that leaves its goal as it is</option>
        </select></label>
      <button type="submit" disabled=${disabled || !name.trim()}>Save as job</button>
    </form>`;
}
