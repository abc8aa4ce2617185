// Visualisation: pick a data set, then a frame, and view it (the thesis's visualisation page); a
// camera data set as a grid of its images with their steering labels, a frame as its image.
import { api, fetchBinary, listOf, query, withToken } from "../api.js";
import { clear, go, h, notice } from "../dom.js";
import { loadViewer, usesArrows } from "./finding.js";
import { uploadedNotice, uploadWidget } from "./upload.js";

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
    root.append(h("p", { class: "muted" }, datasets.length ? "Pick a data set to browse its frames, or upload one to view it." : "No data sets yet: upload one to view it."));
    root.append(uploadWidget({ title: "Upload a data set to view", onUploaded: (ds) => go(`/browse/${encodeURIComponent(ds.name)}?uploaded=1`) }));
    return;
  }
  if (params?.get("uploaded")) root.append((await uploadedNotice(name)) ?? "");
  if (isCamera(datasets, name)) return imageGrid(root, name, params);
  const ids = await frameIds(name);
  const list = h(
    "ul",
    { class: "frame-list", testid: "frame-list" },
    ids.map((id) => h("li", {}, h("a", { href: `#/browse/${encodeURIComponent(name)}/${encodeURIComponent(id)}`, testid: "frame-link" }, id))),
  );
  root.append(h("p", { class: "muted" }, `${ids.length} frames`), list);
}

// How many frames ahead of the one shown are fetched (and parsed) while it is on screen, and how far
// behind they are kept: playback and ← / → then show frames that are already here.
const AHEAD = 6;
const BEHIND = 2;
const RATES = [1, 2, 5, 10, 20];
const PREFETCH_AFTER_MS = 400;

// A data set's frames, fetched ahead and kept around the one shown: `get(i)` the parsed frame at
// position i (a promise), `ready(i)` whether it is already here, `around(i)` fetch ahead of i and
// drop the rest, `stop()` abandon what is on its way (the page is left).
function frameCache(url, count, parseFrame) {
  const frames = new Map();
  const arrived = new Set();
  const leaving = new AbortController();
  const get = (i) => {
    if (!frames.has(i)) {
      const promise = fetchBinary(url(i), { signal: leaving.signal }).then((buffer) => {
        const frame = parseFrame(buffer);
        arrived.add(i);
        return frame;
      });
      promise.catch(() => frames.delete(i)); // a failed fetch is tried again when next asked for
      frames.set(i, promise);
    }
    return frames.get(i);
  };
  return {
    get,
    put: (i, frame) => {
      frames.set(i, Promise.resolve(frame));
      arrived.add(i);
    },
    ready: (i) => arrived.has(i),
    // the page is left: what is on its way is abandoned and the frames let go
    stop() {
      leaving.abort();
      frames.clear();
      arrived.clear();
    },
    around(i) {
      for (const k of [...frames.keys()]) {
        if (k < i - BEHIND || k > i + AHEAD) {
          frames.delete(k);
          arrived.delete(k);
        }
      }
      // one after another, nearest first, so the next frame is never queued behind a far one
      let chain = Promise.resolve();
      for (let k = i + 1; k <= Math.min(count - 1, i + AHEAD); k++) chain = chain.then(() => (leaving.signal.aborted ? null : get(k).catch(() => null)));
    },
  };
}

// The timeline of a log (frames with an order): play / pause, the frame rate, a scrubber and where
// the frame is in the log's time; hidden for a data set without an order.
function timeline(count, order, onSeek, onPlay, onRate) {
  const play = h("button", { class: "small", testid: "playback-play", onclick: () => onPlay() }, "▶ Play");
  const rate = h("select", { testid: "playback-rate" }, RATES.map((r) => h("option", { value: r, selected: r === 10 }, `${r} frames/s`)));
  rate.addEventListener("change", () => onRate(Number(rate.value)));
  const scrubber = h("input", { type: "range", min: 0, max: Math.max(0, count - 1), step: 1, value: 0, testid: "playback-scrubber" });
  scrubber.addEventListener("input", () => onSeek(Number(scrubber.value)));
  const where = h("span", { class: "muted", testid: "playback-position" });
  const bar = h(
    "div",
    { class: "viewer-timeline", testid: "playback" },
    play,
    h("label", {}, "Rate ", rate),
    scrubber,
    where,
    h("span", { class: "muted" }, `a log (ordered by ${order === "frame_ids" ? "its poses" : order}); ← / →: step, space: play / pause`),
  );
  return { bar, play, scrubber, where, rate };
}

export async function frameViewerPage(root, name, frameId) {
  const datasets = listOf(await api("/api/datasets"), "datasets");
  const listing = await api(`/api/datasets/${encodeURIComponent(name)}/frames`).catch(() => null);
  const ids = listing ? listOf(listing, "frames", "frame_ids", "ids").map((f) => (typeof f === "object" ? (f.id ?? f.frame_id ?? f.name) : String(f))) : [];
  const at = ids.indexOf(frameId);
  // moving to another frame opens its page; a LiDAR data set's viewer takes these over (in place)
  const nav = { step: (by) => go(`/browse/${encodeURIComponent(name)}/${encodeURIComponent(ids[at + by])}`), pick: (id) => go(`/browse/${encodeURIComponent(name)}/${encodeURIComponent(id)}`) };
  const frameSelect = h("select", { testid: "browse-frame" }, ids.map((id) => h("option", { value: id, selected: id === frameId }, id)));
  frameSelect.addEventListener("change", () => nav.pick(frameSelect.value));
  const prev = h("button", { disabled: at <= 0, testid: "frame-prev", onclick: () => nav.step(-1) }, "← Previous");
  const next = h("button", { disabled: at < 0 || at >= ids.length - 1, testid: "frame-next", onclick: () => nav.step(1) }, "Next →");
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
  return pointCloudFrames(stage, { name, ids, at, frameId, listing, frameSelect, prev, next, nav });
}

