// The devices the operator plays (verb play): a trackball with source: hmi gets six sliders, dx dy dz
// in m and rx ry rz in rad within its travel; each move sends all six (POST /api/verbs/play), and
// Centre sends zeros. The module that reads the device adds them to the pose the arm had at `on`.
import { html, useState } from "../html.js";
import { verb } from "../api.js";

function PlayedDevice({ device, controls, report }) {
  const [values, setValues] = useState(controls.map(() => 0));
  const send = async (next) => {
    setValues(next);
    try {
      const reply = await verb("play", { device, values: next });
      report(true, reply.message || `device '${device}' plays ${next.join(" ")}`);
    } catch (e) {
      report(false, e.message);
    }
  };
  const move = (index, value) => send(values.map((v, i) => (i === index ? value : v)));
  return html`
    <fieldset class="played" data-testid=${`played-${device}`}>
      <legend>${device}</legend>
      ${controls.map((c, i) => {
        const id = `play-${device}-${c.name}`;
        return html`
          <div class="played-control" key=${c.name}>
            <label for=${id}>${c.name}</label>
            <input id=${id} type="range" min=${c.min} max=${c.max} step=${(c.max - c.min) / 200}
                   value=${values[i]} aria-label=${`${device} ${c.name} (${c.unit})`}
                   onChange=${(e) => move(i, Number(e.target.value))} />
            <output>${values[i].toFixed(3)} ${c.unit}</output>
          </div>`;
      })}
      <button type="button" onClick=${() => send(controls.map(() => 0))} aria-label=${`Centre ${device}`}>Centre</button>
    </fieldset>`;
}

export function PlayedDevices({ status, layout, report }) {
  if (!layout || !layout.played || !Object.keys(layout.played).length) return null;
  return html`
    <section class="played-devices" aria-label="devices the operator plays">
      <h3>Trackball</h3>
      ${Object.entries(layout.played).map(([device, controls]) => html`
        <${PlayedDevice} key=${device} device=${device} controls=${controls} report=${report} />`)}
    </section>`;
}
