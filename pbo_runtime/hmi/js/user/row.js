// The application workspace's row (Onika §4.4.2, Fig. 4) as plain data and the rules that change it.
// A row is a list of steps, left to right: {id, name, object}, `name` a job or an application of
// the dictionary, `object` the named object that fills it (null: none needed, or a gap). The
// interlock rule is the file's (edit/job_dictionary.py): flat against flat, a notch T against a
// tab T. Each change answers {steps, message} or {refused}: the reason, shown to the user as it is.
// The server checks the same row again before it saves or runs it.
//
// A step that decides (if, try, repeat, wait: docs/configuration.md#steps-that-decide) is
// {id, name: its kind, kind, condition, times, max, timeout, rows: [[steps], ...]}: an action with
// flat edges holding rows of steps of their own (then/else, try/fallback, the repeated steps). A
// row is found by its `path` from the workspace's row: [] for it, [step, row, step, row, ...] inside.

let nextId = 1;

/** The steps that decide: their rows' names, and the settings a new one starts with. */
export const DECISIONS = {
  if: { rows: ["then", "else"], settings: { condition: "" }, doc: "runs then: if its condition holds, else: if not" },
  try: { rows: ["try", "fallback"], settings: {}, doc: "runs fallback: if a step of try: fails; then goes on" },
  repeat: { rows: ["repeat"], settings: { times: 2 }, doc: "runs its steps a number of times" },
  wait: { rows: [], settings: { condition: "", timeout: "2 s" }, doc: "goes on once its condition holds; fails after its timeout" },
};
export const FLAT_EDGES = { left: { shape: "flat", object_type: null }, right: { shape: "flat", object_type: null } };

/** The names of a step's rows: a step that decides its kind's, a parallel step its arms (subsystems). */
export function rowNames(step) {
  return step.kind === "parallel" ? step.arms : DECISIONS[step.kind].rows;
}

/** The row at `path` of `steps`. */
export function rowAt(steps, path = []) {
  let row = steps;
  for (let i = 0; i < path.length; i += 2) row = row[path[i]].rows[path[i + 1]];
  return row;
}

/** `steps` with the row at `path` replaced by `row`. */
function withRow(steps, path, row) {
  if (!path.length) return row;
  const [index, which, ...rest] = path;
  return steps.map((s, i) => (i !== index ? s : { ...s, rows: s.rows.map((r, k) => (k === which ? withRow(r, rest, row) : r)) }));
}

/** A change `change(row)` ({steps, message} or {refused}) made to the row at `path`. */
function inRow(steps, path, change) {
  const result = change(rowAt(steps, path));
  return result.refused ? result : { steps: withRow(steps, path, result.steps), message: result.message };
}

/** Where a row is, for a message: "" for the workspace's row, "in the fallback of step 2 " inside. */
export function rowWords(steps, path = []) {
  if (!path.length) return "";
  let row = steps;
  const words = [];
  for (let i = 0; i < path.length; i += 2) {
    const step = row[path[i]];
    words.push(`${step.kind === "parallel" ? "arm " : ""}${rowNames(step)[path[i + 1]]} of step ${path[i] + 1} (${step.kind})`);
    row = step.rows[path[i + 1]];
  }
  return `in the ${words.reverse().join(" in the ")} `;
}

/** One setting of the step that decides at `index` of the row at `path`. */
export function setSetting(steps, path, index, key, value) {
  return inRow(steps, path, (row) => ({ steps: row.map((s, i) => (i === index ? { ...s, [key]: value } : s)), message: "" }));
}

const CLASS_WORDS = { action: "an action", action_requiring_object: "an action requiring an object",
                      incomplete: "an application with gaps of several object types" };

/** The icon called `name` in the dictionary: {name, what: "job"|"application"|"object", class, object_type, edges}. */
export function iconOf(dictionary, name) {
  if (DECISIONS[name] && !dictionary.jobs[name] && !dictionary.applications[name]) {
    return { name, what: "decision", class: "action", object_type: null, edges: FLAT_EDGES };
  }
  if (dictionary.jobs[name]) return { name, what: "job", ...pick(dictionary.jobs[name]) };
  if (dictionary.applications[name]) return { name, what: "application", ...pick(dictionary.applications[name]) };
  if (dictionary.objects[name]) {
    const obj = dictionary.objects[name];
    return { name, what: "object", class: "object", object_type: obj.type, edges: obj.edges };
  }
  return null;
}

function pick(entry) {
  return { class: entry.class, object_type: entry.object_type, edges: entry.edges };
}

