// The New task dialog: operators grouped by family (description, severity table, before/after
// preview), severities or explicit parameters checked against the params schema, relations,
// data set and model pickers, seed; a structural task's logs, sequence system, code targets,
// heuristics and strategies instead (./structural.js); a camera task's image transformations, camera
// data sets and steering systems and its search budget; the server's 422 errors are shown at the
// field they name.
import { api, fetchBlob, listOf } from "../api.js";
import { clear, go, h, notice } from "../dom.js";
import { schemaFields } from "../schema.js";
import { structuralFields } from "./structural.js";

// Operators come as a list (each with its family), as {family: [...]} or as [{family, operators}].
export function operatorsByFamily(reply) {
  let flat = [];
  const source = reply?.families ?? reply?.operators ?? reply;
  if (Array.isArray(source)) {
    for (const item of source) {
      if (Array.isArray(item.operators)) flat.push(...item.operators.map((op) => ({ family: item.family ?? item.name, ...op })));
      else flat.push(item);
    }
  } else if (source && typeof source === "object") {
    for (const [family, ops] of Object.entries(source)) {
      if (Array.isArray(ops)) flat.push(...ops.map((op) => ({ family, ...op })));
    }
  }
  flat = flat.filter((op) => op && op.name);
  const groups = new Map();
  for (const op of flat) {
    const family = op.family || "other";
    if (!groups.has(family)) groups.set(family, []);
    groups.get(family).push(op);
  }
  return groups;
}

// The severity table: a row per config field that changes with the severity (the server's
// severity_table: {field, description, values at severity 0, 1, … 5}), or the configs per severity.
function severityTable(op) {
  const levels = [0, ...severityLevels(op)];
  const rows = (op.severity_table ?? []).filter((r) => new Set(r.values.slice(1)).size > 1 || r.values[0] !== r.values[1]);
  if (rows.length) {
    return h(
      "table",
      { class: "severity-table" },
      h("tr", {}, h("th", {}, "severity"), levels.map((l) => h("th", {}, String(l)))),
      rows.map((r) => h("tr", { title: r.description ?? "" }, h("th", {}, r.field), r.values.map((v) => h("td", {}, String(v))))),
    );
  }
  const legacy = severityRows(op);
  return legacy.length ? h("table", { class: "severity-table" }, legacy) : null;
}

export function severityLevels(op) {
  if (Array.isArray(op.severities) && op.severities.every((s) => Number.isInteger(s))) return op.severities;
  const configs = op.severity_configs ?? (op.severities && !Array.isArray(op.severities) ? op.severities : null);
  return configs ? Object.keys(configs).map(Number).filter((s) => s > 0).sort() : [1, 2, 3, 4, 5];
}

// The severities that set the operator differently (severity_configs compared): one that is the same
// setting at every severity (global_flip mirrors at all five) offers one severity only; the server
// refuses the others as duplicates.
export function distinctLevels(op) {
  const levels = severityLevels(op);
  const configs = op.severity_configs;
  if (!configs || typeof configs !== "object") return levels;
  const seen = new Set();
  return levels.filter((level) => {
    const key = JSON.stringify(configs[String(level)] ?? level);
    if (seen.has(key)) return false;
    seen.add(key);
    return true;
  });
}

function severityRows(op) {
  const table = op.severity_configs ?? (Array.isArray(op.severities) && op.severities.every(Number.isInteger) ? null : op.severities);
  if (!table) return [];
  const entries = Array.isArray(table) ? table.map((v, i) => [v?.severity ?? i + 1, v?.config ?? v]) : Object.entries(table);
  return entries.map(([level, config]) => {
    const text =
      config && typeof config === "object"
        ? Object.entries(config)
            .map(([k, v]) => `${k} ${Array.isArray(v) ? v.join(" – ") : JSON.stringify(v)}`)
            .join("; ")
        : String(config);
    return h("tr", {}, h("th", {}, String(level)), h("td", {}, text));
  });
}

// The first paragraph of a docstring, as plain text (reStructuredText's ``code`` marks dropped).
function firstParagraph(text) {
  return String(text ?? "").split(/\n\s*\n/)[0].replace(/``/g, "").replace(/\s+/g, " ").trim();
}

