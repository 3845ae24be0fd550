// The job canvas (Onika §4.3.1), drawn in SVG: a module dropped from the lexicon is placed where the
// mouse button is let up; each task's pins are joined to the pins of the same variable (consts
// dashed); the checker's diagnostics are badges on the block and on the pin, with E-code and message.
// Blocks move by dragging (or arrow keys) and are selected by click or focus.
import { html, useRef } from "../html.js";
import { BLOCK_WIDTH, blockHeight, pinPlaces, isConst } from "./model.js";
import { DRAG_TYPE } from "./lexicon.js";

export const CANVAS_HEIGHT = 620;

function curve(a, b) {
  // forward: an S as wide as the gap; backward (a feedback link): a short loop that stays near its blocks
  const bend = b.x > a.x ? Math.max(40, (b.x - a.x) / 2) : 50;
  return `M${a.x},${a.y} C${a.x + bend},${a.y} ${b.x - bend},${b.y} ${b.x},${b.y}`;
}

const label = (d) => `${d.code}: ${d.message}${d.hint ? ` (hint: ${d.hint})` : ""}`
  + (d.notes || []).map((n) => `\n  note: ${n.task || `${(n.file || "").split("/").pop()}:${n.line}`}: ${n.message}`).join("");

function Badge({ diagnostics, x, y, pin }) {
  const worst = diagnostics.find((d) => d.severity === "error") || diagnostics[0];
  const text = diagnostics.map(label).join("\n");
  return html`
    <g class=${"badge " + worst.severity + (pin ? " pin-badge" : " block-badge")} transform=${`translate(${x},${y})`}
       data-code=${worst.code} data-port=${pin || undefined} role="img" aria-label=${text}>
      <title>${text}</title>
      ${pin ? html`<circle r="6" />` : html`<rect x="-2" y="-11" rx="4" width=${46 + (diagnostics.length > 1 ? 14 : 0)} height="18" />`}
      ${pin ? "" : html`<text x="4" y="2">${worst.code}${diagnostics.length > 1 ? ` +${diagnostics.length - 1}` : ""}</text>`}
    </g>`;
}

function Block({ task, pins, diagnostics, state, selected, openVariables, onSelect, onMoveStart, onKey }) {
  const places = pinPlaces(pins);
  const height = blockHeight(pins);
  const mine = diagnostics;  // the block's badge counts them all; a pin's badge, those about it
  const byPin = {};
  for (const d of diagnostics.filter((d) => d.port)) (byPin[d.port] = byPin[d.port] || []).push(d);
  const status = state ? ` ${state}` : task.on ? "" : " off";
  return html`
    <g class=${"task" + (task.on ? "" : " off") + (selected ? " selected" : "") + (diagnostics.some((d) => d.severity === "error") ? " has-error" : "")}
       data-task=${task.name} data-module=${task.module} transform=${`translate(${task.x},${task.y})`}
       tabindex="0" role="group" aria-label=${`task ${task.name} (${task.module})${status}`}
       onPointerDown=${(event) => onMoveStart(event, task)} onFocus=${() => onSelect(task.name)} onKeyDown=${(event) => onKey(event, task)}>
      <rect class="block" width=${BLOCK_WIDTH} height=${height} rx="6" />
      <text class="task-name" x="10" y="17">${task.name}</text>
      <text class="task-module" x="10" y="32">${task.module}</text>
      <text class="task-state" x=${BLOCK_WIDTH - 8} y="17" text-anchor="end" data-test="state">${state || (task.on ? "" : "OFF")}</text>
      ${pins.map((pin) => {
        const at = places[pin.port];
        const open = at.input && openVariables.has(pin.variable);
        return html`
          <g class=${"pin" + (isConst(pin.kind) ? " const" : "") + (open ? " open" : "")} data-port=${pin.port} data-variable=${pin.variable}
             data-kind=${pin.kind} transform=${`translate(${at.x},${at.y})`}>
            <title>${`${pin.port}: ${pin.kind} ${pin.variable} (${pin.dtype} ${pin.shape})${open ? " — nobody on the canvas writes it" : ""}`}</title>
            <circle r="4" />
            <text x=${at.input ? 8 : -8} y="4" text-anchor=${at.input ? "start" : "end"}>${pin.variable === pin.port ? pin.port : `${pin.port}→${pin.variable}`}</text>
          </g>`;
      })}
      ${mine.length ? html`<${Badge} diagnostics=${mine} x=${BLOCK_WIDTH - 44} y="-6" />` : ""}
      ${Object.entries(byPin).map(([port, found]) => places[port]
        ? html`<${Badge} diagnostics=${found} pin=${port} x=${places[port].input ? -12 : BLOCK_WIDTH + 12} y=${places[port].y} />` : "")}
    </g>`;
}

