// The job canvas's model, plain functions: task names, a task as the API takes it, pins, the links
// drawn between pins of one variable, and where blocks sit. No DOM here.

export const BLOCK_WIDTH = 190;
const HEADER = 40;
const PIN_STEP = 18;
const GAP = 40;

/** The block's height: its header and one row per pin of its longer side. */
export function blockHeight(pins) {
  const inputs = pins.filter((p) => p.kind.startsWith("in")).length;
  const outputs = pins.length - inputs;
  return HEADER + Math.max(1, inputs, outputs) * PIN_STEP + 8;
}

/** Where each pin sits on its block (inputs left, outputs right), relative to the block's corner. */
export function pinPlaces(pins) {
  const places = {};
  let left = 0, right = 0;
  for (const pin of pins) {
    const input = pin.kind.startsWith("in");
    const row = input ? left++ : right++;
    places[pin.port] = { x: input ? 0 : BLOCK_WIDTH, y: HEADER + row * PIN_STEP + PIN_STEP / 2, input };
  }
  return places;
}

export const isConst = (kind) => kind.endsWith("const");

/** A free name for a task of `module`: the module's own name, else with _2, _3, ... */
export function taskName(module, taken) {
  if (!taken.has(module)) return module;
  for (let n = 2; ; n++) if (!taken.has(`${module}_${n}`)) return `${module}_${n}`;
}

/** A new task of `module` from the lexicon: its defaults for the next drop, on the first RTPU. */
export function newTask(module, name, { rtpus, devices, defaults, x, y }) {
  const fields = { rtpu: rtpus[0] || "rtpu0", period: "1 ms" };  // the demo's rate: a loop sampled slower may be refused as unstable
  const device = (module.params || []).find((p) => p.name === "device");
  const opened = (defaults.params && defaults.params.device) || (device && device.default);
  if (device && opened && devices.includes(opened)) fields.resources = `[${opened}]`;
  return { name, module: module.name, fields, params: { ...(defaults.params || {}) }, ports: {}, on: true,
           x: Math.round(x), y: Math.round(y) };
}

/** The task as POST /api/canvas/check takes it (no position). */
export function payload(task) {
  const { name, module, fields, params, ports, on } = task;
  const given = (values) => Object.fromEntries(Object.entries(values).filter(([, v]) => String(v).trim() !== ""));
  return { name, module, fields: given(fields), params: given(params), ports: given(ports), on };
}

/** A task's pins: the checker's (its bindings), or its module's declared ports as linked. */
export function pinsOf(task, checked, lexicon) {
  if (checked && checked.pins && checked.pins[task.name]) return checked.pins[task.name];
  const module = lexicon.find((m) => m.name === task.module);
  return (module ? module.ports : []).map((p) => ({ port: p.name, kind: p.kind, variable: (task.ports[p.name] || "").trim() || p.variable,
                                                    dtype: p.dtype, shape: p.shape }));
}

/** The links drawn: each writer's pin to each reader's pin of the same variable, among tasks that are on. */
export function links(tasks, pinsByTask) {
  const writers = {}, readers = {};
  for (const task of tasks.filter((t) => t.on)) {
    for (const pin of pinsByTask[task.name] || []) {
      const side = pin.kind.startsWith("in") ? readers : writers;
      (side[pin.variable] = side[pin.variable] || []).push({ task: task.name, pin });
    }
  }
  const out = [];
  for (const [variable, from] of Object.entries(writers)) {
    for (const w of from) {
      for (const r of readers[variable] || []) {
        if (r.task === w.task) continue;
        out.push({ variable, from: w, to: r, dashed: isConst(w.pin.kind) || isConst(r.pin.kind) });
      }
    }
  }
  return { links: out, written: new Set(Object.keys(writers)) };
}

/** The next free spot for a block placed by keyboard: left to right, top to bottom, clear of the others. */
export function nextFreeSpot(tasks, width, heightOf) {
  const columns = Math.max(1, Math.floor((width - GAP) / (BLOCK_WIDTH + GAP)));
  for (let i = 0; ; i++) {
    const x = GAP / 2 + (i % columns) * (BLOCK_WIDTH + GAP);
    const y = 20 + Math.floor(i / columns) * 200;
    const clear = tasks.every((t) => x + BLOCK_WIDTH + 10 < t.x || t.x + BLOCK_WIDTH + 10 < x ||
                                     y + 180 < t.y || t.y + heightOf(t) + 10 < y);
    if (clear) return { x, y };
  }
}

/** A module's modifiers with their default and type, as the lexicon gives them. */
export function modifiers(module) {
  return (module && module.params) || [];
}

/** A default value shown as YAML text (the lexicon's JSON value). */
export function yamlOf(value) {
  if (value === null || value === undefined) return "";
  if (value === Infinity) return ".inf";
  return typeof value === "string" ? value : JSON.stringify(value);
}
