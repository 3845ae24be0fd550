// The job dictionary's icons (Onika §4.4.1): a body "framed in a structure which has a left and right
// edge of a certain shape and color", drawn in SVG. An action's right edge is flat; an action
// requiring an object of type T has a notch T cut into its right edge; an object of type T has the
// matching tab T on its left; a gap is an empty slot of its type. The shape and colour of T come
// from T's name alone (a hash), so every page, every run and every screenshot draws T the same way.
import { html } from "../html.js";

export const WIDTH = 156;   // the body, px
export const HEIGHT = 58;
export const DEPTH = 12;    // how far a notch cuts in and a tab sticks out: an object overlaps its job by this much
const TOP = 15, BOTTOM = 43; // where a shaped edge runs, px from the top

const SHAPES = ["triangle", "square", "round", "dovetail", "double", "step"];

/** FNV-1a over the name's UTF-16 units: a small, stable hash (not for security). */
function hash(text) {
  let h = 0x811c9dc5;
  for (let i = 0; i < text.length; i++) {
    h ^= text.charCodeAt(i);
    h = Math.imul(h, 0x01000193) >>> 0;
  }
  return h >>> 0;
}

/** The shape and colour of object type `type`: {shape, colour}. */
export function typeStyle(type) {
  const h = hash(String(type));
  return { shape: SHAPES[h % SHAPES.length], colour: `hsl(${(Math.floor(h / SHAPES.length) % 12) * 30}, 62%, 42%)` };
}

/** The edge's profile, top to bottom: [depth, y] points (depth 0 on the body's edge line). */
function profile(shape) {
  const middle = (TOP + BOTTOM) / 2, D = DEPTH;
  switch (shape) {
    case "triangle": return [[0, TOP], [D, middle], [0, BOTTOM]];
    case "square": return [[0, TOP], [D, TOP], [D, BOTTOM], [0, BOTTOM]];
    case "dovetail": return [[0, TOP + 6], [D, TOP], [D, BOTTOM], [0, BOTTOM - 6]];
    case "double": return [[0, TOP], [D, TOP + 7], [0, middle], [D, BOTTOM - 7], [0, BOTTOM]];
    case "step": return [[0, TOP], [D, TOP], [D, middle], [D / 2, middle], [D / 2, BOTTOM], [0, BOTTOM]];
    default: { // round: a half disc
      const points = [];
      for (let i = 0; i <= 12; i++) points.push([D * Math.sin(Math.PI * i / 12), TOP + (BOTTOM - TOP) * i / 12]);
      return points;
    }
  }
}

const fixed = (n) => Math.round(n * 100) / 100;

/**
 * The outline of an icon with edges {left, right} (as the dictionary gives them: {shape: "flat" |
 * "notch" | "tab", object_type}), clockwise from the top left: {outline, edgePaths: [{d, colour}]}.
 * x runs from -DEPTH (a tab's tip) to WIDTH; the body is 0..WIDTH.
 */
export function iconPaths(edges) {
  const points = [[0, 0], [WIDTH, 0]];
  const edgePaths = [];
  const right = edges.right || { shape: "flat" };
  if (right.shape === "notch") {
    const style = typeStyle(right.object_type);
    const cut = profile(style.shape).map(([d, y]) => [WIDTH - d, y]);
    points.push(...cut);
    edgePaths.push({ d: "M" + cut.map(([x, y]) => `${fixed(x)},${fixed(y)}`).join(" L"), colour: style.colour, side: "right" });
  }
  points.push([WIDTH, HEIGHT], [0, HEIGHT]);
  const left = edges.left || { shape: "flat" };
  if (left.shape === "tab") {
    const style = typeStyle(left.object_type);
    const tab = profile(style.shape).map(([d, y]) => [-d, y]).reverse();  // bottom to top, sticking out
    points.push(...tab);
    edgePaths.push({ d: "M" + tab.map(([x, y]) => `${fixed(x)},${fixed(y)}`).join(" L"), colour: style.colour, side: "left" });
  }
  const outline = "M" + points.map(([x, y]) => `${fixed(x)},${fixed(y)}`).join(" L") + " Z";
  return { outline, edgePaths };
}

/**
 * One icon, in SVG: `kind` (action, action_requiring_object, incomplete, object, gap) sets its fill;
 * `title` and `subtitle` are its two lines; `application` marks an application (a double left rule).
 */
export function IconSvg({ edges, kind, title, subtitle, application = false }) {
  const { outline, edgePaths } = iconPaths(edges);
  const hasTab = (edges.left || {}).shape === "tab";
  const x0 = hasTab ? -DEPTH : 0;
  const width = WIDTH - x0;
  const clip = (text, most) => (text.length > most ? text.slice(0, most - 1) + "…" : text);  // the full name is the button's label
  return html`
    <svg class=${"icon-svg kind-" + kind} width=${width} height=${HEIGHT} viewBox=${`${x0} 0 ${width} ${HEIGHT}`}
         aria-hidden="true" focusable="false">
      <path class="icon-body" d=${outline} />
      ${edgePaths.map((p) => html`<path class=${"icon-edge edge-" + p.side} d=${p.d} stroke=${p.colour}
                                        fill=${p.side === "left" ? p.colour : "none"} fill-opacity="0.35" />`)}
      ${application ? html`<path class="icon-app-rule" d=${`M5,4 L5,${HEIGHT - 4}`} />` : null}
      <text class="icon-title" x=${hasTab ? 8 : 12} y="24">${clip(title, 17)}</text>
      <text class="icon-subtitle" x=${hasTab ? 8 : 12} y="42">${clip(subtitle, 22)}</text>
    </svg>`;
}

/** A small swatch of object type `type`'s edge (the legend): its tab, in its colour. */
export function TypeSwatch({ type }) {
  const style = typeStyle(type);
  const tab = profile(style.shape).map(([d, y]) => `${fixed(DEPTH - d + 2)},${fixed(y - TOP + 2)}`).join(" L");
  return html`
    <svg class="type-swatch" width=${DEPTH + 10} height=${BOTTOM - TOP + 4} aria-hidden="true" focusable="false"
         data-shape=${style.shape}>
      <path d=${"M" + tab} stroke=${style.colour} fill=${style.colour} fill-opacity="0.35" stroke-width="2.5" />
    </svg>`;
}
