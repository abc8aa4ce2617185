// Models (systems under test): register a built-in, a plugin spec, an ONNX file or an Open3D-ML
// checkpoint; list; delete. subprocess: / worker: specs are refused by the server (CLI only).
import { api, listOf, upload } from "../api.js";
import { clear, emptyRow, formatTime, h, notice, progressBar } from "../dom.js";

const BUILT_INS = ["classic", "pillars"];

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

export async function modelsPage(root) {
  const body = h("tbody", { testid: "models-body" });
  const listMessage = h("div");

  async function load() {
    let reply;
    try {
      reply = await api("/api/models");
    } catch (exc) {
      clear(listMessage).append(notice("error", exc.message, exc.problems));
      return;
    }
    clear(listMessage);
    const models = listOf(reply, "models");
    clear(body);
    if (!models.length) body.append(emptyRow(6, "No models yet: register one below (classic is the built-in pipeline)."));
    for (const model of models) {
      const options = model.options && Object.keys(model.options).length ? JSON.stringify(model.options) : "";
      body.append(
        h(
          "tr",
          { testid: "model-row", dataset: { name: model.name } },
          h("td", {}, model.name),
          h("td", {}, h("code", {}, model.spec ?? ""), model.modality === "camera" ? h("span", { class: "badge modality", testid: "model-modality-badge" }, "camera") : null),
          h("td", {}, h("code", { class: "muted" }, options)),
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
                  if (!window.confirm(`Remove model ${model.name}?`)) return;
                  try {
                    await api(`/api/models/${encodeURIComponent(model.name)}`, { method: "DELETE" });
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
        clear(specMessage);
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
            body: { name: name.value.trim(), spec: spec.value.trim(), options: parsed, modality: modality.value },
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
  const fileMessage = h("div");
  const fileProgress = h("div");
  const fileForm = h(
    "form",
    {
      class: "card form",
      testid: "model-upload-form",
      onsubmit: async (event) => {
        event.preventDefault();
        clear(fileMessage);
        const form = new FormData();
        form.append("name", fileName.value.trim());
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
          fileMessage.append(notice("error", exc.message, exc.problems.length > 1 ? exc.problems : []));
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
      h("thead", {}, h("tr", {}, ["Name", "Spec", "Options", "Fingerprint", "Added", ""].map((t) => h("th", {}, t)))),
      body,
    ),
    h("div", { class: "cards" }, specForm, fileForm),
  );
  await load();
}