// A LiDAR data set's frames in the viewer: the next and previous frames (buttons, ← / →, the frame
// list) shown in place from frames fetched ahead, the camera kept; a log plays on a timeline.
async function pointCloudFrames(stage, { name, ids, at: first, frameId, listing, frameSelect, prev, next, nav }) {
  let at = first;
  const url = (i) => `/api/datasets/${encodeURIComponent(name)}/frames/${encodeURIComponent(ids[i])}`;
  const order = listing?.order ?? null;
  const stamps = listing?.timestamps ?? null;
  let panel = null;
  let loaded = null;
  try {
    ({ panel, frame: loaded } = await loadViewer(stage, `/api/datasets/${encodeURIComponent(name)}/frames/${encodeURIComponent(frameId)}`, { pair: false, title: `${name} / ${frameId}`, cameraKey: `dataset:${name}` }));
  } catch (exc) {
    clear(stage).append(notice("error", `Could not show frame ${frameId}: ${exc.message}`));
    return null;
  }
  if (at < 0) return () => panel.dispose();
  const { parseFrame } = await import("../viewer/viewer.js");
  const cache = frameCache(url, ids.length, parseFrame);
  cache.put(at, loaded);
  // Fetching ahead costs the server a frame's work each: it starts with the first step or play, or
  // for a log (made to be played) a moment after its first frame is drawn, so that opening a frame
  // and leaving at once is not slowed by frames nobody asked for.
  let ahead = false;
  const fetchAhead = () => {
    ahead = true;
    cache.around(at);
  };
  const waiting = order ? setTimeout(fetchAhead, PREFETCH_AFTER_MS) : null;
  // what playback did (tests read it): frames shown, of them already here or waited for, and how
  // many of the frames ahead have arrived
  const playback = (window.__playback = { at, shown: 1, fromCache: 0, waited: 0, playing: false });
  playback.readyAhead = () => ids.slice(at + 1, at + 1 + AHEAD).filter((_, k) => cache.ready(at + 1 + k)).length;
  let rate = 10;
  let timer = null;
  let wanted = at;
  const line = order ? timeline(ids.length, order, (i) => jump(i), () => (playback.playing ? pause() : play()), (r) => (rate = r)) : null;
  if (line) stage.prepend(line.bar);
  const title = stage.querySelector("[data-testid=viewer-title]");

  function mark() {
    frameSelect.value = ids[at];
    prev.disabled = at <= 0;
    next.disabled = at >= ids.length - 1;
    if (title) title.textContent = `${name} / ${ids[at]}`;
    if (line) {
      line.scrubber.value = String(at);
      const t = stamps?.[at];
      const time = t === null || t === undefined ? "" : ` · t = ${(t - stamps[0]).toFixed(2)} s`;
      line.where.textContent = `frame ${at + 1} of ${ids.length} (${ids[at]})${time}`;
    }
    playback.at = at;
  }

  // Show the frame at position i in place (the latest asked for wins), the camera where it is.
  async function showAt(i) {
    const target = Math.max(0, Math.min(ids.length - 1, i));
    wanted = target;
    const started = performance.now();
    const here = cache.ready(target);
    let frame;
    try {
      frame = await cache.get(target);
    } catch (exc) {
      pause();
      stage.querySelector("[data-testid=viewer-info]").textContent = `Could not show frame ${ids[target]}: ${exc.message}`;
      return false;
    }
    if (wanted !== target || panel.viewer.disposed) return false;
    at = target;
    playback.shown++;
    playback[here ? "fromCache" : "waited"]++;
    panel.show(frame, started, { keepCamera: true });
    history.replaceState(null, "", `#/browse/${encodeURIComponent(name)}/${encodeURIComponent(ids[at])}`);
    mark();
    if (ahead) cache.around(at);
    return true;
  }

  function play() {
    if (!line || playback.playing) return;
    clearTimeout(waiting);
    fetchAhead();
    if (at >= ids.length - 1) showAt(0);
    playback.playing = true;
    line.play.textContent = "❚❚ Pause";
    const tick = async () => {
      if (!playback.playing) return;
      const due = performance.now() + 1000 / rate;
      if (at >= ids.length - 1) return pause();
      await showAt(at + 1);
      if (playback.playing) timer = setTimeout(tick, Math.max(0, due - performance.now()));
    };
    timer = setTimeout(tick, 1000 / rate);
  }

  function pause() {
    playback.playing = false;
    clearTimeout(timer);
    if (line) line.play.textContent = "▶ Play";
  }

  // the page's own controls step in place instead of opening the page again: the user moves to
  // frame i, playback stops, frames are fetched ahead from now on
  function jump(i) {
    pause();
    clearTimeout(waiting);
    ahead = true;
    showAt(i);
  }
  const step = (by) => jump(at + by);
  nav.step = step;
  nav.pick = (id) => jump(ids.indexOf(id));
  const onKey = (event) => {
    if (event.altKey || event.ctrlKey || event.metaKey || event.shiftKey || usesArrows(event.target)) return;
    if (event.key === "ArrowLeft" || event.key === "ArrowRight") {
      event.preventDefault();
      step(event.key === "ArrowLeft" ? -1 : 1);
    } else if (event.key === " " && line) {
      event.preventDefault();
      playback.playing ? pause() : play();
    }
  };
  window.addEventListener("keydown", onKey);
  mark();
  return () => {
    pause();
    clearTimeout(waiting);
    cache.stop();
    if (window.__playback === playback) window.__playback = null;
    window.removeEventListener("keydown", onKey);
    panel.dispose();
  };
}
