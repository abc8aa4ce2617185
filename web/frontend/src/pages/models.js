// Models (systems under test): register a built-in, a plugin spec, an ONNX file or an Open3D-ML
// checkpoint (with notes); list them with their type (what kind of system: the server's registry
// says) and modality; delete (a refusal stays under its row, naming the tasks); one model's page
// (#/models/NAME) with its facts, the tasks using it and its notes. subprocess: / worker: specs are
// refused by the server (CLI only).
import { api, listOf, upload } from "../api.js";
import { clear, emptyRow, formatTime, h, notice, progressBar } from "../dom.js";
import { deleteButton, factsList, forget, notesCell, notesEditor, refusalNotice, taskLinks } from "./inventory.js";

const BUILT_INS = ["classic", "pillars"];
const COLUMNS = ["Name", "Type", "Modality", "Spec and options", "Notes", "Fingerprint", "Added", ""];

// "k=v" lines → {k: v}, values read as JSON where they parse (numbers, booleans, lists).
export function parseOptions(text) {
  const options = {};
  for (const [index, raw] of text.split("\n").entries()) {
    const line = raw.trim();
    if (!line || line.startsWith("#")) continue;
    const eq = line.indexOf("=");
    if (eq <= 0) throw new Error(`options line ${index + 1}: expected key=value, got "${line}"`);
    const key = line.slice(0, eq).trim();
    const value = line.slice(eq + 1).trim();
    try {
      options[key] = JSON.parse(value);
    } catch {
      options[key] = value;
    }
  }
  return options;
}

// A model's modality: "camera" as a badge (a steering system), "LiDAR" as text.
function modalityCell(model) {
  return model.modality === "camera"
    ? h("td", {}, h("span", { class: "badge modality", testid: "model-modality-badge" }, "camera"))
    : h("td", { testid: "model-modality" }, "LiDAR");
}

// What kind of system it is (the registry's word), with the spec's scheme on hover.
function typeCell(model) {
  const unavailable = model.type === "unavailable";
  return h("td", { class: unavailable ? "type-cell unavailable" : "type-cell", title: model.kind ? `registered as: ${model.kind}` : "", testid: "model-type", dataset: { type: model.type ?? "" } }, model.type_label ?? model.type ?? "—");
}