function operatorRow(op, previews, withPreview = true) {
  const check = h("input", { type: "checkbox", class: "op-check", testid: `op-${op.name}`, value: op.name });
  const levels = distinctLevels(op);
  const severityChecks = levels.map((s) =>
    h("label", { class: "sev" }, h("input", { type: "checkbox", value: s, checked: s % 2 === 1, testid: `op-${op.name}-sev-${s}` }), String(s)),
  );
  const modeSeverities = h("input", { type: "radio", name: `mode-${op.name}`, value: "severities", checked: true });
  const modeConfig = h("input", { type: "radio", name: `mode-${op.name}`, value: "config" });
  const fields = schemaFields(op.params_schema ?? op.config_schema ?? op.schema ?? op.params ?? {});
  const configBox = h("div", { class: "config-fields", hidden: true }, fields.length ? fields.map((f) => f.element) : h("span", { class: "muted" }, "no parameters"));
  const severityBox = h(
    "span",
    { class: "severities" },
    severityChecks,
    levels.length === 1 && severityLevels(op).length > 1 ? h("span", { class: "muted", testid: `op-${op.name}-one-setting` }, " (the same setting at every severity)") : null,
  );
  const sync = () => {
    configBox.hidden = !modeConfig.checked;
    severityBox.hidden = modeConfig.checked;
  };
  modeSeverities.addEventListener("change", sync);
  modeConfig.addEventListener("change", sync);

  // preview: loaded when the details open, again when its severity changes
  const previewSeverity = h(
    "select",
    { testid: `preview-severity-${op.name}` },
    levels.map((s) => h("option", { value: s, selected: s === (levels.includes(3) ? 3 : levels[0]) }, `severity ${s}`)),
  );
  const image = h("img", { class: "preview", alt: `${op.name} before and after`, testid: `preview-${op.name}` });
  const previewMessage = h("span", { class: "muted" });
  async function loadPreview() {
    const key = `${op.name}@${previewSeverity.value}`;
    previewMessage.textContent = "rendering the preview…";
    try {
      if (!previews.has(key)) {
        const blob = await fetchBlob(`/api/operators/${encodeURIComponent(op.name)}/preview.png?severity=${previewSeverity.value}`);
        previews.set(key, URL.createObjectURL(blob));
      }
      image.src = previews.get(key);
      previewMessage.textContent = "";
    } catch (exc) {
      previewMessage.textContent = `no preview: ${exc.message}`;
    }
  }
  previewSeverity.addEventListener("change", loadPreview);
  const details = h(
    "details",
    { class: "op-details", ontoggle: (e) => withPreview && e.target.open && !image.src && loadPreview() },
    h("summary", {}, withPreview ? "description, severities, preview" : "description, severities"),
    h("p", { class: "op-doc" }, firstParagraph(op.description ?? op.doc)),
    severityTable(op),
    withPreview ? h("div", { class: "preview-box" }, previewSeverity, previewMessage, image) : null,
  );
  const aliases = (op.aliases ?? []).length ? ` (${op.aliases.join(", ")})` : "";
  const relation = op.relation ?? op.relation_kind ?? "";
  const row = h(
    "div",
    { class: "op-row", dataset: { operator: op.name } },
    h(
      "div",
      { class: "op-head" },
      h("label", { class: "op-name" }, check, ` ${op.name}`, h("span", { class: "muted" }, aliases)),
      relation ? h("span", { class: `badge relation-${relation}` }, relation) : null,
      h("span", { class: "op-summary muted" }, firstParagraph(op.description ?? op.doc).split(". ")[0]),
    ),
    h(
      "div",
      { class: "op-options" },
      h("label", {}, modeSeverities, " severities "),
      severityBox,
      h("label", {}, modeConfig, " explicit parameters"),
      configBox,
    ),
    details,
  );
  return {
    op,
    row,
    checked: () => check.checked,
    // {choice} or {error, element}
    read() {
      if (modeConfig.checked) {
        const config = {};
        for (const field of fields) {
          const result = field.read();
          if (result.error) return { error: result.error, element: field.element };
          if (!field.isDefault(result.value)) config[field.name] = result.value;
        }
        return { choice: { name: op.name, config } };
      }
      const severities = severityChecks.map((l) => l.querySelector("input")).filter((i) => i.checked).map((i) => Number(i.value));
      if (!severities.length) return { error: "pick at least one severity", element: severityBox };
      return { choice: { name: op.name, severities } };
    },
    fieldElement(param) {
      if (param === "severities") return severityBox;
      return fields.find((f) => f.name === param)?.element;
    },
  };
}

