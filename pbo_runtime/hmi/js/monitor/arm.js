// The arm drawn from its joint frames as it moves: the frames' origins, base to tool, computed by
// the API from q_m (forward kinematics, GET /api/streams/arm), in two orthographic views.
import { html, useState, useEffect } from "../html.js";
import { stream } from "../api.js";
import { hooks } from "./plot.js";

const SIZE = 220;
const VIEWS = [{ name: "side (x, z)", x: 0, y: 2 }, { name: "top (x, y)", x: 0, y: 1 }];

function View({ frames, reach, view }) {
  const scale = (SIZE / 2 - 12) / reach;
  const points = frames.map((p) => [SIZE / 2 + p[view.x] * scale, SIZE / 2 - p[view.y] * scale]);
  return html`
    <figure class="arm-view">
      <svg width=${SIZE} height=${SIZE} viewBox=${`0 0 ${SIZE} ${SIZE}`} role="img" aria-label=${"arm, " + view.name}>
        <line x1="0" y1=${SIZE / 2} x2=${SIZE} y2=${SIZE / 2} class="arm-axis" />
        <line x1=${SIZE / 2} y1="0" x2=${SIZE / 2} y2=${SIZE} class="arm-axis" />
        <polyline points=${points.map((p) => p.join(",")).join(" ")} class="arm-links" />
        ${points.map((p, i) => html`<circle cx=${p[0]} cy=${p[1]} r=${i === points.length - 1 ? 4 : 3}
                                            class=${i === points.length - 1 ? "arm-tool" : "arm-joint"} />`)}
      </svg>
      <figcaption>${view.name}</figcaption>
    </figure>`;
}

export function ArmView({ status }) {
  const [frames, setFrames] = useState(null);
  const [error, setError] = useState("");
  const [reach, setReach] = useState(0.5);
  const run = status.run_id;
  useEffect(() => {
    const live = stream("arm", { rate: 20 }, (message) => {
      if (message.ok === false) { setError(message.error); return; }
      if (!message.frames) return;
      setError("");
      hooks.arm = message.frames;
      const far = Math.max(...message.frames.map((p) => Math.hypot(p[0], p[1], p[2])));
      setReach((r) => Math.max(r, far * 1.1));
      setFrames(message.frames);
    });
    return () => live.close();
  }, [run]);
  return html`
    <section class="arm" aria-label="arm" data-test="arm" data-frames=${frames ? frames.length : 0}>
      <h3>Arm</h3>
      ${error ? html`<p class="no-run">${error}</p>` : frames ? VIEWS.map((v) => html`<${View} frames=${frames} reach=${reach} view=${v} />`)
                                                       : html`<p class="no-run">Waiting for the arm…</p>`}
    </section>`;
}
