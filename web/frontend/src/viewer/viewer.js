// The point-cloud viewer (three.js): one cloud, or an original and its mutant side by side (one
// camera, so both halves move together) or overlaid with added / removed points coloured from the
// `change` channel; ground truth and detections as wireframe boxes with heading marks (missing
// ground truth and spurious detections highlighted); colour by intensity, height, ring or label
// on turbo; point size; bird's-eye view. The LiDAR frame is z-up (x forward, y left).
//
// Rendering is on demand (after a camera move or a setting change), not in a loop. After each
// render window.__viewer says what was drawn: {pointsDrawn, boxesDrawn, firstRenderMs, renders, …}.
import {
  MOUSE,
  BufferAttribute,
  BufferGeometry,
  Color,
  InterleavedBuffer,
  InterleavedBufferAttribute,
  LineSegments,
  OrthographicCamera,
  PerspectiveCamera,
  Points,
  RawShaderMaterial,
  Scene,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { h } from "../dom.js";
import { categorical, TURBO, turboGradient } from "./colormap.js";

export { parseFrame } from "./lfz.js";

const BACKGROUND = 0x101217;
export const BOX_STYLES = {
  gt: { colour: "#34d058", name: "ground truth" },
  detection: { colour: "#38bdf8", name: "detection" },
  missing: { colour: "#ff4d4f", name: "missing (ground truth not detected)" },
  spurious: { colour: "#ff3bd4", name: "spurious detection" },
  lost: { colour: "#ffa629", name: "detection lost in the mutant" },
};
const ADDED = [64, 255, 96];
const REMOVED = [255, 64, 64];
const KEPT = [120, 124, 132];

export const COLOUR_MODES = {
  height: { channel: "z", label: "height (z)" },
  intensity: { channel: "intensity", label: "intensity" },
  ring: { channel: "ring", label: "ring" },
  label: { channel: "label", label: "label", categorical: true },
  change: { channel: "change", label: "change (added / removed)" },
};

function finiteBox(box) {
  return Array.isArray(box) && box.length >= 7 && box.slice(0, 7).every(Number.isFinite);
}

// 12 edges + a heading mark (centre → front face, and the front face's diagonals) per box.
const EDGES = [
  [0, 1], [1, 2], [2, 3], [3, 0],
  [4, 5], [5, 6], [6, 7], [7, 4],
  [0, 4], [1, 5], [2, 6], [3, 7],
];
export function boxSegments(boxes, inflate = 1) {
  const valid = boxes.filter(finiteBox);
  const out = new Float32Array(valid.length * (EDGES.length + 3) * 6);
  let k = 0;
  const push = (p) => {
    out[k++] = p[0];
    out[k++] = p[1];
    out[k++] = p[2];
  };
  for (const [x, y, z, l, w, hgt, yaw] of valid) {
    const c = Math.cos(yaw);
    const s = Math.sin(yaw);
    const corner = (dx, dy, dz) => [x + (dx * c - dy * s) * inflate, y + (dx * s + dy * c) * inflate, z + dz * inflate];
    const L = l / 2;
    const W = w / 2;
    const H = hgt / 2;
    // 0-3 bottom (front-left, front-right, back-right, back-left), 4-7 the same on top
    const p = [
      corner(L, W, -H), corner(L, -W, -H), corner(-L, -W, -H), corner(-L, W, -H),
      corner(L, W, H), corner(L, -W, H), corner(-L, -W, H), corner(-L, W, H),
    ];
    for (const [a, b] of EDGES) {
      push(p[a]);
      push(p[b]);
    }
    push([x, y, z]);
    push(corner(L, 0, 0));
    push(p[0]);
    push(p[5]);
    push(p[1]);
    push(p[4]);
  }
  return { positions: out, count: valid.length };
}

// One WebGL context, its materials and so its compiled shader programs serve every viewer the page
// opens: a context costs tens of milliseconds to create and its shaders more to compile (far more
// with software WebGL), and browsers cap the contexts a page may hold.
const shared = { renderer: null, points: null, lines: new Map() };

function sharedRenderer() {
  if (!shared.renderer || shared.renderer.getContext().isContextLost()) {
    shared.renderer = new WebGLRenderer({ antialias: false, powerPreference: "high-performance" });
    shared.renderer.domElement.dataset.testid = "viewer-canvas";
    shared.renderer.domElement.className = "viewer-canvas";
    shared.points = pointsMaterial();
    shared.lines.clear();
    // compile the two programs now, while the frame may still be on its way
    const scene = new Scene();
    const geometry = new BufferGeometry();
    geometry.setAttribute("position", new BufferAttribute(new Float32Array(6), 3));
    geometry.setAttribute("color", new BufferAttribute(new Uint8Array(6), 3, true));
    scene.add(new Points(geometry, shared.points), new LineSegments(geometry, lineMaterial(BOX_STYLES.gt.colour)));
    shared.renderer.compile(scene, new PerspectiveCamera());
  }
  return shared.renderer;
}

// Small shaders of our own instead of three's general ones: they compile several times faster,
// which is most of a first render's cost with software WebGL. Point size is in CSS pixels.
function pointsMaterial() {
  const material = new RawShaderMaterial({
    uniforms: { pointSize: { value: 2 } },
    vertexShader: `precision highp float;
uniform mat4 modelViewMatrix; uniform mat4 projectionMatrix; uniform float pointSize;
attribute vec3 position; attribute vec3 color; varying vec3 vColour;
void main() { vColour = color; gl_PointSize = pointSize; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }`,
    fragmentShader: `precision mediump float; varying vec3 vColour;
void main() { gl_FragColor = vec4(vColour, 1.0); }`,
  });
  Object.defineProperty(material, "size", {
    get: () => material.uniforms.pointSize.value / (shared.renderer?.getPixelRatio() ?? 1),
    set: (value) => (material.uniforms.pointSize.value = value * (shared.renderer?.getPixelRatio() ?? 1)),
  });
  return material;
}

function lineMaterial(colour) {
  if (!shared.lines.has(colour)) {
    const c = new Color(colour);
    shared.lines.set(
      colour,
      new RawShaderMaterial({
        uniforms: { colour: { value: [c.r, c.g, c.b] } },
        vertexShader: `precision highp float;
uniform mat4 modelViewMatrix; uniform mat4 projectionMatrix; attribute vec3 position;
void main() { gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }`,
        fragmentShader: `precision mediump float; uniform vec3 colour;
void main() { gl_FragColor = vec4(colour, 1.0); }`,
      }),
    );
  }
  return shared.lines.get(colour);
}

function lines(positions, colour) {
  const geometry = new BufferGeometry();
  geometry.setAttribute("position", new BufferAttribute(positions, 3));
  return new LineSegments(geometry, lineMaterial(colour));
}

// Boxes of one cloud: {objects: [LineSegments], count} split by style.
function boxObjects(entry, show) {
  const objects = [];
  let count = 0;
  if (!entry) return { objects, count };
  const missing = new Set(entry.missing ?? []);
  const spurious = new Set(entry.spurious ?? []);
  const lost = new Set(entry.lost ?? []);
  const add = (boxes, style, inflate = 1) => {
    if (!boxes.length) return;
    const { positions, count: n } = boxSegments(boxes, inflate);
    if (!n) return;
    objects.push(lines(positions, BOX_STYLES[style].colour));
    if (inflate === 1) count += n;
  };
  const gt = entry.gt ?? [];
  const det = entry.detections ?? [];
  if (show.gt) {
    add(gt.filter((_, i) => !missing.has(i)), "gt");
    const miss = gt.filter((_, i) => missing.has(i));
    add(miss, "missing");
    add(miss, "missing", 1.06); // a second outline: WebGL lines are one pixel wide
  }
  if (show.detections) {
    add(det.filter((_, i) => !spurious.has(i) && !lost.has(i)), "detection");
    for (const [style, set] of [["spurious", spurious], ["lost", lost]]) {
      const picked = det.filter((_, i) => set.has(i));
      add(picked, style);
      add(picked, style, 1.06);
    }
  }
  return { objects, count };
}

// Robust range of a channel over clouds: the 1st and 99th percentiles of a sample (99.8th for height:
// the ground is most of a sweep, and what stands on it is what one looks at).
function channelRange(clouds, channel) {
  const values = new Float32Array(clouds.reduce((n, c) => n + Math.min(c.count, 20000), 0));
  let n = 0;
  for (const cloud of clouds) {
    const i = cloud.index[channel];
    if (i === undefined || !cloud.count) continue;
    const step = Math.max(1, Math.floor(cloud.count / 20000));
    for (let p = 0; p < cloud.count && n < values.length; p += step) {
      const v = cloud.data[p * cloud.stride + i];
      if (Number.isFinite(v)) values[n++] = v;
    }
  }
  if (!n) return [0, 1];
  const sample = values.subarray(0, n).sort(); // a typed array sorts numerically, natively
  const discrete = channel === "ring" || channel === "label";
  const at = (q) => sample[Math.min(sample.length - 1, Math.floor(sample.length * q))];
  const lo = discrete ? sample[0] : at(0.01);
  const hi = discrete ? sample[sample.length - 1] : at(channel === "z" ? 0.998 : 0.99);
  return hi > lo ? [lo, hi] : [lo, lo + 1];
}

function fillColours(out, cloud, mode, range, role) {
  const n = cloud.count;
  const spec = COLOUR_MODES[mode] ?? COLOUR_MODES.height;
  const ci = cloud.index[spec.channel];
  const change = cloud.index.change;
  const [lo, hi] = range;
  const scale = 255 / (hi - lo);
  const data = cloud.data;
  const stride = cloud.stride;
  const byChange = mode === "change";
  const marked = role === "overlay" && change !== undefined;
  for (let p = 0, row = 0, o = 0; p < n; p++, row += stride, o += 3) {
    const ch = change !== undefined ? data[row + change] : 0;
    let colour = null;
    if (byChange || (marked && ch !== 0)) colour = ch === 1 ? ADDED : ch === 2 ? REMOVED : KEPT;
    else if (ci === undefined) colour = KEPT;
    if (colour) {
      out[o] = colour[0];
      out[o + 1] = colour[1];
      out[o + 2] = colour[2];
      continue;
    }
    const v = data[row + ci];
    const t = spec.categorical ? Math.round(categorical(v) * 255) : Math.max(0, Math.min(255, Math.round((v - lo) * scale)));
    out[o] = TURBO[t * 3];
    out[o + 1] = TURBO[t * 3 + 1];
    out[o + 2] = TURBO[t * 3 + 2];
  }
}

// A three.js Points on a cloud's float32 block, in place: position reads x, y, z of each row.
function pointsOf(cloud, material) {
  const geometry = new BufferGeometry();
  const buffer = new InterleavedBuffer(cloud.data, cloud.stride);
  geometry.setAttribute("position", new InterleavedBufferAttribute(buffer, 3, 0));
  const colours = new Uint8Array(cloud.count * 3);
  geometry.setAttribute("color", new BufferAttribute(colours, 3, true));
  geometry.computeBoundingSphere();
  const points = new Points(geometry, material);
  points.frustumCulled = false; // a LiDAR sweep surrounds the camera: culling saves nothing
  return { points, colours, cloud };
}

// The removed points of an original (change == 2) as a cloud of their own, for the overlay.
function removedOf(original) {
  const ci = original.index.change;
  if (ci === undefined) return null;
  let n = 0;
  for (let p = 0; p < original.count; p++) if (original.data[p * original.stride + ci] === 2) n++;
  const data = new Float32Array(n * original.stride);
  let k = 0;
  for (let p = 0; p < original.count; p++) {
    const row = p * original.stride;
    if (original.data[row + ci] === 2) data.set(original.data.subarray(row, row + original.stride), (k++) * original.stride);
  }
  return { ...original, name: `${original.name} (removed)`, count: n, data };
}

// The centre of the first highlighted box (what a finding is about), or null.
function highlighted(boxes) {
  for (const [cloud, key, list] of [["mutant", "missing", "gt"], ["original", "missing", "gt"], ["mutant", "spurious", "detections"], ["original", "lost", "detections"]]) {
    const entry = boxes?.[cloud];
    const index = entry?.[key]?.[0];
    const box = index !== undefined ? entry?.[list]?.[index] : undefined;
    if (finiteBox(box)) return box.slice(0, 3);
  }
  return null;
}

export class PointCloudViewer {
  constructor(container, { onRender } = {}) {
    this.container = container;
    this.onRender = onRender;
    this.renderer = sharedRenderer();
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(BACKGROUND, 1);
    container.append(this.renderer.domElement);
    this.material = shared.points;
    this.material.size = 2;
    this.settings = { layout: "side", colour: "height", bev: false, gt: true, detections: true, pointSize: 2 };
    this.frame = null;
    this.scenes = [];
    this.clouds = [];
    this.layers = [];
    this.stats = { pointsDrawn: 0, boxesDrawn: 0, renders: 0, firstRenderMs: null };
    this.frameStart = null;
    this.pending = false;
    this.perspective = new PerspectiveCamera(55, 1, 0.1, 3000);
    this.perspective.up.set(0, 0, 1);
    this.ortho = new OrthographicCamera(-1, 1, 1, -1, -1000, 1000);
    this.ortho.up.set(1, 0, 0); // bird's-eye: forward (+x) points up the screen, left (+y) to the left
    this.camera = this.perspective;
    this.controls = null;
    this.useControls();
    this.resizeObserver = new ResizeObserver(() => this.resize());
    this.resizeObserver.observe(container);
    this.resize();
  }

  useControls() {
    const target = this.controls?.target?.clone();
    this.controls?.dispose();
    const controls = new OrbitControls(this.camera, this.renderer.domElement);
    controls.enableDamping = false;
    controls.zoomSpeed = 1.2;
    if (this.settings.bev) {
      controls.enableRotate = false;
      controls.screenSpacePanning = true;
      controls.mouseButtons = { LEFT: MOUSE.PAN, MIDDLE: MOUSE.DOLLY, RIGHT: MOUSE.PAN };
    } else {
      controls.screenSpacePanning = false; // pan over the ground plane, as driving-data viewers do
      controls.maxPolarAngle = Math.PI * 0.495;
    }
    if (target) controls.target.copy(target);
    controls.addEventListener("change", () => this.requestRender());
    this.controls = controls;
  }

  resetView() {
    const extent = this.extent ?? 40;
    if (this.settings.bev) {
      this.ortho.position.set(extent * 0.35, 0, 500);
      this.ortho.zoom = 1;
      this.controls.target.set(extent * 0.35, 0, 0);
      this.ortho.lookAt(this.controls.target);
    } else if (this.focus) {
      // a finding: look at the object it is about, from the sensor's side of it
      const [fx, fy, fz] = this.focus;
      const norm = Math.hypot(fx, fy);
      const [dx, dy] = norm > 1 ? [fx / norm, fy / norm] : [1, 0];
      this.perspective.position.set(fx - dx * 22, fy - dy * 22, fz + 12);
      this.controls.target.set(fx, fy, fz);
      this.perspective.lookAt(this.controls.target);
    } else {
      this.perspective.position.set(-12, 0, 10);
      this.controls.target.set(14, 0, 0);
      this.perspective.lookAt(this.controls.target);
    }
    this.updateProjection();
    this.controls.update();
    this.requestRender();
  }

  resize() {
    const width = Math.max(1, this.container.clientWidth);
    const height = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(width, height, true);
    this.updateProjection();
    this.requestRender();
  }

  paneCount() {
    return this.settings.layout === "side" && this.scenes.length === 2 ? 2 : 1;
  }

  updateProjection() {
    const width = Math.max(1, this.container.clientWidth) / this.paneCount();
    const height = Math.max(1, this.container.clientHeight);
    const aspect = width / height;
    this.perspective.aspect = aspect;
    this.perspective.updateProjectionMatrix();
    const half = (this.extent ?? 40) * 0.6;
    // screen up is +x in bird's-eye, so the frustum's vertical extent runs along x
    this.ortho.left = -half * aspect;
    this.ortho.right = half * aspect;
    this.ortho.top = half;
    this.ortho.bottom = -half;
    this.ortho.updateProjectionMatrix();
  }

  // Show a parsed LFZ1 frame. `started`: performance.now() when its transfer began.
  show(frame, { started } = {}) {
    this.clearScenes();
    this.frame = frame;
    this.frameStart = started ?? performance.now();
    this.stats.firstRenderMs = null;
    this.clouds = frame.clouds;
    const original = this.clouds.find((c) => c.name === "original") ?? this.clouds[0];
    const mutant = this.clouds.find((c) => c.name === "mutant") ?? (this.clouds.length > 1 ? this.clouds[1] : null);
    this.pair = mutant && original !== mutant ? { original, mutant } : null;
    // the scene's size (the 95th-percentile range in the xy plane) sizes the bird's-eye view
    const rx = channelRange([original], "x");
    const ry = channelRange([original], "y");
    this.extent = Math.max(20, Math.min(150, Math.max(Math.abs(rx[0]), Math.abs(rx[1]), Math.abs(ry[0]), Math.abs(ry[1]))));
    this.focus = highlighted(frame.boxes);
    this.build();
    this.resetView();
    this.stats.builtMs = performance.now() - this.frameStart;
  }

  clearScenes() {
    for (const scene of this.scenes) {
      scene.traverse((obj) => {
        if (obj.geometry) obj.geometry.dispose();
      });
    }
    this.scenes = [];
    this.layers = [];
    this.boxCounts = [];
  }

  // (Re)build the scenes for the current layout and box settings, then colour the points.
  build() {
    for (const scene of this.scenes) {
      scene.traverse((obj) => {
        if (obj.isLineSegments) obj.geometry.dispose();
      });
    }
    this.scenes = [];
    this.layers = [];
    this.boxCounts = [];
    const show = { gt: this.settings.gt, detections: this.settings.detections };
    const boxes = this.frame?.boxes ?? {};
    const addScene = (layers, boxEntry) => {
      const scene = new Scene();
      for (const layer of layers) if (layer.cloud.count) scene.add(layer.points);
      const { objects, count } = boxObjects(boxEntry, show);
      for (const obj of objects) scene.add(obj);
      this.scenes.push(scene);
      this.layers.push(layers);
      this.boxCounts.push(count);
    };
    this.cache ??= new Map();
    const layerOf = (cloud, role) => {
      const key = `${cloud.name}|${role}`;
      if (!this.cache.has(key) || this.cache.get(key).cloud !== cloud) this.cache.set(key, { ...pointsOf(cloud, this.material), role });
      return this.cache.get(key);
    };
    if (!this.pair) {
      for (const cloud of this.clouds.slice(0, 1)) addScene([layerOf(cloud, "single")], boxes[cloud.name]);
    } else if (this.settings.layout === "side") {
      addScene([layerOf(this.pair.original, "original")], boxes[this.pair.original.name]);
      addScene([layerOf(this.pair.mutant, "mutant")], boxes[this.pair.mutant.name]);
    } else {
      const layers = [layerOf(this.pair.mutant, "overlay")];
      if (this.pair.removed === undefined) this.pair.removed = removedOf(this.pair.original);
      if (this.pair.removed) layers.push(layerOf(this.pair.removed, "overlay"));
      addScene(layers, boxes[this.pair.mutant.name]);
    }
    this.recolour();
    this.updateProjection();
  }

  recolour() {
    const mode = this.settings.colour;
    const spec = COLOUR_MODES[mode] ?? COLOUR_MODES.height;
    this.range = spec.categorical || mode === "change" ? [0, 1] : channelRange(this.clouds, spec.channel);
    for (const layers of this.layers) {
      for (const layer of layers) {
        fillColours(layer.colours, layer.cloud, mode, this.range, layer.role);
        layer.points.geometry.getAttribute("color").needsUpdate = true;
      }
    }
    this.requestRender();
  }

  set(changes) {
    const before = { ...this.settings };
    Object.assign(this.settings, changes);
    if (changes.pointSize !== undefined) this.material.size = Number(changes.pointSize);
    if (changes.bev !== undefined && changes.bev !== before.bev) {
      this.camera = this.settings.bev ? this.ortho : this.perspective;
      this.useControls();
      this.resetView();
    }
    if (["layout", "gt", "detections"].some((k) => changes[k] !== undefined && changes[k] !== before[k])) this.build();
    else if (changes.colour !== undefined && changes.colour !== before.colour) this.recolour();
    this.requestRender();
  }

  requestRender() {
    if (this.pending || this.disposed) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.render();
    });
  }

  render() {
    if (this.disposed) return;
    const renderer = this.renderer;
    const size = renderer.getSize(new Vector3());
    const panes = this.paneCount();
    let points = 0;
    let boxes = 0;
    renderer.setScissorTest(panes > 1);
    renderer.setViewport(0, 0, size.x, size.y);
    renderer.clear();
    for (let i = 0; i < Math.min(panes, this.scenes.length); i++) {
      const width = size.x / panes;
      if (panes > 1) {
        renderer.setViewport(i * width, 0, width, size.y);
        renderer.setScissor(i * width, 0, width, size.y);
      }
      renderer.render(this.scenes[i], this.camera);
      for (const layer of this.layers[i]) points += layer.cloud.count;
      boxes += this.boxCounts[i];
    }
    if (panes > 1) {
      // the divider between the two halves
      renderer.setScissor(size.x / 2 - 1, 0, 2, size.y);
      renderer.setClearColor(0x3a3f4b, 1);
      renderer.clear();
      renderer.setClearColor(BACKGROUND, 1);
      renderer.setScissorTest(false);
    }
    this.stats.renders++;
    this.stats.pointsDrawn = points;
    this.stats.boxesDrawn = boxes;
    if (this.stats.firstRenderMs === null && this.frame) {
      // wait for the GPU: reading one pixel back returns only once the frame is drawn
      const gl = renderer.getContext();
      this.stats.submittedMs = performance.now() - this.frameStart;
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
      this.stats.firstRenderMs = performance.now() - this.frameStart;
    }
    this.onRender?.(this.stats);
  }

  // Draw now and wait for the GPU; returns the milliseconds it took (the cost of one camera move).
  timedRender() {
    const start = performance.now();
    this.render();
    const gl = this.renderer.getContext();
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
    return performance.now() - start;
  }

  dispose() {
    this.disposed = true;
    this.resizeObserver.disconnect();
    this.controls?.dispose();
    this.clearScenes();
    for (const layer of this.cache?.values() ?? []) layer.points.geometry.dispose();
    this.renderer.domElement.remove(); // the context, its materials and programs stay for the next viewer
  }
}

