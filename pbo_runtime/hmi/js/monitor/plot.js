// Live plots of chosen state variables: elements of variables, or the difference of two variables
// element by element (a tracking error such as q_r - q_m), drawn with uPlot at the screen's rate
// from the API's variables stream (GET /api/streams/variables?names=...&rate=...).
//
// For tests and benchmarks the plot's data is readable (never its pixels): window.pboMonitor.plot
// holds {labels, data, latest, samples}, and window.pboMonitor.probe, when set, is called after each
// frame the plot drew with (latest values by variable, the wall-clock time in ms of that frame).
// window.pboMonitor.pending = {specs, rate}, set before the page loads, is the plot's first choice;
// window.pboMonitor.plotSeries(specs, rate) changes it.
import uPlot from "uplot";
import { html, useState, useEffect, useRef } from "../html.js";
import { stream } from "../api.js";

const WINDOW_SECONDS = 10;
const RATES = [10, 20, 50, 100];
const COLOURS = ["#2458b3", "#b3261e", "#1f7a3a", "#a15c00", "#6b3fa0", "#00838f", "#5b6575", "#c2185b", "#7a6a00", "#37474f"];

export const hooks = (window.pboMonitor = window.pboMonitor || {});

const elements = (shape) => shape.reduce((n, d) => n * d, 1);
const label = (s) => (s.b ? `${s.a}[${s.index}] - ${s.b}[${s.index}]` : `${s.a}[${s.index}]`);
const flat = (value) => (Array.isArray(value) ? value.flat(Infinity) : [value]);

/** The series specs for variable `a` (minus `b`), one element or all of them. */
export function seriesFor(a, b, element, shape) {
  const indices = element === "all" ? [...Array(elements(shape)).keys()] : [Number(element)];
  return indices.map((index) => ({ a, b: b || null, index }));
}

function SeriesForm({ layout, onAdd }) {
  const numeric = Object.entries(layout.variables).filter(([, v]) => v.dtype !== "bool");
  const [a, setA] = useState(layout.variables.q_m ? "q_m" : numeric.length ? numeric[0][0] : "");
  const [b, setB] = useState("");
  const [element, setElement] = useState("all");
  const shape = a && layout.variables[a] ? layout.variables[a].shape : [];
  const sameShape = numeric.filter(([name, v]) => name !== a && JSON.stringify(v.shape) === JSON.stringify(shape));
  const submit = (event) => {
    event.preventDefault();
    if (a) onAdd(seriesFor(a, b, element, shape));
  };
  return html`
    <form class="series-form" aria-label="add a plotted signal" onSubmit=${submit}>
      <label>Variable <select value=${a} onChange=${(e) => { setA(e.target.value); setB(""); setElement("all"); }} aria-label="variable">
        ${numeric.map(([name]) => html`<option value=${name}>${name}</option>`)}</select></label>
      <label>minus <select value=${b} onChange=${(e) => setB(e.target.value)} aria-label="minus variable">
        <option value="">(nothing)</option>
        ${sameShape.map(([name]) => html`<option value=${name}>${name}</option>`)}</select></label>
      <label>Element <select value=${element} onChange=${(e) => setElement(e.target.value)} aria-label="element">
        <option value="all">all</option>
        ${[...Array(elements(shape)).keys()].map((i) => html`<option value=${i}>${i}</option>`)}</select></label>
      <button type="submit">Add to plot</button>
    </form>`;
}

