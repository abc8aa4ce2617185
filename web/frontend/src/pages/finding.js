// One finding in the viewer: its original and mutant frames, boxes and what it violated; a camera
// task's finding as its picture and steering figures; previous / next finding of the task (the
// buttons, or the ← / → keys).
import { api, fetchBinary, fetchBlob } from "../api.js";
import { clear, formatNumber, go, h, notice } from "../dom.js";

// The viewer's code and the frame are fetched at once; `window.__viewer.timings` says where the
// time to the first render went (ms from the start): code loaded, frame received, parsed, WebGL up.
export async function loadViewer(root, url, options) {
  const started = performance.now();
  const timings = {};
  const since = () => Math.round((performance.now() - started) * 10) / 10;
  const arriving = fetchBinary(url).then((b) => ((timings.frame = since()), b));
  const module = await import("../viewer/viewer.js");
  timings.code = since();
  // WebGL up and its shaders compiled while the frame is still arriving
  const panel = module.viewerPanel(root, options);
  timings.webgl = since();
  let frame;
  try {
    frame = module.parseFrame(await arriving);
  } catch (exc) {
    panel.dispose();
    throw exc;
  }
  timings.parsed = since();
  panel.show(frame, started);
  window.__viewer.timings = timings;
  return { panel, frame };
}

// Eq. 3's verdict on the finding's transformation, in words (lidarfuzz run prints the same).
export function eq3Verdict(code, epsilon) {
  const eps = epsilon === null || epsilon === undefined ? "ε" : `ε = ${epsilon}`;
  if (code === "kept") return `kept at ${eps}: |MSE_t − MSE_orig| ≤ ε`;
  if (code === "filtered_out") return `filtered out at ${eps}: |MSE_t − MSE_orig| > ε`;
  if (code === "not_filtered") return "not filtered (a composite transformation)";
  return "—";
}

const fixed = (value, digits = 4) => (value === null || value === undefined ? "—" : Number(value).toFixed(digits));
const signed = (value) => (value === null || value === undefined ? "—" : `${value >= 0 ? "+" : ""}${Number(value).toFixed(4)}`);

// A camera task's finding: the report's picture (original | transformed, steering arrows) and the
// figures Eq. 2 and Eq. 3 judged, instead of the point-cloud viewer.
function cameraFinding(stage, finding) {
  const s = finding.steering ?? {};
  const image = h("img", { class: "pair-picture", alt: `finding ${finding.id}: original and transformed image`, testid: "finding-picture" });
  const status = h("p", { class: "muted" }, "drawing the picture…");
  fetchBlob(finding.picture)
    .then((blob) => {
      image.src = URL.createObjectURL(blob);
      status.remove();
    })
    .catch((exc) => status.replaceWith(notice("error", `No picture: ${exc.message}`)));
  const params = finding.operator_params ?? {};
  const steps = Array.isArray(params.steps) ? params.steps : null;
  const paramText = steps
    ? steps.map((step) => `${step.operator}(${Object.entries(step.params ?? {}).map(([k, v]) => `${k}=${typeof v === "number" ? Number(v.toFixed(4)) : JSON.stringify(v)}`).join(", ")})`).join(" → ")
    : Object.entries(params).map(([k, v]) => `${k} = ${typeof v === "number" ? Number(v.toFixed(4)) : JSON.stringify(v)}`).join("; ");
  const over = s.squared_error !== null && s.threshold !== null && s.squared_error > s.threshold;
  const rows = [
    ["Label", signed(s.label), "label"],
    ["Prediction, original image", signed(s.original_prediction), "original"],
    ["Prediction, transformed image", signed(s.prediction), "transformed"],
    ["Squared error (label − prediction)²", fixed(s.squared_error), "squared-error"],
    ["λ · MSE_orig", s.threshold === null ? "—" : `${s.lambda} × ${fixed(s.mse_orig)} = ${fixed(s.threshold)}`, "threshold"],
    ["Eq. 2", s.squared_error === null ? "—" : over ? "violated: the squared error exceeds λ · MSE_orig" : "holds", "eq2"],
    ["MSE_t of the transformation", s.mse_t === null ? "— (not complete)" : `${fixed(s.mse_t)} (MSE_t − MSE_orig = ${signed(s.difference)})`, "mse-t"],
    ["Eq. 3", eq3Verdict(s.eq3, s.epsilon), "eq3"],
    [finding.chain ? "Transformations (the search's chain)" : "Transformation", finding.chain ? "guided search" : finding.label ?? finding.operator, "operator"],
    ["Parameters", paramText || "—", "params"],
  ];
  stage.append(
    h("div", { class: "camera-finding" }, status, image),
    h(
      "table",
      { class: "table steering-figures", testid: "steering-figures" },
      h("tbody", {}, rows.map(([k, v, key]) => h("tr", { dataset: { figure: key } }, h("th", {}, k), h("td", { class: "num" }, v)))),
    ),
    h("p", { class: "hint" }, "Arrows from the bottom centre: the label (green), the prediction on the original (blue) and on the transformed image (red); straight up is 0, left is positive."),
  );
  return () => image.src && URL.revokeObjectURL(image.src);
}