export async function modelsPage(root) {
  const body = h("tbody", { testid: "models-body" });
  const listMessage = h("div");
  let refusal = null; // {name, message, tasks}: a refused delete, shown under its row until the next action

  // A new action: the last one's notices go.
  function startAction() {
    refusal = null;
    for (const el of root.querySelectorAll("[data-testid=refusal-row]")) el.remove();
    for (const el of [specMessage, fileMessage, listMessage]) clear(el);
  }

  async function load() {
    let reply;
    try {
      reply = await api("/api/models");
    } catch (exc) {
      clear(listMessage).append(notice("error", exc.message, exc.problems));
      return;
    }
    const models = listOf(reply, "models");
    clear(body);
    if (!models.length) body.append(emptyRow(COLUMNS.length, "No models yet: register one below (classic is the built-in pipeline)."));
    for (const model of models) {
      const options = model.options && Object.keys(model.options).length ? JSON.stringify(model.options) : "";
      const url = `/api/models/${encodeURIComponent(model.name)}`;
      body.append(
        h(
          "tr",
          { testid: "model-row", dataset: { name: model.name } },
          h("td", { class: "name-cell" }, h("a", { href: `#/models/${encodeURIComponent(model.name)}`, testid: "model-link" }, model.name)),
          typeCell(model),
          modalityCell(model),
          h("td", { class: "spec-cell" }, h("code", {}, model.spec ?? ""), options ? h("div", {}, h("code", { class: "muted" }, options)) : null),
          notesCell(model.notes),
          h("td", {}, h("code", { title: model.fingerprint ?? "" }, (model.fingerprint ?? "").slice(0, 12))),
          h("td", {}, formatTime(model.added_at ?? model.created_at)),
          h(
            "td",
            { class: "actions" },
            h(
              "button",
              {
                class: "small danger",
                testid: "delete-model",
                onclick: async () => {
                  startAction();
                  const refused = await forget(url, url, `Remove model ${model.name}?`);
                  if (refused?.cancelled) return;
                  refusal = refused ? { name: model.name, ...refused } : null;
                  load();
                },
              },
              "Delete",
            ),
          ),
        ),
      );
      if (refusal?.name === model.name) {
        body.append(h("tr", { class: "refusal-row", testid: "refusal-row", dataset: { name: model.name } }, h("td", { colspan: COLUMNS.length }, refusalNotice(refusal.message, refusal.tasks))));
      }
    }
  }

  // -- register by spec --
  const kind = h(
    "select",
    { testid: "model-kind" },
    h("option", { value: "builtin" }, "built-in"),
    h("option", { value: "plugin" }, "plugin spec (module:callable)"),
  );
  const name = h("input", { required: true, placeholder: "name", pattern: "[A-Za-z0-9._\\-]+", testid: "model-name" });
  const modality = h(
    "select",
    { testid: "model-modality" },
    h("option", { value: "lidar" }, "LiDAR: detects objects in point clouds"),
    h("option", { value: "camera" }, "camera: a steering system on images"),
  );
  const spec = h("input", { required: true, placeholder: "classic", list: "builtin-suts", testid: "model-spec" });
  const options = h("textarea", { rows: 3, placeholder: "key=value per line (optional)", testid: "model-options" });
  const notes = h("textarea", { rows: 2, maxlength: 10000, placeholder: "its version, training, what it is for (optional)", testid: "model-notes" });
  const specMessage = h("div", { testid: "model-message" });
  const datalist = h("datalist", { id: "builtin-suts" }, BUILT_INS.map((n) => h("option", { value: n })));
  const placeholder = () => {
    if (kind.value !== "builtin") spec.placeholder = modality.value === "camera" ? "my_package.steering:Net" : "my_package.detectors:build";
    else spec.placeholder = modality.value === "camera" ? "dave2" : "classic";
  };
  kind.addEventListener("change", placeholder);
  modality.addEventListener("change", placeholder);
  const specForm = h(
    "form",
    {
      class: "card form",
      testid: "model-form",
      onsubmit: async (event) => {
        event.preventDefault();
        startAction();
        let parsed;
        try {
          parsed = parseOptions(options.value);
        } catch (exc) {
          specMessage.append(notice("error", exc.message));
          return;
        }
        try {
          await api("/api/models", {
            method: "POST",
            body: { name: name.value.trim(), spec: spec.value.trim(), options: parsed, modality: modality.value, notes: notes.value.trim() },
          });
          specMessage.append(notice("ok", `Registered ${name.value.trim()}.`));
          specForm.reset();
          load();
        } catch (exc) {
          const why = exc.status === 403 ? " (subprocess and worker specs can only be registered from the CLI)" : "";
          specMessage.append(notice("error", `${exc.message}${why}`, exc.problems.length > 1 ? exc.problems : []));
        }
      },
    },
    h("h2", {}, "Register a system under test"),
    h("p", { class: "hint" }, "A built-in name (lidarfuzz suts: classic, pillars …; steering systems dave2, epoch, chauffeur) or an installed plugin's module:callable."),
    h("label", {}, "Kind ", kind),
    h("label", {}, "Modality ", modality),
    h("label", {}, "Name ", name),
    h("label", {}, "Spec ", spec),
    datalist,
    h("label", {}, "Options ", options),
    h("label", {}, "Notes ", notes),
    h("button", { type: "submit", class: "primary", testid: "model-submit" }, "Register"),
    specMessage,
  );

  // -- upload a model file --
  const fileKind = h(
    "select",
    { name: "kind", testid: "model-file-kind" },
    h("option", { value: "onnx" }, "ONNX model (.onnx)"),
    h("option", { value: "open3d" }, "Open3D-ML checkpoint (.pth / .pt)"),
    h("option", { value: "onnx-steering" }, "ONNX steering network (.onnx; camera tasks)"),
  );
  const fileName = h("input", { required: true, placeholder: "name", pattern: "[A-Za-z0-9._\\-]+" });
  const file = h("input", { type: "file", required: true, accept: ".onnx,.pth,.pt,.ckpt", testid: "model-file" });
  const fileOptions = h("textarea", { rows: 2, placeholder: "key=value per line (optional)" });
  const fileNotes = h("textarea", { rows: 2, maxlength: 10000, placeholder: "where it comes from, how it was trained (optional)", testid: "model-file-notes" });
  const fileMessage = h("div", { testid: "model-file-message" });
  const fileProgress = h("div");
  const fileForm = h(
    "form",
    {
      class: "card form",
      testid: "model-upload-form",
      onsubmit: async (event) => {
        event.preventDefault();
        startAction();
        const form = new FormData();
        form.append("name", fileName.value.trim());
        if (fileNotes.value.trim()) form.append("notes", fileNotes.value.trim());
        form.append("kind", fileKind.value === "onnx-steering" ? "onnx" : fileKind.value);
        if (fileKind.value === "onnx-steering") form.append("modality", "camera");
        try {
          form.append("options", JSON.stringify(parseOptions(fileOptions.value)));
        } catch (exc) {
          fileMessage.append(notice("error", exc.message));
          return;
        }
        form.append("file", file.files[0], file.files[0].name);
        try {
          await upload("/api/models/upload", form, (loaded, total) =>
            clear(fileProgress).append(progressBar(Math.round(loaded / 1024), Math.round(total / 1024))),
          );
          fileMessage.append(notice("ok", `Registered ${fileName.value.trim()}.`));
          fileForm.reset();
          load();
        } catch (exc) {
          fileMessage.append(notice("error", `The upload of ${file.files[0]?.name ?? "the model"} was refused: ${exc.message.replace(/^HTTP \d+: /, "")}`, exc.problems.length > 1 ? exc.problems : [], "model-file-error"));
        } finally {
          clear(fileProgress);
        }
      },
    },
    h("h2", {}, "Upload a model file"),
    h("p", { class: "hint" }, "Checkpoints are loaded with torch.load(weights_only=True); nothing uploaded is executed."),
    h("label", {}, "Kind ", fileKind),
    h("label", {}, "Name ", fileName),
    h("label", {}, "File ", file),
    h("label", {}, "Options ", fileOptions),
    h("label", {}, "Notes ", fileNotes),
    h("button", { type: "submit", class: "primary" }, "Upload"),
    fileProgress,
    fileMessage,
  );

  // the built-in and plugin systems the server knows, for the spec field
  api("/api/suts")
    .then((reply) => {
      const known = listOf(reply, "suts");
      if (known.length) {
        datalist.replaceChildren(...known.map((s) => h("option", { value: s.name }, s.description ?? "")));
      }
    })
    .catch(() => {});

  root.append(
    h("div", { class: "page-head" }, h("h1", {}, "Models")),
    listMessage,
    h(
      "table",
      { class: "table", testid: "models-table" },
      h("thead", {}, h("tr", {}, COLUMNS.map((t) => h("th", {}, t)))),
      body,
    ),
    h("div", { class: "cards" }, specForm, fileForm),
  );
  await load();
}