/**
 * The canvas. `tasks` with positions; `pins` by task; `drawn` = model.links(); `diagnostics` by task;
 * `states` by task (live); `onDrop(module, x, y)`, `onMove(name, x, y)`, `onSelect(name)`, `onKey(event, task)`.
 */
export function JobCanvas({ tasks, pins, drawn, jobWritten, diagnostics, states, selected, onDrop, onMove, onSelect, onKey }) {
  const svg = useRef(null);
  const point = (event) => {
    const box = svg.current.getBoundingClientRect();
    return { x: event.clientX - box.left, y: event.clientY - box.top };
  };
  const byName = Object.fromEntries(tasks.map((t) => [t.name, t]));
  const where = (end) => {
    const task = byName[end.task];
    const at = pinPlaces(pins[end.task] || [])[end.pin.port];
    return { x: task.x + at.x, y: task.y + at.y };
  };
  const openVariables = new Set(tasks.filter((t) => t.on).flatMap((t) => (pins[t.name] || []).filter((p) => p.kind.startsWith("in"))
    .map((p) => p.variable)).filter((v) => !drawn.written.has(v) && !jobWritten.has(v)));
  const moveStart = (event, task) => {
    if (event.button !== 0) return;
    onSelect(task.name);
    const start = point(event);
    const from = { x: task.x, y: task.y };
    const target = event.currentTarget;
    target.setPointerCapture(event.pointerId);
    const move = (e) => {
      const now = point(e);
      onMove(task.name, Math.max(0, from.x + now.x - start.x), Math.max(0, from.y + now.y - start.y));
    };
    const up = () => { target.removeEventListener("pointermove", move); target.removeEventListener("pointerup", up); };
    target.addEventListener("pointermove", move);
    target.addEventListener("pointerup", up);
  };
  return html`
    <svg ref=${svg} class="job-canvas" height=${CANVAS_HEIGHT} role="application" aria-label="job canvas" data-test="canvas"
         onDragOver=${(event) => { if ([...event.dataTransfer.types].includes(DRAG_TYPE)) { event.preventDefault(); event.dataTransfer.dropEffect = "copy"; } }}
         onDrop=${(event) => {
           const module = event.dataTransfer.getData(DRAG_TYPE);
           if (!module) return;
           event.preventDefault();
           const at = point(event);
           onDrop(module, at.x, at.y);
         }}>
      <g class="links">
        ${drawn.links.map((l) => {
          const a = where(l.from), b = where(l.to);
          return html`<path class=${"link" + (l.dashed ? " const" : "")} d=${curve(a, b)} data-variable=${l.variable}
                            data-from=${`${l.from.task}.${l.from.pin.port}`} data-to=${`${l.to.task}.${l.to.pin.port}`}>
                        <title>${`${l.variable}: ${l.from.task}.${l.from.pin.port} → ${l.to.task}.${l.to.pin.port}${l.dashed ? " (const)" : ""}`}</title></path>`;
        })}
      </g>
      ${tasks.length === 0 ? html`<text class="canvas-hint" x="24" y="40">Drag a module from the lexicon here (or select it and press Enter).</text>` : ""}
      ${tasks.map((t) => html`<${Block} key=${t.name} task=${t} pins=${pins[t.name] || []} diagnostics=${diagnostics[t.name] || []}
                                        state=${states[t.name]} selected=${selected === t.name} openVariables=${openVariables}
                                        onSelect=${onSelect} onMoveStart=${moveStart} onKey=${onKey} />`)}
    </svg>`;
}