export async function findingViewerPage(root, id, params) {
  const task = params.get("task");
  const head = h("div", { class: "page-head" }, h("h1", {}, `Finding #${id}`), h("span", { class: "spacer" }));
  const facts = h("dl", { class: "facts", testid: "finding-facts" });
  const message = h("div");
  const stage = h("div", { class: "viewer-page" });
  root.append(head, message, facts, stage);
  const finding = await api(`/api/findings/${id}`).catch((exc) => {
    message.append(notice("error", exc.message));
    return null;
  });
  const taskId = task ?? finding?.task_id;
  const suffix = task ? `?task=${task}` : "";
  if (finding) {
    head.append(
      finding.previous ? h("a", { class: "button", href: `#/findings/${finding.previous}${suffix}`, testid: "finding-prev" }, "← Previous") : h("button", { disabled: true, testid: "finding-prev" }, "← Previous"),
      finding.next ? h("a", { class: "button", href: `#/findings/${finding.next}${suffix}`, testid: "finding-next" }, "Next →") : h("button", { disabled: true, testid: "finding-next" }, "Next →"),
    );
  }
  if (taskId) head.append(h("a", { class: "button", href: `#/tasks/${taskId}/findings`, testid: "back-to-findings" }, "All findings"));
  const stopKeys = finding ? arrowKeys((step) => {
    const to = step < 0 ? finding.previous : finding.next;
    if (to) go(`/findings/${to}${suffix}`);
  }) : () => {};
  if (finding) {
    const replay = finding.replay ?? {};
    const rows = [
      ["Relation / kind", finding.relation ?? finding.kind],
      ["Operator", [finding.operator ?? replay.operator?.name, finding.severity ? `severity ${finding.severity}` : ""].filter(Boolean).join(", ")],
      ["Frame", finding.frame ?? finding.frame_id ?? replay.frame],
      ["Class", finding.cls ?? finding.class],
      ["Magnitude", formatNumber(finding.magnitude)],
      ["Message", finding.message],
      ["Replay", `lidarfuzz replay ${id}`],
    ];
    facts.append(...rows.filter(([, v]) => v !== undefined && v !== null && v !== "").flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, String(v))]));
  }
  if (finding?.modality === "camera") {
    const release = cameraFinding(stage, finding);
    return () => {
      stopKeys();
      release();
    };
  }
  let panel = null;
  try {
    ({ panel } = await loadViewer(stage, `/api/findings/${id}/frames`, { pair: true }));
  } catch (exc) {
    clear(stage).append(notice("error", `Could not show the frames: ${exc.message}`));
  }
  return () => {
    stopKeys();
    panel?.dispose();
  };
}

// Whether the arrow keys already mean something in `el` (a text field, a list, a slider); a
// checkbox or a button leaves them to the page.
export function usesArrows(el) {
  if (!el || el.isContentEditable) return Boolean(el?.isContentEditable);
  if (el.tagName === "SELECT" || el.tagName === "TEXTAREA") return true;
  return el.tagName === "INPUT" && !["checkbox", "button", "submit", "reset"].includes(el.type);
}

// ← / → (without a modifier, and not while typing in a field) call `step(-1)` / `step(1)`; returns
// the function that stops listening.
export function arrowKeys(step) {
  const onKey = (event) => {
    if (event.altKey || event.ctrlKey || event.metaKey || event.shiftKey || usesArrows(event.target)) return;
    if (event.key !== "ArrowLeft" && event.key !== "ArrowRight") return;
    event.preventDefault();
    step(event.key === "ArrowLeft" ? -1 : 1);
  };
  window.addEventListener("keydown", onKey);
  return () => window.removeEventListener("keydown", onKey);
}
