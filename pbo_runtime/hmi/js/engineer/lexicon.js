// The task lexicon (Onika §4.3.1): one block icon per module, made on the fly from its declaration:
// its name, input pins on the left, output pins on the right (consts marked), its modifiers with
// their defaults. A module that cannot be placed legally on the canvas is dimmed and unselectable
// (aria-disabled), with the placement query's reason on hover.
import { html } from "../html.js";
import { modifiers, yamlOf, isConst } from "./model.js";

export const DRAG_TYPE = "application/x-pbo-module";

function Pins({ ports, side }) {
  return html`
    <ul class=${"lex-pins " + side}>
      ${ports.map((p) => html`
        <li class=${"lex-pin" + (isConst(p.kind) ? " const" : "")} title=${`${p.name}: ${p.kind} ${p.variable} (${p.dtype} ${p.shape})`}>
          ${p.name}${isConst(p.kind) ? html`<abbr title="const: read or written once, at init">c</abbr>` : ""}</li>`)}
    </ul>`;
}

function reasonOf(verdict) {
  if (!verdict || verdict.legal) return "";
  return `${verdict.code}: ${verdict.reason}${verdict.hint ? ` (${verdict.hint})` : ""}`;
}

function Block({ module, verdict, selected, defaults, onSelect, onPlace }) {
  const disabled = Boolean(verdict && !verdict.legal);
  const reason = reasonOf(verdict);
  const inputs = module.ports.filter((p) => p.kind.startsWith("in"));
  const outputs = module.ports.filter((p) => !p.kind.startsWith("in"));
  const given = (defaults[module.name] && defaults[module.name].params) || {};
  const keys = (event) => {
    if (disabled) return;
    if (event.key === "Enter") { event.preventDefault(); onPlace(module.name); }
    else if (event.key === " ") { event.preventDefault(); onSelect(module.name); }
  };
  return html`
    <li class=${"lex-block" + (disabled ? " dimmed" : "") + (selected ? " selected" : "")} data-module=${module.name}
        role="option" tabindex="0" aria-selected=${selected} aria-disabled=${disabled}
        aria-describedby=${disabled ? `why-${module.name}` : undefined}
        title=${disabled ? reason : `${module.summary} Drag onto the canvas, or press Enter to place it.`}
        draggable=${!disabled}
        onDragStart=${(event) => { event.dataTransfer.setData(DRAG_TYPE, module.name); event.dataTransfer.setData("text/plain", module.name);
                                   event.dataTransfer.effectAllowed = "copy"; }}
        onClick=${() => !disabled && onSelect(module.name)} onKeyDown=${keys}>
      <div class="lex-body">
        <${Pins} ports=${inputs} side="inputs" />
        <div class="lex-name"><strong>${module.name}</strong>
          ${module.note ? html`<small class="lex-note">ports from modifiers</small>` : ""}</div>
        <${Pins} ports=${outputs} side="outputs" />
      </div>
      ${modifiers(module).length ? html`
        <dl class="lex-modifiers">
          ${modifiers(module).map((p) => html`
            <div title=${`${p.name}: ${p.type}${p.doc ? " — " + p.doc : ""}`}>
              <dt>${p.name}</dt><dd>${given[p.name] || (p.required ? "required" : yamlOf(p.default))}</dd></div>`)}
        </dl>` : ""}
      ${disabled ? html`<p class="lex-why" id=${`why-${module.name}`} data-code=${verdict.code}>${reason}</p>` : ""}
    </li>`;
}

/** The lexicon: `verdicts` by module from the placement query; `note` when the query could not answer. */
export function Lexicon({ modules, verdicts, busy, note, selected, defaults, onSelect, onPlace }) {
  if (!modules) return html`<p>Loading the lexicon…</p>`;
  return html`
    ${note ? html`<p class="lex-placement-note" data-test="placement-note">${note}</p>` : ""}
    <ul class="lexicon" role="listbox" aria-label="task lexicon" aria-busy=${busy ? "true" : "false"}>
      ${modules.map((m) => html`<${Block} key=${m.name} module=${m} verdict=${verdicts[m.name]} selected=${selected === m.name}
                                          defaults=${defaults} onSelect=${onSelect} onPlace=${onPlace} />`)}
    </ul>`;
}
