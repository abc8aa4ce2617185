// One finding in the viewer: its original and mutant frames, boxes and what it violated.
import { api, fetchBinary } from "../api.js";
import { clear, formatNumber, h, notice } from "../dom.js";

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
  if (taskId) head.append(h("a", { class: "button", href: `#/tasks/${taskId}/findings`, testid: "back-to-findings" }, "All findings"));
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
  let panel = null;
  try {
    ({ panel } = await loadViewer(stage, `/api/findings/${id}/frames`, { pair: true }));
  } catch (exc) {
    clear(stage).append(notice("error", `Could not show the frames: ${exc.message}`));
  }
  return () => panel?.dispose();
}