function showFieldError(element, message) {
  element.classList.add("invalid");
  const error = h("div", { class: "field-error", testid: "field-error" }, message);
  element.after(error);
  return error;
}

export async function newTaskPage(root) {
  root.append(h("div", { class: "page-head" }, h("h1", {}, "New task")), h("p", { class: "muted" }, "Loading the catalogue…"));
  const [operators, cameraOperators, relations, datasets, models, sequenceSystems] = await Promise.all([
    api("/api/operators"),
    api("/api/operators?modality=camera").catch(() => ({ families: [] })),
    api("/api/relations").catch(() => []),
    api("/api/datasets"),
    api("/api/models"),
    api("/api/sequence-systems").catch(() => ({ items: [] })),
  ]);
  clear(root);
  const previews = new Map();

  const name = h("input", { name: "name", placeholder: "optional", testid: "task-name" });
  // a camera task lists camera data sets and steering systems; the other kinds LiDAR ones
  const datasetItems = listOf(datasets, "datasets");
  const modelItems = listOf(models, "models");
  const dataset = h("select", { name: "dataset", required: true, testid: "task-dataset" });
  const sut = h("select", { name: "sut", required: true, testid: "task-model" });
  function fillPickers(modality) {
    const keep = [dataset.value, sut.value];
    const ofModality = (item) => (item.modality ?? "lidar") === modality;
    dataset.replaceChildren(...datasetItems.filter(ofModality).map((d) => h("option", { value: d.name }, `${d.name}${d.frame_count ? ` (${d.frame_count} frames)` : ""}`)));
    sut.replaceChildren(...modelItems.filter(ofModality).map((m) => h("option", { value: m.name }, `${m.name} — ${m.spec ?? ""}`)));
    for (const [select, value] of [[dataset, keep[0]], [sut, keep[1]]]) {
      if ([...select.options].some((o) => o.value === value)) select.value = value;
    }
  }
  fillPickers("lidar");
  const seed = h("input", { name: "seed", type: "number", value: 0, min: 0, step: 1, required: true, testid: "task-seed" });
  const trials = h("input", { name: "trials", type: "number", value: 1, min: 1, max: 100, step: 1, testid: "task-trials" });
  const frames = h("input", { name: "frames", type: "number", min: 1, step: 1, placeholder: "all", testid: "task-frames" });
  const kind = h("select", { name: "kind", testid: "task-kind" }, ["mutation", "guided", "fuzz", "structural", "camera"].map((k) => h("option", { value: k }, k)));
  const budget = h("input", { name: "budget", type: "number", value: 0, min: 0, max: 100000, step: 1, testid: "task-budget" });
  const search = h("textarea", { rows: 2, placeholder: '{"budget": 50, "criteria": ["nc:0.2"]}', hidden: true });
  const structural = structuralFields(sequenceSystems);

  const rows = [];
  const families = h("div", { class: "families", testid: "operators" });
  for (const [family, ops] of operatorsByFamily(operators)) {
    const group = h("fieldset", { class: "family", dataset: { family } }, h("legend", {}, family));
    for (const op of ops) {
      const row = operatorRow(op, previews);
      rows.push(row);
      group.append(row.row);
    }
    families.append(group);
  }

  // a camera task's image transformations (DeepTest's nine), without previews (those are drawn from above)
  const cameraRows = [];
  const cameraFamilies = h("div", { class: "families", testid: "camera-operators", hidden: true });
  for (const [family, ops] of operatorsByFamily(cameraOperators)) {
    const group = h("fieldset", { class: "family", dataset: { family } }, h("legend", {}, family));
    for (const op of ops) {
      const row = operatorRow(op, previews, false);
      cameraRows.push(row);
      group.append(row.row);
    }
    cameraFamilies.append(group);
  }

  const relationList = listOf(relations, "relations");
  const auto = h("input", { type: "radio", name: "relations", value: "auto", checked: true, testid: "relations-auto" });
  const choose = h("input", { type: "radio", name: "relations", value: "choose", testid: "relations-choose" });
  const relationChecks = relationList.map((r) => ({
    name: r.name,
    input: h("input", { type: "checkbox", value: r.name, testid: `relation-${r.name}` }),
    r,
  }));
  const relationBox = h(
    "div",
    { class: "relations", hidden: true },
    relationChecks.map(({ name: n, input, r }) =>
      h("label", { class: "relation", title: r.description ?? "" }, input, ` ${n}`, h("span", { class: "muted" }, ` ${firstParagraph(r.description).split(". ")[0]}`)),
    ),
  );
  auto.addEventListener("change", () => (relationBox.hidden = true));
  choose.addEventListener("change", () => (relationBox.hidden = false));
  const relationsField = h("div", { class: "relations-field" }, h("label", {}, auto, " auto (every relation that applies to each operator)"), h("label", {}, choose, " choose"), relationBox);

  const message = h("div", { testid: "task-message" });
  const submit = h("button", { type: "submit", class: "primary", testid: "task-submit" }, "Create task");
  const budgetLabel = h("label", { hidden: true, title: "tests Algorithm 1 generates after the transformations (0: no search)" }, "Search budget ", budget);
  const detectionFields = { name, dataset, sut, seed, trials, frames, kind, relations: relationsField, search, "search.budget": budgetLabel, budget: budgetLabel };
  const structuralTopFields = { name, seed, kind, ...structural.fields };
  const isStructural = () => kind.value === "structural";
  const isCamera = () => kind.value === "camera";
  const operatorRows = () => (isCamera() ? cameraRows : rows);

  // what a detection campaign (mutation, guided, fuzz) shows and a structural one does not
  const detectionOnly = [
    h("label", {}, "Data set ", dataset, h("a", { class: "picker-link", href: "#/datasets", testid: "upload-dataset-link" }, "upload or generate a data set")),
    h("label", {}, "Model ", sut, h("a", { class: "picker-link", href: "#/models", testid: "upload-model-link" }, "upload or register a model")),
    h("label", {}, "Trials ", trials),
    h("label", {}, "Frames ", frames),
  ];
  const operatorsHeading = h("h2", {}, "Operators");
  const relationsHeading = h("h2", {}, "Relations");
  const detectionSections = [operatorsHeading, families, cameraFamilies, relationsHeading, relationsField];
  const structuralSection = h("div", { hidden: true }, h("h2", {}, "Logs and code"), structural.element);
  let logsLoaded = false;
  function syncKind() {
    for (const element of [...detectionOnly, ...detectionSections]) element.hidden = isStructural();
    structuralSection.hidden = !isStructural();
    search.hidden = kind.value === "mutation" || isStructural() || isCamera();
    // a camera task: image transformations, DeepTest's relation on the steering angle, a search budget
    families.hidden = isStructural() || isCamera();
    cameraFamilies.hidden = !isCamera();
    relationsHeading.hidden = relationsField.hidden = isStructural() || isCamera();
    operatorsHeading.textContent = isCamera() ? "Image transformations (none checked: DeepTest's nine at severities 1, 3, 5)" : "Operators";
    budgetLabel.hidden = !isCamera();
    fillPickers(isCamera() ? "camera" : "lidar");
    if (isStructural() && !logsLoaded) {
      logsLoaded = true;
      structural.load();
    }
  }
  kind.addEventListener("change", syncKind);

  const form = h(
    "form",
    { class: "new-task", testid: "new-task-form", novalidate: true },
    h(
      "div",
      { class: "card form grid" },
      h("label", {}, "Kind ", kind),
      h("label", {}, "Name ", name),
      detectionOnly.slice(0, 2),
      h("label", {}, "Seed ", seed),
      detectionOnly.slice(2),
      budgetLabel,
      search,
    ),
    detectionSections,
    structuralSection,
    message,
    h("div", { class: "form-actions" }, submit, h("a", { class: "button", href: "#/tasks" }, "Cancel")),
  );

  function clearErrors() {
    for (const el of form.querySelectorAll(".field-error")) el.remove();
    for (const el of form.querySelectorAll(".invalid")) el.classList.remove("invalid");
    clear(message);
  }

  // A server problem → the element it names: "operators.1.severities", "dataset", "seed", …
  // (a "coverage.targets: …" line reads like a file name and its message: without a line number it is a field)
  const fieldOf = (problem) => problem.field ?? (problem.line === undefined ? (problem.file ?? "") : "");
  function elementFor(problem, chosen) {
    const path = fieldOf(problem);
    const text = `${path} ${problem.message}`;
    const match = /operators\.(\d+)(?:\.(?:config\.)?([A-Za-z_]\w*))?/.exec(text);
    if (match) {
      const row = chosen[Number(match[1])];
      if (row) return (match[2] && row.fieldElement(match[2])) || row.row.querySelector(".op-options");
    }
    for (const [key, element] of Object.entries(isStructural() ? structuralTopFields : detectionFields)) {
      if (path === key || path.startsWith(`${key}.`) || new RegExp(`(^|\\s)${key}(\\.\\w+)*:`).test(text)) {
        return element.closest("label") ?? element;
      }
    }
    return null;
  }

  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    clearErrors();
    const chosen = isStructural() ? [] : operatorRows().filter((r) => r.checked());
    const body = { dataset: dataset.value, sut: sut.value, kind: kind.value };
    if (name.value.trim()) body.name = name.value.trim();
    let ok = true;
    const fail = (element, text) => {
      showFieldError(element, text);
      ok = false;
    };
    const numbers = isStructural() ? [["seed", seed]] : [["seed", seed], ["trials", trials], ["frames", frames]];
    for (const [key, input] of numbers) {
      if (input.value.trim() === "") {
        if (key === "seed") fail(input.closest("label"), "seed: a whole number is required");
        continue;
      }
      const value = Number(input.value);
      const min = Number(input.min);
      if (!Number.isInteger(value) || value < min || (input.max && value > Number(input.max))) {
        fail(input.closest("label"), `${key}: a whole number${input.max ? ` from ${min} to ${input.max}` : ` ≥ ${min}`}`);
      } else body[key] = value;
    }
    if (isStructural()) {
      const result = structural.read();
      for (const [element, text] of result.errors ?? []) fail(element, text);
      Object.assign(body, result.body ?? {});
    } else {
      if (!dataset.value) fail(dataset.closest("label"), "register or upload a data set first");
      if (!sut.value) fail(sut.closest("label"), "register a model first");
      body.operators = [];
      for (const row of chosen) {
        const result = row.read();
        if (result.error) fail(result.element, `${row.op.name}: ${result.error}`);
        else body.operators.push(result.choice);
      }
      if (kind.value === "mutation" && !chosen.length) fail(families, "pick at least one operator");
      if (isCamera()) {
        const value = Number(budget.value || 0);
        if (!Number.isInteger(value) || value < 0) fail(budgetLabel, "search budget: a whole number ≥ 0");
        else if (value > 0) body.search = { budget: value };
        body.relations = "auto";
      } else if (choose.checked) {
        const picked = relationChecks.filter((r) => r.input.checked).map((r) => r.name);
        if (!picked.length) fail(relationsField, "pick at least one relation, or auto");
        body.relations = picked;
      } else body.relations = "auto";
      if (kind.value !== "mutation" && !isCamera() && search.value.trim()) {
        try {
          body.search = JSON.parse(search.value);
        } catch {
          fail(search, "search: not valid JSON");
        }
      }
    }
    if (!ok) {
      message.append(notice("error", "Fix the marked fields."));
      form.querySelector(".invalid")?.scrollIntoView({ block: "center" });
      return;
    }
    submit.disabled = true;
    try {
      const reply = await api("/api/tasks", { method: "POST", body });
      go(`/tasks/${reply.id}`);
    } catch (exc) {
      const unplaced = [];
      for (const problem of exc.problems.length ? exc.problems : [{ message: exc.message }]) {
        const element = elementFor(problem, chosen);
        const field = fieldOf(problem);
        if (element) showFieldError(element, field && !problem.message.includes(field) ? `${field}: ${problem.message}` : problem.message);
        else unplaced.push(problem);
      }
      message.append(notice("error", `The server refused the task (${exc.status}).`, unplaced, "task-error"));
      form.querySelector(".invalid")?.scrollIntoView({ block: "center" });
    } finally {
      submit.disabled = false;
    }
  });

  root.append(h("div", { class: "page-head" }, h("h1", {}, "New task")), form);
  return () => {
    for (const url of previews.values()) URL.revokeObjectURL(url);
  };
}