// One model (#/models/NAME): what kind of system it is, its modality, spec, options and fingerprint,
// the tasks using it, its notes (editable), and Delete.
export async function modelDetailPage(root, name) {
  const url = `/api/models/${encodeURIComponent(name)}`;
  const model = await api(url);
  const message = h("div", { testid: "detail-message" });
  const options = model.options && Object.keys(model.options).length ? JSON.stringify(model.options, null, 1) : null;
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", { class: "wrap-name" }, h("a", { href: "#/models" }, "Models"), " / ", model.name),
      h("span", { class: "spacer" }),
      deleteButton({ url, question: `Remove model ${model.name}?`, listPath: "/models", message, testid: "delete-model" }),
    ),
    message,
    h(
      "div",
      { class: "cards" },
      h(
        "div",
        { class: "card" },
        h("h2", {}, "Facts"),
        factsList([
          ["Type", model.type_label ?? model.type, "fact-type"],
          ["Modality", model.modality === "camera" ? "camera: a steering system on images" : "LiDAR: detects objects in point clouds", "fact-modality"],
          ["Spec", h("code", { class: "wrap-code" }, model.spec ?? ""), "fact-spec"],
          ["Options", options ? h("code", { class: "wrap-code" }, options) : null, "fact-options"],
          ["Fingerprint", h("code", {}, model.fingerprint ?? ""), "fact-fingerprint"],
          ["Added", formatTime(model.added_at), "fact-added"],
          ["Used by", model.used_by?.length ? taskLinks(model.used_by) : "no task yet", "fact-used-by"],
        ]),
      ),
      notesEditor(model.notes, (notes) => api(url, { method: "PATCH", body: { notes } })),
    ),
  );
}
