// The application workspace's row (Onika §4.4.2, Fig. 4) as plain data and the rules that change it.
// A row is a list of steps, left to right: {id, name, object}, `name` a job or an application of
// the dictionary, `object` the named object that fills it (null: none needed, or a gap). The
// interlock rule is the file's (config/job_dictionary.py): flat against flat, a notch T against a
// tab T. Each change answers {steps, message} or {refused}: the reason, shown to the user as it is.
// The server checks the same row again before it saves or runs it.

let nextId = 1;

const CLASS_WORDS = { action: "an action", action_requiring_object: "an action requiring an object",
                      incomplete: "an application with gaps of several object types" };

/** The icon called `name` in the dictionary: {name, what: "job"|"application"|"object", class, object_type, edges}. */
export function iconOf(dictionary, name) {
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
export function gaps(dictionary, steps) {
  const found = [];
  steps.forEach((step, index) => {
    const icon = iconOf(dictionary, step.name);
    if (!icon) return;
    if (icon.class === "action_requiring_object" && !step.object) found.push({ index, step: index + 1, name: step.name, object_type: icon.object_type });
    if (icon.class === "incomplete") found.push({ index, step: index + 1, name: step.name, object_type: null });
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
  const changed = [...steps.slice(0, at), { id: nextId++, name, object: null }, ...steps.slice(at)];
  let message = `'${name}' inserted as step ${at + 1}`;
  if (icon.class === "action_requiring_object") {
    message += `: it needs an object of type ${icon.object_type} and its right neighbour is no such object, so a gap opened; `
               + `drop an object of that type on the gap`;
  } else if (icon.class === "incomplete") {
    message += `: it has gaps of several object types inside, to fill in its own definition before it can run`;
  }
  return { steps: changed, message };
}

/** The row without step `index` (its object goes with it). */
export function remove(steps, index) {
  const step = steps[index];
  return { steps: steps.filter((_, i) => i !== index), message: `step ${index + 1} '${step.name}' removed` };
}

/** The row with step `index`'s object taken out: its gap opens again. */
export function removeObject(steps, index) {
  const step = steps[index];
  return { steps: steps.map((s, i) => (i === index ? { ...s, object: null } : s)),
           message: `'${step.object}' taken out of step ${index + 1} '${step.name}': its gap is open again` };
}

/** The row with step `from` (and its object) moved to stand before step `before` of the row as it was. */
export function move(steps, from, before) {
  if (before === from || before === from + 1) return { steps, message: "" };
  const step = steps[from];
  const rest = steps.filter((_, i) => i !== from);
  const at = before > from ? before - 1 : before;
  return { steps: [...rest.slice(0, at), step, ...rest.slice(at)], message: `'${step.name}' moved to step ${at + 1}` };
}

/** Application `name` of the dictionary as a row, to change and save again; refused if a step's object is written out as values. */
export function fromApplication(dictionary, name) {
  const application = dictionary.applications[name];
  const deciding = application.steps.find((s) => s.decision);
  if (deciding) {
    return { refused: `step ${deciding.step} of '${name}' is a ${deciding.decision.kind} step: the workspace builds sequences `
                      + "of jobs and applications; edit the steps that decide in the file" };
  }
  const written = application.steps.find((s) => s.object === null && s.value !== null && s.value !== undefined);
  if (written) {
    return { refused: `step ${written.step} of '${name}' gives '${written.job}' its object as values written out in the file; `
                      + "the workspace takes named objects: name the value under objects: in the file, or build the row anew" };
  }
  const steps = application.steps.map((s) => ({ id: nextId++, name: s.job, object: s.object }));
  return { steps, message: `application '${name}' opened in the workspace: Save with replace ticked writes it back` };
}

/** The row as the API takes it: [{name, object}]. */
export function rowBody(steps) {
  return steps.map((s) => ({ name: s.name, object: s.object }));
}