/** The uPlot chart of `specs`, fed from the variables stream at `rate` Hz and redrawn once per animation frame. */
function Chart({ specs, rate }) {
  const box = useRef(null);
  const [state, setState] = useState("connecting");
  const [error, setError] = useState("");
  const names = [...new Set(specs.flatMap((s) => (s.b ? [s.a, s.b] : [s.a])))];
  const key = JSON.stringify(specs) + rate;
  useEffect(() => {
    const labels = specs.map(label);
    const data = [[], ...specs.map(() => [])];
    const latest = {};
    const shared = { labels, data, latest, samples: 0, values: {} };
    hooks.plot = shared;
    const width = Math.max(400, box.current.clientWidth || 600);
    const chart = new uPlot({
      width, height: 220, legend: { live: false },
      scales: { x: { time: false } },
      axes: [{ label: "s" }, {}],
      series: [{ label: "t (s)" }, ...labels.map((l, i) => ({ label: l, stroke: COLOURS[i % COLOURS.length], width: 1.5 }))],
    }, data, box.current);
    let t0 = null;
    let dirty = false;
    const live = stream("variables", { names: names.join(","), rate }, (message) => {
      if (message.ok === false) { setError(message.error); return; }
      if (message.ok === true || !message.values) return;  // the stream's head, or a busy table
      setError("");
      if (t0 === null) t0 = message.time;
      const values = {};
      for (const name of names) values[name] = flat(message.values[name]);
      data[0].push(message.time - t0);
      specs.forEach((s, i) => {
        const v = s.b ? values[s.a][s.index] - values[s.b][s.index] : values[s.a][s.index];
        data[i + 1].push(v);
        latest[labels[i]] = v;
      });
      while (data[0].length && data[0][data[0].length - 1] - data[0][0] > WINDOW_SECONDS) data.forEach((d) => d.shift());
      shared.samples += 1;
      shared.values = values;
      dirty = true;
    }, setState);
    let frame = requestAnimationFrame(function draw() {
      if (dirty) {
        dirty = false;
        chart.setData(data);
        box.current && box.current.setAttribute("data-samples", String(shared.samples));
        if (hooks.probe) hooks.probe(shared.values, performance.timeOrigin + performance.now());
      }
      frame = requestAnimationFrame(draw);
    });
    return () => { cancelAnimationFrame(frame); live.close(); chart.destroy(); };
  }, [key]);
  return html`
    <div class="chart" ref=${box} data-test="plot" data-series=${specs.map(label).join(";")} aria-label="live plot"
         role="img"></div>
    ${error ? html`<p class="error" role="alert">${error}</p>` : state !== "open" ? html`<p class="no-run">stream ${state}</p>` : null}`;
}

export function Plots({ status, layout }) {
  // a benchmark may ask for series before the page's scripts run (window.pboMonitor.pending)
  const [specs, setSpecs] = useState(() => (hooks.pending ? hooks.pending.specs : []));
  const [rate, setRate] = useState(() => (hooks.pending ? hooks.pending.rate : 50));
  useEffect(() => {
    hooks.plotSeries = (next, nextRate) => { setSpecs(next); if (nextRate) setRate(nextRate); };
    return () => { delete hooks.plotSeries; };
  }, []);
  if (!layout) return null;
  const vars = layout.variables;
  const canTrack = vars.q_r && vars.q_m;
  const add = (more) => setSpecs((now) => [...now, ...more.filter((m) => !now.some((s) => label(s) === label(m)))]);
  return html`
    <section class="plots" aria-label="live plots">
      <h3>Live plot</h3>
      <div class="plot-controls">
        <${SeriesForm} layout=${layout} onAdd=${add} />
        ${canTrack ? html`<button onClick=${() => add(seriesFor("q_r", "q_m", "all", vars.q_r.shape))}>Plot tracking error q_r - q_m</button>` : null}
        <label>Rate <select value=${rate} onChange=${(e) => setRate(Number(e.target.value))} aria-label="plot rate">
          ${RATES.map((r) => html`<option value=${r}>${r} Hz</option>`)}</select></label>
        ${specs.length ? html`<button onClick=${() => setSpecs([])}>Clear plot</button>` : null}
      </div>
      ${specs.length ? html`<${Chart} specs=${specs} rate=${rate} />` : html`<p class="no-run">Choose a variable to plot.</p>`}
    </section>`;
}
