// Data sets: the list (with notes), uploads (pages/upload.js: KITTI zip, a frame folder, point-cloud +
// label files, a bag or MCAP) with every validation problem shown with its file and line, delete (a
// refusal stays under its row, naming the tasks), "generate from the simulator", and one data set's
// page (#/datasets/NAME): its facts, how many frames have labels, the tasks using it, its notes.
import { api, listOf } from "../api.js";
import { clear, emptyRow, every, formatTime, h, notice, progressBar } from "../dom.js";
import { deleteButton, factsList, forget, notesCell, notesEditor, refusalNotice, taskLinks } from "./inventory.js";
import { labelsLine, labelsWarning, uploadWidget } from "./upload.js";

const COLUMNS = ["Name", "Format", "Frames", "Notes", "Added", ""];
const uploadMessageOf = (root) => root.querySelector("[data-testid=upload-message]") ?? h("div");

export async function datasetsPage(root) {
  const body = h("tbody", { testid: "datasets-body" });
  const listMessage = h("div");
  const pending = new Set(); // names being generated: keep refreshing until they are recorded
  let refusal = null; // {name, message, tasks}: a refused delete, shown under its row until the next action

  // A new action: the last one's notices go.
  function startAction() {
    refusal = null;
    for (const el of root.querySelectorAll("[data-testid=refusal-row]")) el.remove();
    clear(uploadMessageOf(root));
    clear(genMessage);
    clear(listMessage);
  }

  async function load() {
    let reply;
    try {
      reply = await api("/api/datasets");
    } catch (exc) {
      clear(listMessage).append(notice("error", exc.message, exc.problems));
      return;
    }
    const datasets = listOf(reply, "datasets");
    clear(body);
    if (!datasets.length) body.append(emptyRow(COLUMNS.length, "No data sets yet: upload one or generate one from the simulator."));
    for (const ds of datasets) {
      const generating = ds.status === "generating";
      if (generating) pending.add(ds.name);
      else pending.delete(ds.name);
      const status =
        ds.status && ds.status !== "ready"
          ? h("span", { class: "muted", testid: "dataset-status" }, ` ${ds.status}${ds.error ? `: ${ds.error}` : ""}`)
          : null;
      const link = `#/datasets/${encodeURIComponent(ds.name)}`;
      body.append(
        h(
          "tr",
          { testid: "dataset-row", dataset: { name: ds.name } },
          h("td", { class: "name-cell" }, generating ? ds.name : h("a", { href: link, testid: "dataset-link" }, ds.name), status),
          h("td", {}, ds.format ?? "—", ds.modality === "camera" ? h("span", { class: "badge modality", testid: "dataset-modality" }, "camera") : null),
          h("td", { class: "num" }, generating && ds.total ? progressBar(ds.done ?? 0, ds.total) : (ds.frame_count ?? ds.frames ?? "—")),
          notesCell(ds.notes),
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
                  startAction();
                  const name = encodeURIComponent(ds.name);
                  const refused = await forget(`/api/datasets/${name}`, `/api/datasets/${name}`, `Forget data set ${ds.name}? Uploaded files are removed; other files stay.`);
                  if (refused?.cancelled) return;
                  refusal = refused ? { name: ds.name, ...refused } : null;
                  load();
                },
              },
              "Delete",
            ),
          ),
        ),
      );
      if (refusal?.name === ds.name) {
        body.append(h("tr", { class: "refusal-row", testid: "refusal-row", dataset: { name: ds.name } }, h("td", { colspan: COLUMNS.length }, refusalNotice(refusal.message, refusal.tasks))));
      }
    }
  }

  // -- upload --
  const uploadForm = uploadWidget({ onUploaded: () => load() });
  uploadForm.addEventListener("submit", () => {
    refusal = null;
    for (const el of root.querySelectorAll("[data-testid=refusal-row]")) el.remove();
  });

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
        startAction();
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
      h("thead", {}, h("tr", {}, COLUMNS.map((t) => h("th", {}, t)))),
      body,
    ),
    h("div", { class: "cards" }, uploadForm, genForm),
  );
  await load();
  return every(3000, () => {
    if (pending.size && !document.hidden) load();
  });
}

// One data set (#/datasets/NAME): its facts, how many frames have labels (with the warning when
// not all do), the tasks using it, its notes (editable), and View / Delete.
export async function datasetDetailPage(root, name) {
  const url = `/api/datasets/${encodeURIComponent(name)}`;
  const ds = await api(url);
  const message = h("div", { testid: "detail-message" });
  const options = ds.options ?? {};
  const labels = ds.labels;
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", { class: "wrap-name" }, h("a", { href: "#/datasets" }, "Data sets"), " / ", ds.name),
      h("span", { class: "spacer" }),
      h("a", { class: "button", href: `#/browse/${encodeURIComponent(ds.name)}`, testid: "browse-dataset" }, "View frames"),
      deleteButton({
        url,
        question: `Forget data set ${ds.name}? Uploaded files are removed; other files stay.`,
        listPath: "/datasets",
        message,
        testid: "delete-dataset",
      }),
    ),
    message,
    h(
      "div",
      {},
      labelsWarning(labels),
      ds.labels_error ? notice("error", `Its files cannot be read as they were recorded: ${ds.labels_error}`, [], "labels-error") : null,
    ),
    h(
      "div",
      { class: "cards" },
      h(
        "div",
        { class: "card" },
        h("h2", {}, "Facts"),
        factsList([
          ["Format", ds.format, "fact-format"],
          ["Frames", ds.frame_count ?? ds.total, "fact-frames"],
          ["Modality", ds.modality === "camera" ? "camera images" : "LiDAR point clouds", "fact-modality"],
          ["Labels", labelsLine(labels), "fact-labels"],
          ["Point layout", options.layout, "fact-layout"],
          ["Frames without labels", labels?.label_files && labels.labelled < labels.checked ? (options.allow_unlabelled ? "run; AP from the labelled ones" : "refused (tasks need every frame labelled)") : null, "fact-unlabelled"],
          ["Stored at", h("span", { class: "path" }, ds.path ?? ""), "fact-path"],
          ["Added", formatTime(ds.added_at), "fact-added"],
          ["Used by", ds.used_by?.length ? taskLinks(ds.used_by) : "no task yet", "fact-used-by"],
        ]),
      ),
      notesEditor(ds.notes, (notes) => api(url, { method: "PATCH", body: { notes } })),
    ),
  );
}