// The viewer with its controls and legend, in `root`. Returns {viewer, show(frame, started), dispose}.
export function viewerPanel(root, { title = "", pair = true } = {}) {
  const stage = h("div", { class: "viewer-stage", testid: "viewer" });
  const tags = h("div", { class: "viewer-tags" });
  const legend = h("div", { class: "viewer-legend", testid: "viewer-legend" });
  const info = h("div", { class: "viewer-info muted", testid: "viewer-info" });
  stage.append(tags);
  const hook = (window.__viewer = { ready: false, pointsDrawn: 0, boxesDrawn: 0, firstRenderMs: null, renders: 0 });
  hook.timedRender = () => viewer.timedRender();
  const viewer = new PointCloudViewer(stage, {
    onRender: (stats) => {
      Object.assign(hook, stats, { ready: true, layout: viewer.settings.layout, bev: viewer.settings.bev, colour: viewer.settings.colour });
    },
  });

  const layout = h("select", { testid: "viewer-layout" }, h("option", { value: "side" }, "side by side"), h("option", { value: "overlay" }, "overlay"));
  const colour = h("select", { testid: "viewer-colour" });
  const size = h("input", { type: "range", min: 1, max: 8, step: 0.5, value: 2, testid: "viewer-point-size" });
  const bev = h("input", { type: "checkbox", testid: "viewer-bev" });
  const gt = h("input", { type: "checkbox", checked: true, testid: "viewer-gt" });
  const det = h("input", { type: "checkbox", checked: true, testid: "viewer-detections" });
  layout.addEventListener("change", () => {
    viewer.set({ layout: layout.value });
    updateLegend();
  });
  colour.addEventListener("change", () => {
    viewer.set({ colour: colour.value });
    updateLegend();
  });
  size.addEventListener("input", () => viewer.set({ pointSize: Number(size.value) }));
  bev.addEventListener("change", () => viewer.set({ bev: bev.checked }));
  gt.addEventListener("change", () => viewer.set({ gt: gt.checked }));
  det.addEventListener("change", () => viewer.set({ detections: det.checked }));
  const layoutLabel = h("label", {}, "Layout ", layout);
  const toolbar = h(
    "div",
    { class: "toolbar viewer-toolbar", testid: "viewer-toolbar" },
    title ? h("strong", {}, title) : null,
    layoutLabel,
    h("label", {}, "Colour ", colour),
    h("label", {}, "Point size ", size),
    h("label", {}, bev, " bird's-eye"),
    h("label", {}, gt, " ground truth"),
    h("label", {}, det, " detections"),
    h("button", { class: "small", testid: "viewer-reset", onclick: () => viewer.resetView() }, "Reset view"),
  );
  root.append(toolbar, h("div", { class: "viewer-wrap" }, stage, legend), info);

  function updateLegend() {
    legend.replaceChildren();
    const frame = viewer.frame;
    if (!frame) return;
    const mode = COLOUR_MODES[viewer.settings.colour];
    legend.append(h("div", { class: "legend-title" }, "Boxes"));
    for (const [key, style] of Object.entries(BOX_STYLES)) {
      if (!viewer.pair && !["gt", "detection"].includes(key)) continue;
      legend.append(h("div", { class: "legend-row", dataset: { key } }, h("span", { class: "swatch line", style: { background: style.colour } }), style.name));
    }
    legend.append(h("div", { class: "legend-row muted" }, "— heading: line to the front face, front face crossed"));
    legend.append(h("div", { class: "legend-title" }, `Points: ${mode.label}`));
    if (viewer.settings.colour === "change") {
      legend.append(
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${ADDED})` } }), "added or moved (mutant only)"),
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${REMOVED})` } }), "removed or moved (original only)"),
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${KEPT})` } }), "in both"),
      );
    } else if (mode.categorical) {
      legend.append(h("div", { class: "legend-row muted" }, "one turbo colour per class id"));
    } else {
      const [lo, hi] = viewer.range ?? [0, 1];
      legend.append(
        h("div", { class: "colourbar", style: { background: turboGradient() } }),
        h("div", { class: "colourbar-labels" }, h("span", {}, lo.toFixed(2)), h("span", {}, hi.toFixed(2))),
      );
    }
    if (viewer.pair && viewer.settings.layout === "overlay" && viewer.settings.colour !== "change") {
      legend.append(
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${ADDED})` } }), "added / moved"),
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${REMOVED})` } }), "removed / moved"),
      );
    }
    tags.replaceChildren();
    const failed = (name) => (frame.boxes[name]?.failed ? " · the system failed here" : "");
    if (viewer.pair && viewer.settings.layout === "side") {
      tags.append(
        h("span", { class: "tag left" }, `original · ${viewer.pair.original.count.toLocaleString()} points${failed(viewer.pair.original.name)}`),
        h("span", { class: "tag right" }, `mutant · ${viewer.pair.mutant.count.toLocaleString()} points${failed(viewer.pair.mutant.name)}`),
      );
    } else if (viewer.pair) {
      tags.append(h("span", { class: "tag left" }, `overlay · mutant ${viewer.pair.mutant.count.toLocaleString()} points + removed`));
    } else if (viewer.clouds[0]) {
      tags.append(h("span", { class: "tag left" }, `${viewer.clouds[0].name} · ${viewer.clouds[0].count.toLocaleString()} points`));
    }
  }

  return {
    viewer,
    show(frame, started) {
      const channels = new Set(frame.clouds.flatMap((c) => c.channels));
      colour.replaceChildren(
        ...Object.entries(COLOUR_MODES)
          .filter(([, m]) => channels.has(m.channel))
          .map(([key, m]) => h("option", { value: key }, m.label)),
      );
      const preferred = channels.has("z") ? "height" : colour.options[0]?.value;
      colour.value = preferred;
      viewer.settings.colour = preferred;
      layoutLabel.hidden = !(pair && frame.clouds.length > 1);
      viewer.show(frame, { started });
      updateLegend();
      const mb = (frame.bytes / 1048576).toFixed(1);
      info.textContent = `${frame.clouds.map((c) => `${c.name}: ${c.count.toLocaleString()} points (${c.channels.join(", ")})`).join(" · ")} · ${mb} MB · left drag: orbit, right drag: pan, wheel: zoom`;
    },
    dispose() {
      viewer.dispose();
      hook.disposed = true;
    },
  };
}
