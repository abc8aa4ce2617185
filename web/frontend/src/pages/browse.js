// Visualisation: pick a data set, then a frame, and view it (the thesis's visualisation page); a
// camera data set as a grid of its images with their steering labels, a frame as its image.
import { api, listOf, query, withToken } from "../api.js";
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

const THUMBS = 60;
const steeringText = (value) => (value === null || value === undefined ? "unlabelled" : `${value >= 0 ? "+" : ""}${Number(value).toFixed(4)}`);
const isCamera = (datasets, name) => datasets.find((d) => d.name === name)?.modality === "camera";

// A camera data set: its images as thumbnails with their labels, a page at a time.
async function imageGrid(root, name, params) {
  const offset = Math.max(0, Number(params?.get("offset") ?? 0) || 0);
  const reply = await api(`/api/datasets/${encodeURIComponent(name)}/images${query({ limit: THUMBS, offset })}`);
  const items = listOf(reply, "images");
  const grid = h(
    "div",
    { class: "image-grid", testid: "image-grid" },
    items.map((item) =>
      h(
        "a",
        { class: "thumb", href: `#/browse/${encodeURIComponent(name)}/${encodeURIComponent(item.frame_id)}`, testid: "frame-link", dataset: { frameId: item.frame_id } },
        h("img", { src: withToken(`${item.image}?width=240`), alt: `${item.frame_id}: steering ${steeringText(item.steering)}`, loading: "lazy", testid: "thumb-image" }),
        h("span", { class: "thumb-caption" }, h("strong", {}, item.frame_id), " ", h("span", { testid: "thumb-steering" }, steeringText(item.steering))),
      ),
    ),
  );
  const pager = h("div", { class: "pager" });
  const page = (at) => `#/browse/${encodeURIComponent(name)}${query({ offset: at || undefined })}`;
  if (offset > 0) pager.append(h("a", { class: "button", href: page(Math.max(0, offset - THUMBS)) }, "← Previous"));
  if (offset + items.length < reply.total) pager.append(h("a", { class: "button", href: page(offset + THUMBS) }, "Next →"));
  const shown = items.length ? `images ${offset + 1}–${offset + items.length} of ${reply.total}` : `${reply.total} images`;
  root.append(h("p", { class: "muted" }, `${shown}; steering labels in the data set's units (left positive), the arrow drawn from the bottom centre.`), grid, pager);
}

export async function browsePage(root, name, params) {
  const datasets = listOf(await api("/api/datasets"), "datasets");
  root.append(h("div", { class: "page-head" }, h("h1", {}, "Visualisation"), h("span", { class: "spacer" }), h("label", {}, "Data set ", datasetPicker(datasets, name))));
  if (!name) {
    root.append(h("p", { class: "muted" }, datasets.length ? "Pick a data set to browse its frames." : "No data sets yet."));
    return;
  }
  if (isCamera(datasets, name)) return imageGrid(root, name, params);
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
  if (isCamera(datasets, name)) {
    const item = await api(`/api/datasets/${encodeURIComponent(name)}/images${query({ limit: 1, offset: Math.max(0, at) })}`).then((r) => listOf(r, "images")[0]).catch(() => null);
    // a small image is drawn larger on the server (its arrow and text stay sharp), a large one as it is
    const width = item && item.width < 640 ? "?width=640" : "";
    stage.append(
      h("img", { class: "frame-image", src: withToken(`/api/datasets/${encodeURIComponent(name)}/frames/${encodeURIComponent(frameId)}/image.png${width}`), alt: `${name} / ${frameId}`, testid: "frame-image" }),
      item
        ? h("p", { class: "muted", testid: "frame-facts" }, `${frameId}: steering label ${steeringText(item.steering)} (green arrow; straight up is 0, left is positive), ${item.width} × ${item.height} pixels.`)
        : null,
    );
    return null;
  }
  let panel = null;
  try {
    ({ panel } = await loadViewer(stage, `/api/datasets/${encodeURIComponent(name)}/frames/${encodeURIComponent(frameId)}`, { pair: false, title: `${name} / ${frameId}` }));
  } catch (exc) {
    clear(stage).append(notice("error", `Could not show frame ${frameId}: ${exc.message}`));
  }
  return () => panel?.dispose();
}
