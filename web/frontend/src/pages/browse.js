// Visualisation: pick a data set, then a frame, and view it (the thesis's visualisation page).
import { api, listOf } from "../api.js";
import { clear, go, h, notice } from "../dom.js";
import { loadViewer } from "./finding.js";

async function frameIds(name) {
  const reply = await api(`/api/datasets/${encodeURIComponent(name)}/frames`);
  return listOf(reply, "frames", "frame_ids", "ids").map((f) => (typeof f === "object" ? (f.id ?? f.frame_id ?? f.name) : String(f)));
}

function datasetPicker(datasets, selected) {
  const select = h(
    "select",
    { testid: "browse-dataset" },
    h("option", { value: "" }, "pick a data set"),
    datasets.map((d) => h("option", { value: d.name, selected: d.name === selected }, d.name)),
  );
  select.addEventListener("change", () => select.value && go(`/browse/${encodeURIComponent(select.value)}`));
  return select;
}

export async function browsePage(root, name) {
  const datasets = listOf(await api("/api/datasets"), "datasets");
  root.append(h("div", { class: "page-head" }, h("h1", {}, "Visualisation"), h("span", { class: "spacer" }), h("label", {}, "Data set ", datasetPicker(datasets, name))));
  if (!name) {
    root.append(h("p", { class: "muted" }, datasets.length ? "Pick a data set to browse its frames." : "No data sets yet."));
    return;
  }
  const ids = await frameIds(name);
  const list = h(
    "ul",
    { class: "frame-list", testid: "frame-list" },
    ids.map((id) => h("li", {}, h("a", { href: `#/browse/${encodeURIComponent(name)}/${encodeURIComponent(id)}`, testid: "frame-link" }, id))),
  );
  root.append(h("p", { class: "muted" }, `${ids.length} frames`), list);
}

export async function frameViewerPage(root, name, frameId) {
  const datasets = listOf(await api("/api/datasets"), "datasets");
  const ids = await frameIds(name).catch(() => []);
  const at = ids.indexOf(frameId);
  const frameSelect = h("select", { testid: "browse-frame" }, ids.map((id) => h("option", { value: id, selected: id === frameId }, id)));
  const open = (id) => go(`/browse/${encodeURIComponent(name)}/${encodeURIComponent(id)}`);
  frameSelect.addEventListener("change", () => open(frameSelect.value));
  const prev = h("button", { disabled: at <= 0, testid: "frame-prev", onclick: () => open(ids[at - 1]) }, "← Previous");
  const next = h("button", { disabled: at < 0 || at >= ids.length - 1, testid: "frame-next", onclick: () => open(ids[at + 1]) }, "Next →");
  const stage = h("div", { class: "viewer-page" });
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, "Visualisation"),
      h("span", { class: "spacer" }),
      h("label", {}, "Data set ", datasetPicker(datasets, name)),
      h("label", {}, "Frame ", frameSelect),
      prev,
      next,
    ),
    stage,
  );
  let panel = null;
  try {
    ({ panel } = await loadViewer(stage, `/api/datasets/${encodeURIComponent(name)}/frames/${encodeURIComponent(frameId)}`, { pair: false, title: `${name} / ${frameId}` }));
  } catch (exc) {
    clear(stage).append(notice("error", `Could not show frame ${frameId}: ${exc.message}`));
  }
  return () => panel?.dispose();
}