/** Whether step `step` takes an object (its right edge is a notch). */
export function needsObject(dictionary, step) {
  const icon = iconOf(dictionary, step.name);
  return icon !== null && icon.class === "action_requiring_object";
}

/** The row's gaps: [{index, step, name, object_type}] (object_type null: gaps of several types inside an application). */
export function gaps(dictionary, steps, where = "") {
  const found = [];
  steps.forEach((step, index) => {
    if (step.kind) {  // a step that decides: the gaps of its rows are the application's
      step.rows.forEach((row, which) => found.push(
        ...gaps(dictionary, row, `${where}${index + 1} (${step.kind}, ${rowNames(step)[which]}): step `)));
      return;
    }
    const icon = iconOf(dictionary, step.name);
    if (!icon) return;
    if (icon.class === "action_requiring_object" && !step.object) found.push({ index, step: where + (index + 1), name: step.name, object_type: icon.object_type });
    if (icon.class === "incomplete") found.push({ index, step: where + (index + 1), name: step.name, object_type: null });
  });
  return found;
}

/** The gaps as the sentence Run shows when it refuses. */
export function gapsSentence(found) {
  const parts = found.map((g) => g.object_type ? `step ${g.step} '${g.name}' needs an object of type ${g.object_type}`
                                               : `step ${g.step} '${g.name}' has gaps of several object types inside it`);
  return `the application has ${found.length} gap${found.length === 1 ? "" : "s"}: ${parts.join("; ")}; drop an object of that type on each gap`;
}

function describeStep(icon) {
  return icon.class === "action_requiring_object" ? `'${icon.name}', which needs an object of type ${icon.object_type}`
                                                  : `'${icon.name}', ${CLASS_WORDS[icon.class]} (its right edge is flat)`;
}

/** An object dropped into the slot of step `index` (a gap, or an object there already): the row, or why not. */
function fillSlot(dictionary, steps, index, object) {
  const step = steps[index];
  const icon = iconOf(dictionary, step.name);
  if (icon.class !== "action_requiring_object") {
    return { refused: `object '${object.name}' (type ${object.object_type}) does not interlock with ${describeStep(icon)}` };
  }
  if (icon.object_type !== object.object_type) {
    return { refused: `object '${object.name}' (type ${object.object_type}) does not interlock with ${describeStep(icon)}` };
  }
  const changed = steps.map((s, i) => (i === index ? { ...s, object: object.name } : s));
  const message = step.object ? `'${object.name}' replaces '${step.object}' as the object of step ${index + 1} '${step.name}'`
                              : `'${object.name}' fills the gap of step ${index + 1} '${step.name}'`;
  return { steps: changed, message };
}

/**
 * Insert the dictionary's icon `name` into the row. `where`: {before: i} (between steps; i = steps.length
 * appends) or {slot: i} (step i's gap or object). Objects only ever fill a slot: dropped between steps,
 * an object meets the right edge of the step on its left.
 */
export function insert(dictionary, steps, name, where) {
  const path = where.path || [];
  const result = inRow(steps, path, (row) => insertInRow(dictionary, row, name, where));
  if (result.message && path.length) result.message = result.message.replace(/ as step (\d+)/, ` as step $1 ${rowWords(steps, path)}`.trimEnd());
  return result;
}

function insertInRow(dictionary, steps, name, where) {
  const icon = iconOf(dictionary, name);
  if (!icon) return { refused: `'${name}' is no icon of the dictionary (reload the page: the file changed?)` };
  if (icon.what === "object") {
    const index = where.slot !== undefined ? where.slot : where.before - 1;
    if (index < 0) {
      return { refused: `object '${name}' (type ${icon.object_type}) does not interlock with the start of the application: `
                        + "an object fills the gap of a step that needs one" };
    }
    const step = steps[index];
    if (where.slot === undefined && step.object) {
      return { refused: `step ${index + 1} '${step.name}' has its object '${step.object}' already: drop '${name}' on it to replace it` };
    }
    return fillSlot(dictionary, steps, index, icon);
  }
  if (where.slot !== undefined) {
    const needed = iconOf(dictionary, steps[where.slot].name);
    return { refused: `the slot of step ${where.slot + 1} takes an object of type ${needed.object_type}; '${name}' is `
                      + `${CLASS_WORDS[icon.class]}, not an object: drop it between steps` };
  }
  const at = Math.max(0, Math.min(where.before, steps.length));
  const made = icon.what === "decision"
    ? { id: nextId++, name, kind: name, object: null, ...DECISIONS[name].settings, rows: DECISIONS[name].rows.map(() => []) }
    : { id: nextId++, name, object: null };
  if (where.subsystem) made.subsystem = where.subsystem;  // an arm's step: the subsystem whose dictionary it came from
  const changed = [...steps.slice(0, at), made, ...steps.slice(at)];
  let message = `'${name}' inserted as step ${at + 1}`;
  if (icon.class === "action_requiring_object") {
    message += `: it needs an object of type ${icon.object_type} and its right neighbour is no such object, so a gap opened; `
               + `drop an object of that type on the gap`;
  } else if (icon.what === "decision") {
    message += DECISIONS[name].rows.length ? `: drop steps into its rows (${DECISIONS[name].rows.join(", ")})` : "";
  } else if (icon.class === "incomplete") {
    message += `: it has gaps of several object types inside, to fill in its own definition before it can run`;
  }
  return { steps: changed, message };
}

