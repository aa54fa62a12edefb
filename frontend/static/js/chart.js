// Small SVG charts (no library): line curves and before/after bars, each with a text alternative.
const NS = "http://www.w3.org/2000/svg";
const COLOURS = ["#3b78e7", "#d0544a", "#2e9a4f", "#b07d12", "#8b5cf6", "#0e96b0"]; // readable on light and dark

/** A step of 1, 2 or 5 × 10^k that cuts `span` into about `count` parts. */
function niceStep(span, count) {
  const raw = span / count;
  const power = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * power).find((step) => step >= raw);
}

/** The y axis: its ends on round numbers around the data, and its ticks. A flat line sits in the middle of a
 * narrow axis around its value (never −0.3 … 1.7 around 0.7); `range` ([lo, hi], e.g. [0, 1] for rates)
 * is kept whenever the data fit in it. */
export function yAxis(values, range = null) {
  let lo = Math.min(...values);
  let hi = Math.max(...values);
  if (range && lo >= range[0] && hi <= range[1]) [lo, hi] = range;
  else if (lo === hi) {
    const pad = Math.abs(lo) > 1e-9 ? Math.abs(lo) * 0.1 : 0.1;
    [lo, hi] = [lo - pad, hi + pad];
  }
  const step = niceStep(hi - lo, 4);
  const [from, to] = [Math.floor(lo / step + 1e-9) * step, Math.ceil(hi / step - 1e-9) * step];
  const ticks = [];
  for (let v = from; v <= to + step / 2; v += step) ticks.push(Number(v.toPrecision(12)));
  return { from, to, ticks };
}

function tickText(value) {
  return Math.abs(value) >= 1000 ? value.toLocaleString() : String(Number(value.toPrecision(3)));
}

function svg(tag, attributes = {}) {
  const node = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attributes)) node.setAttribute(k, v);
  return node;
}

/** series: {name: [y, …] or [[x, y], …]} → an <svg> line chart. */
export function lineChart(series, { title = "", width = 480, height = 160, range = null } = {}) {
  const lines = Object.entries(series)
    .map(([name, values]) => [name, values.map((v, i) => (Array.isArray(v) ? v : [i, v])).filter(([x, y]) => Number.isFinite(x) && Number.isFinite(y))])
    .filter(([, points]) => points.length > 0);
  const root = svg("svg", { viewBox: `0 0 ${width} ${height}`, class: "chart", role: "img" });
  const all = lines.flatMap(([, points]) => points);
  const summary = lines.map(([name, points]) => `${name}: ${points.length} points, last ${points[points.length - 1][1].toPrecision(3)}`).join("; ");
  root.setAttribute("aria-label", `${title}${title ? ". " : ""}${summary || "no data yet"}`);
  if (!all.length) return root;
  const [x0, x1] = [Math.min(...all.map((p) => p[0])), Math.max(...all.map((p) => p[0]))];
  const axis = yAxis(all.map((p) => p[1]), range);
  const [y0, y1] = [axis.from, axis.to];
  const pad = { l: 44, r: 8, t: 18, b: 18 };
  const sx = (x) => pad.l + ((x - x0) / (x1 - x0 || 1)) * (width - pad.l - pad.r);
  const sy = (y) => height - pad.b - ((y - y0) / (y1 - y0)) * (height - pad.t - pad.b);
  for (const y of axis.ticks) {
    const text = svg("text", { x: 4, y: sy(y) + 4, "font-size": 11, class: "muted-ink y-tick" });
    text.textContent = tickText(y);
    root.append(text, svg("line", { x1: pad.l, x2: width - pad.r, y1: sy(y), y2: sy(y), class: "gridline" }));
  }
  for (const [x, anchor] of [[x0, "start"], [x1, "end"]]) {
    const text = svg("text", { x: sx(x), y: height - 4, "font-size": 11, "text-anchor": anchor, class: "muted-ink x-tick" });
    text.textContent = tickText(x);
    root.append(text);
  }
  root.dataset.yFrom = String(y0);
  root.dataset.yTo = String(y1);
  lines.forEach(([name, points], i) => {
    const colour = COLOURS[i % COLOURS.length];
    root.append(svg("polyline", { points: points.map(([x, y]) => `${sx(x)},${sy(y)}`).join(" "), fill: "none", stroke: colour, "stroke-width": 2 }));
    const legend = svg("text", { x: pad.l + 4 + i * 130, y: 12, "font-size": 12, fill: colour });
    legend.textContent = name;
    root.append(legend);
  });
  return root;
}

/** before/after: {metric: number} each → grouped bars. */
export function beforeAfterChart(before, after, { width = 480, height = 170 } = {}) {
  const keys = Object.keys(after).filter((k) => Number.isFinite(before[k]) && Number.isFinite(after[k]));
  const root = svg("svg", { viewBox: `0 0 ${width} ${height}`, class: "chart", role: "img" });
  root.setAttribute("aria-label", "Before and after: " + keys.map((k) => `${k} ${before[k].toPrecision(3)} → ${after[k].toPrecision(3)}`).join("; "));
  const top = Math.max(1e-9, ...keys.flatMap((k) => [Math.abs(before[k]), Math.abs(after[k])]));
  const slot = (width - 20) / Math.max(1, keys.length);
  keys.forEach((key, i) => {
    [["before", before[key], "#9aa5b1"], ["after", after[key], "#0b57d0"]].forEach(([, value, colour], j) => {
      const h = (Math.abs(value) / top) * (height - 50);
      const x = 10 + i * slot + 8 + j * (slot / 2 - 8);
      root.append(svg("rect", { x, y: height - 30 - h, width: slot / 2 - 12, height: h, fill: colour }));
      const t = svg("text", { x, y: height - 34 - h, "font-size": 11, class: "ink" });
      t.textContent = value.toPrecision(3);
      root.append(t);
    });
    const name = svg("text", { x: 10 + i * slot + 8, y: height - 12, "font-size": 12, class: "ink" });
    name.textContent = key;
    root.append(name);
  });
  const legend = svg("text", { x: width - 150, y: 14, "font-size": 12, class: "muted-ink" });
  legend.textContent = "grey: before · blue: after";
  root.append(legend);
  return root;
}
