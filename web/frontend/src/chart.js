// AP per operator as lines (bbox / BEV / 3D), the form of the thesis's figure 5-14: drawn as SVG,
// one point per subtask in task order, the originals' values as dashed reference lines.
import { h, svg } from "./dom.js";

// three hues far apart (blue, orange, green: told apart with the common colour-vision deficiencies
// too), each line also with its own dash, named in the legend
export const METRICS = [
  { key: "bbox", name: "bbox (2D)", colour: "#1f77b4", dash: "" },
  { key: "bev", name: "BEV", colour: "#e6550d", dash: "6 3" },
  { key: "3d", name: "3D", colour: "#2ca02c", dash: "2 3" },
];

// One AP figure of a subtask: its KITTI result (the contract's APRecord: {ap: {metric: {class:
// {difficulty: {R11, R40}}}}, map: {metric: {difficulty: {R11, R40}}}}; null until it completes).
// Undefined figures are null.
export function apValue(subtask, metric, cls, difficulty, points) {
  const ap = subtask.ap;
  if (ap === null) return null;
  const value = cls === "mAP" ? ap.map[metric]?.[difficulty]?.[points] : ap.ap[metric]?.[cls]?.[difficulty]?.[points];
  return typeof value === "number" ? value : null;
}

export function classesOf(subtasks) {
  for (const subtask of subtasks) {
    const bbox = subtask.ap?.ap.bbox;
    if (bbox && typeof bbox === "object") return Object.keys(bbox);
  }
  return [];
}

export function apChart(subtasks, { cls = "Car", difficulty = "moderate", points = "R40", width: available = 0 } = {}) {
  const labels = subtasks.map((subtask) => subtask.label);
  const series = METRICS.map((m) => ({ ...m, values: subtasks.map((subtask) => apValue(subtask, m.key, cls, difficulty, points)) }));
  const width = Math.max(560, 70 + labels.length * 56, available);
  const longest = Math.max(0, ...labels.map((l) => l.length));
  const margin = { left: 48, right: 24, top: 16, bottom: Math.min(170, 24 + longest * 5) };
  const height = 230 + margin.bottom;
  const plotW = width - margin.left - margin.right;
  const plotH = height - margin.top - margin.bottom;
  const x = (i) => margin.left + (labels.length <= 1 ? plotW / 2 : (i * plotW) / (labels.length - 1));
  const y = (v) => margin.top + plotH - (Math.max(0, Math.min(100, v)) / 100) * plotH;
  const root = svg("svg", {
    viewBox: `0 0 ${width} ${height}`,
    width,
    height,
    class: "chart",
    role: "img",
    "aria-label": `AP per subtask, ${cls}, ${difficulty}, ${points}`,
    testid: "ap-chart",
  });
  for (let tick = 0; tick <= 100; tick += 20) {
    root.append(
      svg("line", { x1: margin.left, x2: width - margin.right, y1: y(tick), y2: y(tick), class: "grid" }),
      svg("text", { x: margin.left - 6, y: y(tick) + 4, class: "tick", "text-anchor": "end" }, String(tick)),
    );
  }
  root.append(svg("text", { x: 12, y: margin.top + plotH / 2, class: "axis-title", transform: `rotate(-90 12 ${margin.top + plotH / 2})`, "text-anchor": "middle" }, "AP (%)"));
  labels.forEach((label, i) => {
    const tx = x(i);
    const ty = margin.top + plotH + 10;
    root.append(
      svg("line", { x1: tx, x2: tx, y1: margin.top + plotH, y2: margin.top + plotH + 4, class: "axis" }),
      svg("text", { x: tx, y: ty, class: "tick", "text-anchor": "end", transform: `rotate(-40 ${tx} ${ty})` }, label),
    );
  });
  root.append(svg("line", { x1: margin.left, x2: width - margin.right, y1: margin.top + plotH, y2: margin.top + plotH, class: "axis" }));
  let drawn = 0;
  for (const s of series) {
    if (s.values[0] !== null && /^original/.test(labels[0])) {
      root.append(svg("line", { x1: margin.left, x2: width - margin.right, y1: y(s.values[0]), y2: y(s.values[0]), stroke: s.colour, class: "reference" }));
    }
    // a line through consecutive known values; gaps where a subtask has none yet
    let path = "";
    let pen = false;
    s.values.forEach((v, i) => {
      if (v === null) {
        pen = false;
        return;
      }
      path += `${pen ? "L" : "M"}${x(i).toFixed(1)},${y(v).toFixed(1)}`;
      pen = true;
    });
    if (path) root.append(svg("path", { d: path, stroke: s.colour, "stroke-dasharray": s.dash || null, class: "series", "data-metric": s.key }));
    s.values.forEach((v, i) => {
      if (v === null) return;
      drawn++;
      root.append(
        svg("circle", { cx: x(i), cy: y(v), r: 3.5, fill: s.colour, class: "dot" }, svg("title", {}, `${labels[i]} · ${s.name}: ${v.toFixed(2)}`)),
      );
    });
  }
  root.dataset.points = String(drawn);
  const legend = h(
    "div",
    { class: "legend" },
    series.map((s) => h("span", { class: "legend-item", dataset: { metric: s.key }, testid: `legend-${s.key}` }, h("span", { class: "swatch", style: { background: s.colour } }), s.name)),
    h("span", { class: "legend-item muted" }, "dashed: the originals"),
  );
  return h("figure", { class: "chart-figure" }, h("div", { class: "chart-scroll" }, root), legend);
}
