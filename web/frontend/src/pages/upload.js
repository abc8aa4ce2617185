// The data-set upload widget, shared by the data-sets page and the visualisation page: files, a
// folder or a zip (picked or dropped), a name, notes, how to read it, and whether frames without
// labels may run. After an upload it says how many frames have labels and warns when AP cannot be
// scored on all of them; every refusal names the user's file and line.
import { api, upload } from "../api.js";
import { append, clear, h, notice, progressBar } from "../dom.js";

// A name the server accepts, from a file or folder name: "KITTI drive 05.zip" → "KITTI-drive-05".
export function suggestedName(fileName) {
  const stem = String(fileName ?? "").replace(/\.[^.]+$/, "");
  return stem.replace(/[^A-Za-z0-9._-]+/g, "-").replace(/^[-.]+|-+$/g, "").slice(0, 100);
}

// Every file under a dropped directory entry (a folder dropped onto the page), depth first.
async function filesOf(entry) {
  if (entry.isFile) return [await new Promise((resolve, reject) => entry.file(resolve, reject))];
  const reader = entry.createReader();
  const files = [];
  for (;;) {
    const batch = await new Promise((resolve, reject) => reader.readEntries(resolve, reject));
    if (!batch.length) return files;
    for (const child of batch) files.push(...(await filesOf(child)));
  }
}

// The files a drop carries, folders walked; and the name of what was dropped (for the data set's name).
async function droppedFiles(dataTransfer) {
  const entries = [...(dataTransfer.items ?? [])].map((item) => item.webkitGetAsEntry?.()).filter(Boolean);
  if (!entries.length) return { files: [...dataTransfer.files], label: dataTransfer.files[0]?.name };
  const files = [];
  for (const entry of entries) files.push(...(await filesOf(entry)));
  return { files, label: entries.length === 1 ? entries[0].name : files[0]?.name };
}

// How many frames have labels, as the upload reply counts them (null when it does not say).
export function labelsLine(labels) {
  if (!labels) return null;
  const what = labels.unit === "images" ? "images have a steering label" : labels.label_files ? "frames have a label file" : "frames have labels";
  const scope = labels.checked < labels.frames ? ` (the first ${labels.checked} of ${labels.frames} checked)` : "";
  return `${labels.labelled} of ${labels.checked} ${what}${scope}.`;
}

// The warning for frames without labels, as a notice (null when every frame checked has labels).
export function labelsWarning(labels, testid = "labels-warning") {
  return labels?.warning ? notice("warning", `${labels.warning}.`, [], testid) : null;
}