/** The row at `path` without step `index` (its object, or its rows, go with it). */
export function remove(steps, path, index) {
  return inRow(steps, path, (row) => ({ steps: row.filter((_, i) => i !== index),
                                         message: `step ${index + 1} '${row[index].name}' ${rowWords(steps, path)}removed` }));
}

/** The row at `path` with step `index`'s object taken out: its gap opens again. */
export function removeObject(steps, path, index) {
  return inRow(steps, path, (row) => ({
    steps: row.map((s, i) => (i === index ? { ...s, object: null } : s)),
    message: `'${row[index].object}' taken out of step ${index + 1} '${row[index].name}' ${rowWords(steps, path)}: its gap is open again`
      .replace(" :", ":") }));
}

/** The row at `path` with step `from` (and its object) moved to stand before step `before` of the row as it was. */
export function move(steps, path, from, before) {
  return inRow(steps, path, (row) => {
    if (before === from || before === from + 1) return { steps: row, message: "" };
    const step = row[from];
    const rest = row.filter((_, i) => i !== from);
    const at = before > from ? before - 1 : before;
    return { steps: [...rest.slice(0, at), step, ...rest.slice(at)], message: `'${step.name}' moved to step ${at + 1}` };
  });
}

/**
 * Steps as the dictionary writes an application's (`{job, object, value, decision}`) as a row; each step
 * written out as values is pushed to `written`; `subsystem`, when given, marks whose dictionary they are of.
 */
export function entriesToSteps(entries, written = [], subsystem = undefined) {
  return entries.map((s) => {
    const mark = subsystem ? { subsystem } : {};
    if (!s.decision) {
      if (s.object === null && s.value !== null && s.value !== undefined) written.push(s);
      return { id: nextId++, name: s.job, object: s.object, ...mark };
    }
    const d = s.decision;
    const settings = d.kind === "repeat"
      ? (d.condition ? { until: d.condition, max: d.max } : { times: d.times })
      : { condition: d.condition, ...(d.kind === "wait" && d.timeout !== null ? { timeout: `${d.timeout} s` } : {}) };
    const rows = DECISIONS[d.kind].rows.map((_, k) => entriesToSteps(d.rows[k] || [], written, subsystem));
    return { id: nextId++, name: d.kind, kind: d.kind, object: null, ...settings, rows, ...mark };
  });
}

/** A new step with its own id (a parallel step, made by the application file's workspace). */
export function newStep(fields) {
  return { id: nextId++, object: null, ...fields };
}

/** Application `name` of the dictionary as a row, to change and save again; refused if a step's object is written out as values. */
export function fromApplication(dictionary, name) {
  const written = [];
  const steps = entriesToSteps(dictionary.applications[name].steps, written);
  if (written.length) {
    return { refused: `step ${written[0].step} of '${name}' gives '${written[0].job}' its object as values written out in the file; `
                      + "the workspace takes named objects: name the value under objects: in the file, or build the row anew" };
  }
  return { steps, message: `application '${name}' opened in the workspace: Save with replace ticked writes it back` };
}

/** The row as the API takes it: [{name, object}], a step that decides as {kind, its settings, rows}. */
export function rowBody(steps) {
  return steps.map((s) => (s.kind
    ? { kind: s.kind, condition: s.condition, times: s.times, max: s.max, until: s.until, timeout: s.timeout, rows: s.rows.map(rowBody),
        subsystem: s.subsystem }
    : { name: s.name, object: s.object, subsystem: s.subsystem }));
}
