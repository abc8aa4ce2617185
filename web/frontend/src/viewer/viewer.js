// The point-cloud viewer (three.js): one cloud, or an original and its mutant side by side (one
// camera, so both halves move together) or overlaid with added / removed points coloured from the
// `change` channel; ground truth and detections as wireframe boxes with heading marks (missing
// ground truth and spurious detections highlighted); colour by intensity, height, ring or label
// on turbo; point size; bird's-eye view. The LiDAR frame is z-up (x forward, y left).
//
// A geometric operator's pair can be "aligned": the mutant drawn mapped back by the inverse of the
// operator's transform (a matrix on its objects, nothing recomputed), its points marked from the
// `aligned_change` channel, so only real changes show. Pointing at a box (or clicking it) tells its
// class, score, IoU and partners (from the payload). The settings live in localStorage, so every
// frame and finding opens the way the last one was left.
//
// Rendering is on demand (after a camera move or a setting change), not in a loop. After each
// render window.__viewer says what was drawn: {pointsDrawn, boxesDrawn, firstRenderMs, renders, …};
// each frame shown gets a fresh window.__viewer.
import {
  MOUSE,
  BufferAttribute,
  BufferGeometry,
  Color,
  InterleavedBuffer,
  InterleavedBufferAttribute,
  LineSegments,
  Matrix4,
  OrthographicCamera,
  PerspectiveCamera,
  Points,
  Raycaster,
  RawShaderMaterial,
  Scene,
  Vector2,
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

// The settings a user picks, kept across frames and findings (localStorage).
const SETTINGS_KEY = "lidarfuzz.viewer.settings";
export const DEFAULT_SETTINGS = { layout: "side", colour: "height", bev: false, gt: true, detections: true, pointSize: 2, aligned: true };

export function storedSettings() {
  try {
    const saved = JSON.parse(localStorage.getItem(SETTINGS_KEY) ?? "{}");
    const out = { ...DEFAULT_SETTINGS };
    for (const [key, value] of Object.entries(saved ?? {})) if (key in out && typeof value === typeof out[key]) out[key] = value;
    return out;
  } catch {
    return { ...DEFAULT_SETTINGS };
  }
}

function storeSettings(settings) {
  try {
    const kept = Object.fromEntries(Object.keys(DEFAULT_SETTINGS).map((key) => [key, settings[key]]));
    localStorage.setItem(SETTINGS_KEY, JSON.stringify(kept));
  } catch {
    // storage full or refused (a private window): the settings last as long as the page
  }
}

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

// An object drawn through `matrix` (null: as it is).
function placed(object, matrix) {
  object.matrixAutoUpdate = false;
  if (matrix) object.matrix.copy(matrix);
  else object.matrix.identity();
  object.matrixWorldNeedsUpdate = true;
  return object;
}

function lines(positions, colour) {
  const geometry = new BufferGeometry();
  geometry.setAttribute("position", new BufferAttribute(positions, 3));
  return new LineSegments(geometry, lineMaterial(colour));
}

// Boxes of one cloud: {objects: [LineSegments], count} split by style; `matrix` places them (the
// aligned mutant's inverse transform), null: where they are; `highlightsOnly`: only the boxes the
// finding is about (the original's, in the overlay).
function boxObjects(entry, show, matrix = null, highlightsOnly = false) {
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
    objects.push(placed(lines(positions, BOX_STYLES[style].colour), matrix));
    if (inflate === 1) count += n;
  };
  const gt = entry.gt ?? [];
  const det = entry.detections ?? [];
  if (show.gt) {
    if (!highlightsOnly) add(gt.filter((_, i) => !missing.has(i)), "gt");
    const miss = gt.filter((_, i) => missing.has(i));
    add(miss, "missing");
    add(miss, "missing", 1.06); // a second outline: WebGL lines are one pixel wide
  }
  if (show.detections) {
    if (!highlightsOnly) add(det.filter((_, i) => !spurious.has(i) && !lost.has(i)), "detection");
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

// `changeChannel`: "change" (bit-for-bit) or "aligned_change" (the aligned mutant's).
function fillColours(out, cloud, mode, range, role, changeChannel = "change") {
  const n = cloud.count;
  const spec = COLOUR_MODES[mode] ?? COLOUR_MODES.height;
  const change = cloud.index[changeChannel] ?? cloud.index.change;
  const ci = mode === "change" ? change : cloud.index[spec.channel];
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
function removedOf(original, channel = "change") {
  const ci = original.index[channel];
  if (ci === undefined) return null;
  let n = 0;
  for (let p = 0; p < original.count; p++) if (original.data[p * original.stride + ci] === 2) n++;
  const data = new Float32Array(n * original.stride);
  let k = 0;
  for (let p = 0; p < original.count; p++) {
    const row = p * original.stride;
    if (original.data[row + ci] === 2) data.set(original.data.subarray(row, row + original.stride), (k++) * original.stride);
  }
  return { ...original, name: `${original.name} (removed, ${channel})`, count: n, data };
}

// The first highlighted box (what a finding is about) as {centre, size: its diagonal}, or null;
// `mutantMatrix` maps the mutant's boxes to where they are drawn (aligned: back onto the original).
function highlighted(boxes, mutantMatrix = null) {
  for (const [cloud, key, list] of [["mutant", "missing", "gt"], ["original", "missing", "gt"], ["mutant", "spurious", "detections"], ["original", "lost", "detections"]]) {
    const entry = boxes?.[cloud];
    const index = entry?.[key]?.[0];
    const box = index !== undefined ? entry?.[list]?.[index] : undefined;
    if (!finiteBox(box)) continue;
    const centre = new Vector3(box[0], box[1], box[2]);
    if (cloud === "mutant" && mutantMatrix) centre.applyMatrix4(mutantMatrix);
    return { centre: centre.toArray(), size: Math.hypot(box[3], box[4], box[5]) };
  }
  return null;
}

// Where a ray first enters a box [x, y, z, l, w, h, yaw] (its distance along the ray), or null.
function rayHitsBox(ray, box) {
  const [x, y, z, l, w, hgt, yaw] = box;
  const c = Math.cos(-yaw);
  const s = Math.sin(-yaw);
  const local = (v, shift) => {
    const dx = v.x - (shift ? x : 0);
    const dy = v.y - (shift ? y : 0);
    return [dx * c - dy * s, dx * s + dy * c, v.z - (shift ? z : 0)];
  };
  const o = local(ray.origin, true);
  const d = local(ray.direction, false);
  let near = -Infinity;
  let far = Infinity;
  for (const [k, half] of [[0, l / 2], [1, w / 2], [2, hgt / 2]]) {
    if (Math.abs(d[k]) < 1e-12) {
      if (Math.abs(o[k]) > half) return null;
      continue;
    }
    const a = (-half - o[k]) / d[k];
    const b = (half - o[k]) / d[k];
    near = Math.max(near, Math.min(a, b));
    far = Math.min(far, Math.max(a, b));
  }
  return near <= far && far >= 0 ? Math.max(near, 0) : null;
}

// A box in words: its class, score, IoU and partners in its cloud and in the other (the payload's
// per-box fields), as lines of text. `pick`: {cloud, kind: "gt" | "detection", index}.
export function describeBox(frame, pick) {
  const boxes = frame?.boxes ?? {};
  const entry = boxes[pick.cloud] ?? {};
  const otherName = pick.cloud === "original" ? "mutant" : pick.cloud === "mutant" ? "original" : null;
  const other = otherName ? boxes[otherName] : null;
  const iou = (v) => (v === null || v === undefined ? "" : ` (IoU ${Number(v).toFixed(2)})`);
  const lines = [];
  const where = frame?.clouds?.length > 1 ? ` · ${pick.cloud}` : "";
  if (pick.kind === "gt") {
    const label = entry.gt_labels?.[pick.index] ?? "?";
    lines.push(`Ground truth ${pick.index} · ${label}${where}`);
    const partner = entry.gt_partner?.[pick.index] ?? -1;
    lines.push(partner >= 0
      ? `detected by detection ${partner} · ${entry.labels?.[partner] ?? "?"}${entry.scores?.[partner] !== null && entry.scores?.[partner] !== undefined ? ` · score ${Number(entry.scores[partner]).toFixed(2)}` : ""}${iou(entry.gt_iou?.[pick.index])}`
      : entry.failed ? "no detections: the system failed on this frame" : "not detected (no detection of its class overlaps it)");
    if ((entry.missing ?? []).includes(pick.index)) lines.push(pick.cloud === "original" ? "the finding: the mutant lost this object" : "the finding: this object is missing in the mutant");
    if (other) {
      const there = entry.gt_other?.[pick.index] ?? -1;
      lines.push(there >= 0 ? `in the ${otherName}: ground truth ${there}` : `in the ${otherName}: no such object`);
    }
  } else {
    const label = entry.labels?.[pick.index] ?? "?";
    const score = entry.scores?.[pick.index];
    lines.push(`Detection ${pick.index} · ${label}${score === null || score === undefined ? "" : ` · score ${Number(score).toFixed(2)}`}${where}`);
    const partner = entry.detection_partner?.[pick.index] ?? -1;
    lines.push(partner >= 0 ? `matches ground truth ${partner} · ${entry.gt_labels?.[partner] ?? "?"}${iou(entry.detection_iou?.[pick.index])}` : "matches no ground truth (a false positive here)");
    if ((entry.lost ?? []).includes(pick.index)) lines.push("the finding: the mutant lost this detection");
    if ((entry.spurious ?? []).includes(pick.index)) lines.push("the finding: a spurious detection (nothing in the original maps to it)");
    if (other) {
      const there = entry.detection_other?.[pick.index] ?? -1;
      lines.push(there >= 0 ? `in the ${otherName}: detection ${there}${iou(entry.detection_other_iou?.[pick.index])}` : `in the ${otherName}: no matching detection`);
    }
  }
  return lines;
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
    this.settings = storedSettings();
    this.material.size = this.settings.pointSize;
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
    this.camera = this.settings.bev ? this.ortho : this.perspective;
    this.mutantMatrix = null;
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

  // The view a frame opens with: a finding's object framed (from the sensor's side of it, at a
  // distance that fits its size and some surroundings), otherwise the scene ahead of the sensor.
  resetView() {
    const extent = this.extent ?? 40;
    const reach = this.focus ? Math.max(8, this.focus.size * 3) : 0;
    if (this.settings.bev) {
      const [cx, cy] = this.focus ? this.focus.centre : [extent * 0.35, 0];
      this.ortho.position.set(cx, cy, 500);
      // the frustum's half height is extent × 0.6: zoom so that the object and ~2 of its sizes around it show
      this.ortho.zoom = this.focus ? Math.max(1, (extent * 0.6) / (reach * 1.5)) : 1;
      this.controls.target.set(cx, cy, 0);
      this.ortho.lookAt(this.controls.target);
    } else if (this.focus) {
      const [fx, fy, fz] = this.focus.centre;
      const norm = Math.hypot(fx, fy);
      const [dx, dy] = norm > 1 ? [fx / norm, fy / norm] : [1, 0];
      this.perspective.position.set(fx - dx * reach, fy - dy * reach, fz + reach * 0.55);
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

  // Show a parsed LFZ1 frame. `started`: performance.now() when its transfer began; `keepCamera`:
  // stay where the camera is (the next frame of a log playing), instead of the frame's own view.
  show(frame, { started, keepCamera = false } = {}) {
    this.clearScenes();
    this.disposeCache(frame);
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
    const transform = frame.header?.transform;
    this.transform = Array.isArray(transform) && transform.length === 4 && this.pair ? new Matrix4().set(...transform.flat()) : null;
    this.build();
    if (keepCamera) this.requestRender();
    else this.resetView();
    this.stats.builtMs = performance.now() - this.frameStart;
  }

  // Whether the mutant is drawn mapped back onto the original (a geometric operator's pair).
  get isAligned() {
    return Boolean(this.transform && this.settings.aligned);
  }

  // The layers of clouds no longer shown (a frame replaced by the next): their GPU buffers go.
  disposeCache(next) {
    const keep = new Set(next?.clouds ?? []);
    for (const [key, layer] of this.cache ?? []) {
      if (keep.has(layer.cloud) || (layer.source && keep.has(layer.source))) continue;
      layer.points.geometry.dispose();
      this.cache.delete(key);
    }
  }

  // The camera as it is ({bev, position, target, zoom}), and back (a data set's frames keep it).
  cameraState() {
    return { bev: this.settings.bev, position: this.camera.position.toArray(), target: this.controls.target.toArray(), zoom: this.camera.zoom };
  }

  setCamera(state) {
    if (!state || state.bev !== this.settings.bev) return false;
    this.camera.position.fromArray(state.position);
    this.controls.target.fromArray(state.target);
    this.camera.zoom = state.zoom ?? 1;
    this.camera.lookAt(this.controls.target);
    this.updateProjection();
    this.controls.update();
    this.requestRender();
    return true;
  }

  // The box under a point of the canvas (client pixels): {cloud, kind, index} or null.
  pickBox(clientX, clientY) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const panes = this.paneCount();
    const width = rect.width / panes;
    const pane = Math.min(panes - 1, Math.max(0, Math.floor((clientX - rect.left) / width)));
    const ndc = new Vector2(((clientX - rect.left - pane * width) / width) * 2 - 1, -((clientY - rect.top) / rect.height) * 2 + 1);
    const raycaster = new Raycaster();
    raycaster.setFromCamera(ndc, this.camera);
    let best = null;
    for (const { cloud, kind, index, box, matrix } of this.paneBoxes(pane)) {
      const ray = raycaster.ray.clone();
      if (matrix) ray.applyMatrix4(matrix.clone().invert());
      const t = rayHitsBox(ray, box);
      // the nearest box entered; a box around the camera (t = 0) loses to one in front of it
      if (t !== null && (!best || (t > 0 && (best.t === 0 || t < best.t)))) best = { cloud, kind, index, t };
    }
    return best && { cloud: best.cloud, kind: best.kind, index: best.index };
  }

  // The boxes drawn in a pane: [{cloud, kind, index, box, matrix}].
  paneBoxes(pane) {
    const overlay = this.pair && this.settings.layout !== "side";
    const names = !this.pair ? [this.clouds[0]?.name] : overlay ? [this.pair.mutant.name, this.pair.original.name] : [[this.pair.original.name, this.pair.mutant.name][pane]];
    const out = [];
    for (const name of names) {
      const entry = this.frame?.boxes?.[name];
      if (!entry) continue;
      const matrix = this.pair && name === this.pair.mutant.name ? this.mutantMatrix : null;
      // the overlay draws only the original's highlighted boxes
      const onlyHighlights = overlay && name === this.pair.original.name;
      const gtShown = (i) => !onlyHighlights || (entry.missing ?? []).includes(i);
      const detectionShown = (i) => !onlyHighlights || (entry.lost ?? []).includes(i) || (entry.spurious ?? []).includes(i);
      if (this.settings.gt) (entry.gt ?? []).forEach((box, index) => finiteBox(box) && gtShown(index) && out.push({ cloud: name, kind: "gt", index, box, matrix }));
      if (this.settings.detections) (entry.detections ?? []).forEach((box, index) => finiteBox(box) && detectionShown(index) && out.push({ cloud: name, kind: "detection", index, box, matrix }));
    }
    return out;
  }

  // Where a box's centre is drawn, in client pixels (tests point at boxes with it), or null.
  boxScreenPoint(cloud, kind, index) {
    const panes = this.paneCount();
    for (let pane = 0; pane < panes; pane++) {
      const hit = this.paneBoxes(pane).find((b) => b.cloud === cloud && b.kind === kind && b.index === index);
      if (!hit) continue;
      const rect = this.renderer.domElement.getBoundingClientRect();
      const p = new Vector3(hit.box[0], hit.box[1], hit.box[2]);
      if (hit.matrix) p.applyMatrix4(hit.matrix);
      p.project(this.camera);
      const width = rect.width / panes;
      return { x: rect.left + pane * width + ((p.x + 1) / 2) * width, y: rect.top + ((1 - p.y) / 2) * rect.height };
    }
    return null;
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
    this.mutantMatrix = this.isAligned ? this.transform.clone().invert() : null;
    this.focus = highlighted(boxes, this.mutantMatrix);
    const addScene = (layers, boxEntry, matrix = null) => {
      const scene = new Scene();
      for (const layer of layers) if (layer.cloud.count) scene.add(placed(layer.points, layer.role === "removed" ? null : matrix));
      const { objects, count } = boxObjects(boxEntry, show, matrix);
      for (const obj of objects) scene.add(obj);
      this.scenes.push(scene);
      this.layers.push(layers);
      this.boxCounts.push(count);
    };
    this.cache ??= new Map();
    const layerOf = (cloud, role) => {
      const key = `${cloud.name}|${role}`;
      if (!this.cache.has(key) || this.cache.get(key).cloud !== cloud) {
        this.cache.get(key)?.points.geometry.dispose();
        this.cache.set(key, { ...pointsOf(cloud, this.material), role, source: role === "removed" ? this.pair?.original : undefined });
      }
      return this.cache.get(key);
    };
    if (!this.pair) {
      for (const cloud of this.clouds.slice(0, 1)) addScene([layerOf(cloud, "single")], boxes[cloud.name]);
    } else if (this.settings.layout === "side") {
      addScene([layerOf(this.pair.original, "original")], boxes[this.pair.original.name]);
      addScene([layerOf(this.pair.mutant, "mutant")], boxes[this.pair.mutant.name], this.mutantMatrix);
    } else {
      // the mutant, and the original's points it does not have (drawn where they are)
      const channel = this.isAligned ? "aligned_change" : "change";
      const layers = [layerOf(this.pair.mutant, "overlay")];
      this.pair.removed ??= {};
      if (this.pair.removed[channel] === undefined) this.pair.removed[channel] = removedOf(this.pair.original, channel);
      const removed = this.pair.removed[channel];
      if (removed) layers.push({ ...layerOf(removed, "removed"), source: this.pair.original });
      addScene(layers, boxes[this.pair.mutant.name], this.mutantMatrix);
      // and what the finding is about on the original (the objects the mutant lost)
      const { objects, count } = boxObjects(boxes[this.pair.original.name], show, null, true);
      for (const obj of objects) this.scenes[0].add(placed(obj, null));
      this.boxCounts[0] += count;
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
        const role = layer.role === "removed" ? "overlay" : layer.role;
        fillColours(layer.colours, layer.cloud, mode, this.range, role, this.isAligned ? "aligned_change" : "change");
        layer.points.geometry.getAttribute("color").needsUpdate = true;
      }
    }
    this.requestRender();
  }

  set(changes) {
    const before = { ...this.settings };
    Object.assign(this.settings, changes);
    if (changes.pointSize !== undefined) this.material.size = Number(changes.pointSize);
    const changed = (key) => changes[key] !== undefined && changes[key] !== before[key];
    if (["layout", "gt", "detections", "aligned"].some(changed)) this.build();
    else if (changed("colour")) this.recolour();
    if (changed("bev")) {
      this.camera = this.settings.bev ? this.ortho : this.perspective;
      this.useControls();
      this.resetView();
    }
    storeSettings(this.settings);
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

// Where the camera of a data set's frames is kept (sessionStorage), so that the next frame opens as
// the last was left; a finding's frames open framed on its object instead.
function keptCamera(key) {
  try {
    return key ? JSON.parse(sessionStorage.getItem(`lidarfuzz.viewer.camera.${key}`) ?? "null") : null;
  } catch {
    return null;
  }
}

function keepCamera(key, state) {
  try {
    if (key) sessionStorage.setItem(`lidarfuzz.viewer.camera.${key}`, JSON.stringify(state));
  } catch {
    // refused: the camera is not kept
  }
}

// The viewer with its controls and legend, in `root`. Returns {viewer, show(frame, started, options),
// dispose}. `cameraKey`: keep the camera across frames under that key (a data set's name).
export function viewerPanel(root, { title = "", pair = true, cameraKey = null } = {}) {
  const stage = h("div", { class: "viewer-stage", testid: "viewer" });
  const tags = h("div", { class: "viewer-tags" });
  const legend = h("div", { class: "viewer-legend", testid: "viewer-legend" });
  const info = h("div", { class: "viewer-info muted", testid: "viewer-info" });
  const toolError = h("div", { class: "notice notice-warning viewer-tool-error", testid: "viewer-tool-error", role: "status", hidden: true });
  const tooltip = h("div", { class: "viewer-tooltip", testid: "viewer-tooltip", hidden: true });
  const boxInfo = h("div", { class: "viewer-box-info", testid: "viewer-box-info", hidden: true });
  stage.append(tags, tooltip, boxInfo);
  // each frame shown gets a fresh hook (so a test or a benchmark can wait for the next frame's figures)
  let hook = null;
  const freshHook = () => {
    hook = window.__viewer = { ready: false, pointsDrawn: 0, boxesDrawn: 0, firstRenderMs: null, renders: 0 };
    hook.timedRender = () => viewer.timedRender();
    hook.boxAt = (cloud, kind, index) => viewer.boxScreenPoint(cloud, kind, index);
    hook.pick = (x, y) => viewer.pickBox(x, y);
    hook.camera = () => viewer.cameraState();
    hook.focus = () => viewer.focus;
    return hook;
  };
  freshHook();
  const viewer = new PointCloudViewer(stage, {
    onRender: (stats) => {
      Object.assign(hook, stats, { ready: true, layout: viewer.settings.layout, bev: viewer.settings.bev, colour: viewer.settings.colour, aligned: viewer.isAligned });
    },
  });
  const settings = viewer.settings;

  const layout = h("select", { testid: "viewer-layout" }, h("option", { value: "side" }, "side by side"), h("option", { value: "overlay" }, "overlay"));
  layout.value = settings.layout;
  const colour = h("select", { testid: "viewer-colour" });
  const size = h("input", { type: "range", min: 1, max: 8, step: 0.5, value: settings.pointSize, testid: "viewer-point-size" });
  const bev = h("input", { type: "checkbox", checked: settings.bev, testid: "viewer-bev" });
  const gt = h("input", { type: "checkbox", checked: settings.gt, testid: "viewer-gt" });
  const det = h("input", { type: "checkbox", checked: settings.detections, testid: "viewer-detections" });
  const aligned = h("input", { type: "checkbox", checked: settings.aligned, testid: "viewer-aligned" });
  const changed = (changes) => {
    viewer.set(changes);
    hideBoxInfo();
    updateLegend();
  };
  layout.addEventListener("change", () => changed({ layout: layout.value }));
  colour.addEventListener("change", () => changed({ colour: colour.value }));
  size.addEventListener("input", () => viewer.set({ pointSize: Number(size.value) }));
  bev.addEventListener("change", () => changed({ bev: bev.checked }));
  gt.addEventListener("change", () => changed({ gt: gt.checked }));
  det.addEventListener("change", () => changed({ detections: det.checked }));
  aligned.addEventListener("change", () => changed({ aligned: aligned.checked }));
  const layoutLabel = h("label", {}, "Layout ", layout);
  const alignedLabel = h("label", { title: "the mutant mapped back by the inverse of the operator's transform: only real changes show" }, aligned, " aligned");
  const toolbar = h(
    "div",
    { class: "toolbar viewer-toolbar", testid: "viewer-toolbar" },
    title ? h("strong", { testid: "viewer-title" }, title) : null,
    layoutLabel,
    alignedLabel,
    h("label", {}, "Colour ", colour),
    h("label", {}, "Point size ", size),
    h("label", {}, bev, " bird's-eye"),
    h("label", {}, gt, " ground truth"),
    h("label", {}, det, " detections"),
    h("button", { class: "small", testid: "viewer-reset", onclick: () => viewer.resetView() }, "Reset view"),
  );
  root.append(toolbar, toolError, h("div", { class: "viewer-wrap" }, stage, legend), info);

  // pointing at a box: a tooltip by the pointer; clicking one: its facts pinned in the corner
  const canvas = viewer.renderer.domElement;
  let hoverQueued = null;
  const boxText = (pick) => describeBox(viewer.frame, pick);
  function hideBoxInfo() {
    boxInfo.hidden = true;
    tooltip.hidden = true;
  }
  const onMove = (event) => {
    if (event.buttons) {
      tooltip.hidden = true;
      return;
    }
    const queued = !hoverQueued;
    hoverQueued = event;
    if (!queued) return;
    requestAnimationFrame(() => {
      const last = hoverQueued;
      hoverQueued = null;
      if (!last || !viewer.frame || viewer.disposed) return;
      const pick = viewer.pickBox(last.clientX, last.clientY);
      if (!pick) {
        tooltip.hidden = true;
        return;
      }
      const rect = stage.getBoundingClientRect();
      tooltip.replaceChildren(...boxText(pick).map((line) => h("div", {}, line)));
      tooltip.style.left = `${last.clientX - rect.left + 14}px`;
      tooltip.style.top = `${last.clientY - rect.top + 14}px`;
      tooltip.hidden = false;
    });
  };
  let downAt = null;
  const onDown = (event) => (downAt = [event.clientX, event.clientY]);
  const onUp = (event) => {
    // a click, not the end of a drag
    if (!downAt || Math.hypot(event.clientX - downAt[0], event.clientY - downAt[1]) > 4 || !viewer.frame) return;
    const pick = viewer.pickBox(event.clientX, event.clientY);
    if (!pick) {
      boxInfo.hidden = true;
      return;
    }
    boxInfo.dataset.cloud = pick.cloud;
    boxInfo.dataset.kind = pick.kind;
    boxInfo.dataset.index = String(pick.index);
    boxInfo.replaceChildren(...boxText(pick).map((line, i) => h(i ? "div" : "strong", {}, line)));
    boxInfo.hidden = false;
  };
  const onLeave = () => (tooltip.hidden = true);
  canvas.addEventListener("pointermove", onMove);
  canvas.addEventListener("pointerdown", onDown);
  canvas.addEventListener("pointerup", onUp);
  canvas.addEventListener("pointerleave", onLeave);
  const saveCamera = () => cameraKey && viewer.frame && keepCamera(cameraKey, viewer.cameraState());

  function updateLegend() {
    legend.replaceChildren();
    const frame = viewer.frame;
    if (!frame) return;
    const mode = COLOUR_MODES[viewer.settings.colour] ?? COLOUR_MODES.height;
    legend.append(h("div", { class: "legend-title" }, "Boxes"));
    for (const [key, style] of Object.entries(BOX_STYLES)) {
      if (!viewer.pair && !["gt", "detection"].includes(key)) continue;
      legend.append(h("div", { class: "legend-row", dataset: { key } }, h("span", { class: "swatch line", style: { background: style.colour } }), style.name));
    }
    legend.append(h("div", { class: "legend-row muted" }, "— heading: line to the front face, front face crossed"));
    legend.append(h("div", { class: "legend-row muted" }, "point at a box for its class, score and IoU; click to pin"));
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
        h("div", { class: "colourbar", testid: "viewer-colourbar", style: { background: turboGradient() } }),
        h("div", { class: "colourbar-labels" }, h("span", {}, lo.toFixed(2)), h("span", {}, hi.toFixed(2))),
      );
    }
    if (viewer.pair && viewer.settings.layout === "overlay" && viewer.settings.colour !== "change") {
      legend.append(
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${ADDED})` } }), "added / moved"),
        h("div", { class: "legend-row" }, h("span", { class: "swatch", style: { background: `rgb(${REMOVED})` } }), "removed / moved"),
      );
    }
    if (viewer.isAligned) legend.append(h("div", { class: "legend-row muted", testid: "viewer-aligned-note" }, "aligned: the mutant mapped back by the inverse transform; a change is a point that moved more than 1 mm"));
    tags.replaceChildren();
    // the system's failure, or lidarfuzz's own error (a relation or the operator raised: the system's output is drawn)
    const failed = (name) => (frame.boxes[name]?.failed ? " · the system failed here" : frame.boxes[name]?.tool_error ? " · lidarfuzz's error, see above" : "");
    if (viewer.pair && viewer.settings.layout === "side") {
      tags.append(
        h("span", { class: "tag left" }, `original · ${viewer.pair.original.count.toLocaleString()} points${failed(viewer.pair.original.name)}`),
        h("span", { class: "tag right" }, `mutant${viewer.isAligned ? " (aligned)" : ""} · ${viewer.pair.mutant.count.toLocaleString()} points${failed(viewer.pair.mutant.name)}`),
      );
    } else if (viewer.pair) {
      tags.append(h("span", { class: "tag left" }, `overlay · mutant${viewer.isAligned ? " (aligned)" : ""} ${viewer.pair.mutant.count.toLocaleString()} points + removed${failed(viewer.pair.mutant.name)}`));
    } else if (viewer.clouds[0]) {
      tags.append(h("span", { class: "tag left" }, `${viewer.clouds[0].name} · ${viewer.clouds[0].count.toLocaleString()} points`));
    }
  }

  return {
    viewer,
    // `keepCamera`: the camera stays where it is (a log playing); otherwise the frame's own view, or
    // the data set's kept camera.
    show(frame, started, { keepCamera: stay = false } = {}) {
      if (viewer.frame) freshHook();
      const channels = new Set(frame.clouds.flatMap((c) => c.channels));
      colour.replaceChildren(
        ...Object.entries(COLOUR_MODES)
          .filter(([, m]) => channels.has(m.channel))
          .map(([key, m]) => h("option", { value: key }, m.label)),
      );
      const kept = settings.colour && channels.has(COLOUR_MODES[settings.colour]?.channel) ? settings.colour : null;
      const preferred = kept ?? (channels.has("z") ? "height" : colour.options[0]?.value);
      colour.value = preferred;
      viewer.settings.colour = preferred;
      layoutLabel.hidden = !(pair && frame.clouds.length > 1);
      alignedLabel.hidden = !(pair && frame.clouds.length > 1 && Array.isArray(frame.header?.transform));
      const camera = stay ? null : keptCamera(cameraKey);
      viewer.show(frame, { started, keepCamera: stay || Boolean(camera) });
      if (camera && !viewer.setCamera(camera)) viewer.resetView();
      hideBoxInfo();
      const errorText = frame.header?.tool_error;
      toolError.textContent = errorText ? `${errorText} — this is lidarfuzz's error, not the system's: its detections are drawn.` : "";
      toolError.hidden = !errorText;
      updateLegend();
      const mb = (frame.bytes / 1048576).toFixed(1);
      info.textContent = `${frame.clouds.map((c) => `${c.name}: ${c.count.toLocaleString()} points (${c.channels.join(", ")})`).join(" · ")} · ${mb} MB · left drag: orbit, right drag: pan, wheel: zoom`;
    },
    dispose() {
      saveCamera();
      canvas.removeEventListener("pointermove", onMove);
      canvas.removeEventListener("pointerdown", onDown);
      canvas.removeEventListener("pointerup", onUp);
      canvas.removeEventListener("pointerleave", onLeave);
      viewer.dispose();
      hook.disposed = true;
    },
  };
}
