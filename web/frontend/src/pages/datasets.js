// Data sets: the list, uploads (KITTI zip; point-cloud + label files; a bag or MCAP) with every
// validation problem shown with its file and line, delete, and "generate from the simulator".
import { api, listOf, upload } from "../api.js";
import { clear, emptyRow, every, formatTime, h, notice, progressBar } from "../dom.js";

export async function datasetsPage(root) {
  const body = h("tbody", { testid: "datasets-body" });
  const listMessage = h("div");
  const pending = new Set(); // names being generated: keep refreshing until they are recorded

  async function load() {
    let reply;
    try {
      reply = await api("/api/datasets");
    } catch (exc) {
      clear(listMessage).append(notice("error", exc.message, exc.problems));
      return;
    }
    clear(listMessage);
    const datasets = listOf(reply, "datasets");
    clear(body);
    if (!datasets.length) body.append(emptyRow(6, "No data sets yet: upload one or generate one from the simulator."));
    for (const ds of datasets) {
      const generating = ds.status === "generating";
      if (generating) pending.add(ds.name);
      else pending.delete(ds.name);
      const status =
        ds.status && ds.status !== "ready"
          ? h("span", { class: "muted", testid: "dataset-status" }, ` ${ds.status}${ds.error ? `: ${ds.error}` : ""}`)
          : null;
      body.append(
        h(
          "tr",
          { testid: "dataset-row", dataset: { name: ds.name } },
          h("td", {}, h("a", { href: `#/browse/${encodeURIComponent(ds.name)}` }, ds.name), status),
          h("td", {}, ds.format ?? "—", ds.modality === "camera" ? h("span", { class: "badge modality", testid: "dataset-modality" }, "camera") : null),
          h("td", { class: "num" }, generating && ds.total ? progressBar(ds.done ?? 0, ds.total) : (ds.frame_count ?? ds.frames ?? "—")),
          h("td", { class: "path" }, ds.path ?? ""),
          h("td", {}, formatTime(ds.added_at ?? ds.created_at)),
          h(
            "td",
            { class: "actions" },
            h("a", { class: "button small", href: `#/browse/${encodeURIComponent(ds.name)}`, testid: "browse-dataset" }, "View"),
            h(
              "button",
              {
                class: "small danger",
                testid: "delete-dataset",
                onclick: async () => {
                  if (!window.confirm(`Forget data set ${ds.name}? Uploaded files are removed; other files stay.`)) return;
                  try {
                    await api(`/api/datasets/${encodeURIComponent(ds.name)}`, { method: "DELETE" });
                  } catch (exc) {
                    clear(listMessage).append(notice("error", exc.message, exc.problems));
                  }
                  load();
                },
              },
              "Delete",
            ),
          ),
        ),
      );
    }
  }

  // -- upload --
  const uploadName = h("input", { name: "name", required: true, placeholder: "name", pattern: "[A-Za-z0-9._\\-]+", testid: "upload-name" });
  const uploadFiles = h("input", { name: "files", type: "file", multiple: true, required: true, testid: "upload-files" });
  const uploadModality = h(
    "select",
    { name: "modality", testid: "upload-modality" },
    h("option", { value: "" }, "what the data holds"),
    h("option", { value: "lidar" }, "LiDAR point clouds"),
    h("option", { value: "camera" }, "camera images (steering labels)"),
  );
  const uploadMessage = h("div", { testid: "upload-message" });
  const uploadProgress = h("div");
  const uploadButton = h("button", { type: "submit", class: "primary", testid: "upload-submit" }, "Upload");
  const uploadForm = h(
    "form",
    {
      class: "card form",
      testid: "upload-form",
      onsubmit: async (event) => {
        event.preventDefault();
        clear(uploadMessage);
        const form = new FormData();
        form.append("name", uploadName.value.trim());
        if (uploadModality.value) form.append("modality", uploadModality.value);
        for (const file of uploadFiles.files) form.append("files", file, file.name);
        uploadButton.disabled = true;
        try {
          const reply = await upload("/api/datasets/upload", form, (loaded, total) => {
            clear(uploadProgress).append(progressBar(Math.round(loaded / 1024), Math.round(total / 1024)));
          });
          const frames = reply?.frame_count ?? reply?.frames;
          uploadMessage.append(
            notice("ok", `Added ${reply?.name ?? uploadName.value}${frames !== undefined ? ` (${frames} frames)` : ""}.`),
          );
          uploadForm.reset();
          load();
        } catch (exc) {
          uploadMessage.append(notice("error", `The upload was refused: ${exc.message}`, exc.problems, "upload-error"));
        } finally {
          uploadButton.disabled = false;
          clear(uploadProgress);
        }
      },
    },
    h("h2", {}, "Upload a data set"),
    h(
      "p",
      { class: "hint" },
      "One .zip in KITTI layout (velodyne/, label_2/, calib/ …); or point-cloud files (.bin, .pcd, .ply, .las, .npy …) ",
      "with their KITTI label files; or one ROS bag / MCAP file; or camera images (.png, .jpg) with one CSV of steering angles ",
      "(a zip for KITTI image_2/, Udacity or driving_log layouts). Every problem is listed with its file and line.",
    ),
    h("label", {}, "Name ", uploadName),
    h("label", {}, "Files ", uploadFiles),
    h("label", {}, "Read as ", uploadModality),
    uploadButton,
    uploadProgress,
    uploadMessage,
  );

  // -- generate --
  const genName = h("input", { name: "name", required: true, placeholder: "name", pattern: "[A-Za-z0-9._\\-]+", testid: "generate-name" });
  const genFrames = h("input", { name: "frames", type: "number", min: 1, max: 10000, value: 10, required: true });
  const genSeed = h("input", { name: "seed", type: "number", min: 0, value: 0, required: true });
  const genKind = h(
    "select",
    { name: "kind" },
    h("option", { value: "" }, "mixed"),
    h("option", { value: "urban" }, "urban"),
    h("option", { value: "suburban" }, "suburban"),
  );
  const genScenes = h(
    "select",
    { name: "scenes", testid: "generate-scenes" },
    h("option", { value: "independent" }, "independent scenes"),
    h("option", { value: "sequence" }, "a log: one scene driven through"),
    h("option", { value: "drive" }, "a drive log: a stop, a turn, pedestrians"),
  );
  const genCamera = h(
    "select",
    { name: "camera", testid: "generate-camera" },
    h("option", { value: "" }, "none: a LiDAR data set"),
    h("option", { value: "640x480" }, "640 × 480: a camera data set"),
    h("option", { value: "1242x375" }, "1242 × 375 (KITTI's): a camera data set"),
  );
  const genMessage = h("div", { testid: "generate-message" });
  const genForm = h(
    "form",
    {
      class: "card form",
      testid: "generate-form",
      onsubmit: async (event) => {
        event.preventDefault();
        clear(genMessage);
        const name = genName.value.trim();
        try {
          await api("/api/datasets/generate", {
            method: "POST",
            body: { name, frames: Number(genFrames.value), seed: Number(genSeed.value), kind: genKind.value || null, scenes: genScenes.value, camera: genCamera.value || null },
          });
          pending.add(name);
          genMessage.append(notice("ok", `Rendering ${name} in the background; it appears in the list when done.`));
          load();
        } catch (exc) {
          genMessage.append(notice("error", exc.message, exc.problems));
        }
      },
    },
    h("h2", {}, "Generate from the simulator"),
    h("p", { class: "hint" }, "Labelled HDL-64E street scenes in KITTI layout, rendered by lidarfuzz's simulator; a log (10 Hz, with timestamps and poses) for structural tasks; with camera images (and their steering labels) a data set for camera tasks."),
    h("label", {}, "Name ", genName),
    h("label", {}, "Frames ", genFrames),
    h("label", {}, "Seed ", genSeed),
    h("label", {}, "Kind ", genKind),
    h("label", {}, "Frames are ", genScenes),
    h("label", {}, "Camera images ", genCamera),
    h("button", { type: "submit", class: "primary", testid: "generate-submit" }, "Generate"),
    genMessage,
  );

  root.append(
    h("div", { class: "page-head" }, h("h1", {}, "Data sets")),
    listMessage,
    h(
      "table",
      { class: "table", testid: "datasets-table" },
      h("thead", {}, h("tr", {}, ["Name", "Format", "Frames", "Path", "Added", ""].map((t) => h("th", {}, t)))),
      body,
    ),
    h("div", { class: "cards" }, uploadForm, genForm),
  );
  await load();
  return every(3000, () => {
    if (pending.size && !document.hidden) load();
  });
}