// The upload form. `onUploaded(reply)` runs after a data set is recorded (the list reloads, or the
// visualisation page opens it); `title` heads the card.
export function uploadWidget({ onUploaded, title = "Upload a data set" } = {}) {
  let chosen = null; // files picked or dropped: {files, label}
  const name = h("input", { name: "name", required: true, placeholder: "name", pattern: "[A-Za-z0-9._\\-]+", maxlength: 100, testid: "upload-name" });
  const files = h("input", { name: "files", type: "file", multiple: true, testid: "upload-files" });
  const folder = h("input", { name: "folder", type: "file", multiple: true, webkitdirectory: true, testid: "upload-folder" });
  const notes = h("textarea", { name: "notes", rows: 2, maxlength: 10000, placeholder: "where the data comes from, what it is for (optional)", testid: "upload-notes" });
  const modality = h(
    "select",
    { name: "modality", testid: "upload-modality" },
    h("option", { value: "" }, "what the data holds"),
    h("option", { value: "lidar" }, "LiDAR point clouds"),
    h("option", { value: "camera" }, "camera images (steering labels)"),
  );
  const allowUnlabelled = h("input", { type: "checkbox", name: "allow_unlabelled", checked: true, testid: "upload-allow-unlabelled" });
  const picked = h("span", { class: "muted", testid: "upload-picked" }, "no files chosen");
  const message = h("div", { testid: "upload-message" });
  const progress = h("div");
  const button = h("button", { type: "submit", class: "primary", testid: "upload-submit" }, "Upload");

  // what the next upload sends; a new choice clears the last upload's messages
  function choose(list, label, { keepMessage = false } = {}) {
    chosen = list.length ? { files: [...list], label } : null;
    picked.textContent = chosen ? `${chosen.files.length} file${chosen.files.length === 1 ? "" : "s"}: ${label ?? chosen.files[0].name}` : "no files chosen";
    if (chosen && !name.value.trim()) name.value = suggestedName(label ?? chosen.files[0].name);
    if (!keepMessage) clear(message);
  }
  files.addEventListener("change", () => choose(files.files, files.files[0]?.name));
  folder.addEventListener("change", () => {
    const first = folder.files[0];
    choose(folder.files, first?.webkitRelativePath?.split("/")[0] || first?.name);
  });

  const drop = h(
    "div",
    { class: "drop-zone", testid: "upload-drop" },
    h("strong", {}, "Drop a frame folder, files or a .zip here"),
    h("span", { class: "muted" }, " — or pick them: "),
    h("label", { class: "inline" }, "files ", files),
    h("label", { class: "inline" }, "a folder ", folder),
    h("div", {}, picked),
  );
  drop.addEventListener("dragover", (event) => {
    event.preventDefault();
    drop.classList.add("over");
  });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", async (event) => {
    event.preventDefault();
    drop.classList.remove("over");
    const { files: list, label } = await droppedFiles(event.dataTransfer);
    choose(list, label);
  });

  const form = h(
    "form",
    {
      class: "card form upload-card",
      testid: "upload-form",
      onsubmit: async (event) => {
        event.preventDefault();
        clear(message);
        if (!chosen) {
          message.append(notice("error", "files: choose or drop the data set's files, folder or .zip first", [], "upload-error"));
          return;
        }
        const body = new FormData();
        body.append("name", name.value.trim());
        if (notes.value.trim()) body.append("notes", notes.value.trim());
        if (modality.value) body.append("modality", modality.value);
        body.append("allow_unlabelled", allowUnlabelled.checked ? "true" : "false");
        for (const file of chosen.files) body.append("files", file, file.name);
        button.disabled = true;
        try {
          const reply = await upload("/api/datasets/upload", body, (loaded, total) => {
            clear(progress).append(progressBar(Math.round(loaded / 1024), Math.round(total / 1024)));
          });
          const frames = reply?.frame_count;
          append(message, [
            notice(
              "ok",
              [
                h("span", {}, `Added ${reply?.name ?? name.value}${frames !== undefined ? ` (${frames} frames)` : ""}. `),
                h("span", { testid: "upload-labels" }, labelsLine(reply?.labels) ?? ""),
              ],
              (reply?.warnings ?? []).map((line) => ({ message: line })),
              "upload-ok",
            ),
            labelsWarning(reply?.labels, "upload-labels-warning"),
          ]);
          form.reset();
          allowUnlabelled.checked = true;
          choose([], null, { keepMessage: true });
          onUploaded?.(reply);
        } catch (exc) {
          const what = chosen.files.length === 1 ? chosen.files[0].name : `${chosen.label ?? "the files"} (${chosen.files.length} files)`;
          const problems = exc.problems.length > 1 || exc.problems[0]?.file ? exc.problems : [];
          message.append(notice("error", `The upload of ${what} was refused: ${exc.message.replace(/^HTTP \d+: /, "")}`, problems, "upload-error"));
        } finally {
          button.disabled = false;
          clear(progress);
        }
      },
    },
    h("h2", {}, title),
    h(
      "p",
      { class: "hint" },
      "One .zip in KITTI layout (velodyne/, label_2/, calib/ …), a frame folder, point-cloud files (.bin, .pcd, .ply, .las, .npy …) ",
      "with their KITTI label files, one ROS bag / MCAP file, or camera images (.png, .jpg) with one CSV of steering angles. ",
      "Every problem is listed with its file and line.",
    ),
    drop,
    h("label", {}, "Name ", name),
    h("label", {}, "Notes ", notes),
    h("label", {}, "Read as ", modality),
    h("label", { title: "AP is scored on the labelled frames; without this, tasks on a partly labelled data set are refused" }, allowUnlabelled, " Frames without labels: run them too (AP from the labelled ones)"),
    button,
    progress,
    message,
  );
  return form;
}

// What the visualisation page says about a data set just uploaded (it opens it right away): how many
// frames have labels, and the warning when not all do.
export async function uploadedNotice(name) {
  const ds = await api(`/api/datasets/${encodeURIComponent(name)}`).catch(() => null);
  if (!ds) return null;
  return h(
    "div",
    { testid: "uploaded-notice" },
    notice("ok", `Uploaded ${ds.name} (${ds.frame_count} frames). ${labelsLine(ds.labels) ?? ""}`, [], "upload-ok"),
    labelsWarning(ds.labels, "upload-labels-warning"),
  );
}
