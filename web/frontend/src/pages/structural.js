// The New task form's fields for a structural task (Neves et al.'s environment, docs/structural.md):
// the field-test logs (registered data sets with order, GET /api/datasets/logs), the sequence system
// and the code it covers (GET /api/sequence-systems proposes targets per system), heuristics,
// strategies and the segment size. They read into the campaign keys dataset, logs, sut,
// coverage.targets, heuristics, strategies and segments.
import { api, listOf } from "../api.js";
import { clear, h } from "../dom.js";

const firstSentence = (text) => String(text ?? "").replace(/``/g, "").split(/(?<=\.)\s/)[0];

function checkList(items, prefix) {
  return items.map((item) => ({
    name: item.name,
    input: h("input", { type: "checkbox", value: item.name, checked: true, testid: `${prefix}-${item.name}` }),
    description: item.description ?? "",
  }));
}

function checkBox(checks, testid) {
  return h(
    "div",
    { class: "check-list", testid },
    checks.map(({ name, input, description }) =>
      h("label", { class: "check", title: description }, input, ` ${name}`, description ? h("span", { class: "muted" }, ` ${description}`) : null),
    ),
  );
}

// `catalogue`: the reply of GET /api/sequence-systems. Returns {element, fields (campaign key →
// element, for the server's errors), load() (fetches the logs; called when the kind is chosen),
// read() → {body} or {errors: [[element, message]]}}.
export function structuralFields(catalogue) {
  const systems = listOf(catalogue, "items");
  const system = h(
    "select",
    { name: "sut", testid: "task-sequence-system" },
    systems.map((s) => h("option", { value: s.name, title: s.description ?? "" }, s.name)),
  );
  const systemHelp = h("div", { class: "muted system-help", testid: "sequence-system-help" });
  const targets = h("textarea", { name: "targets", rows: 3, spellcheck: false, testid: "task-targets", placeholder: "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process" });
  // the proposed targets follow the system until the user edits them
  let edited = false;
  const propose = () => {
    systemHelp.textContent = firstSentence(systems.find((s) => s.name === system.value)?.description);
    if (!edited) targets.value = (systems.find((s) => s.name === system.value)?.targets ?? []).join("\n");
  };
  targets.addEventListener("input", () => (edited = targets.value.trim() !== ""));
  system.addEventListener("change", propose);
  propose();

  const heuristics = checkList(catalogue?.heuristics ?? [], "heuristic");
  const strategies = checkList(catalogue?.strategies ?? [], "strategy");
  const heuristicBox = checkBox(heuristics, "task-heuristics");
  const strategyBox = checkBox(strategies, "task-strategies");
  const segments = h("input", { name: "segments", type: "number", value: catalogue?.segments ?? 5, min: 1, step: 1, testid: "task-segments" });

  const logBox = h("div", { class: "check-list", testid: "task-logs" }, h("span", { class: "muted" }, "Loading the logs…"));
  let logChecks = [];
  async function load() {
    let reply;
    try {
      reply = await api("/api/datasets/logs");
    } catch (exc) {
      clear(logBox).append(h("span", { class: "field-error" }, `cannot list the logs: ${exc.message}`));
      return;
    }
    const before = new Set(logChecks.filter((c) => c.input.checked).map((c) => c.name));
    const logs = listOf(reply, "items");
    logChecks = logs.map((log, index) => ({
      name: log.name,
      input: h("input", { type: "checkbox", value: log.name, checked: before.size ? before.has(log.name) : index === 0, testid: `log-${log.name}` }),
      log,
    }));
    const refused = reply?.refused ?? [];
    clear(logBox).append(
      ...logChecks.map(({ name, input, log }) => h("label", { class: "check" }, input, ` ${name}`, h("span", { class: "muted" }, ` ${log.frame_count} frames, ordered by ${log.order.replace("_", " ")}`))),
      logs.length ? "" : h("div", { class: "muted" }, "No registered data set is a log (a data set with order): register a drive log, e.g. one from lidarfuzz gen --drive --sensor VLP-16."),
      refused.length
        ? h(
            "div",
            { class: "muted not-logs", testid: "not-logs" },
            "Not logs: ",
            refused.map((r, i) => [i ? ", " : "", h("span", { title: r.reason }, r.name)]),
          )
        : null,
    );
  }

  const element = h(
    "div",
    { class: "card form structural-fields", testid: "structural-fields" },
    h("div", { class: "field" }, h("div", { class: "field-label" }, "Field-test logs (replayed in this order)"), logBox),
    h("div", { class: "field" }, h("label", {}, "Sequence system ", system), systemHelp),
    h("div", { class: "field wide" }, h("div", { class: "field-label" }, "Code to cover (one target a line: pkg.module, pkg.module:Class or pkg.module:Class.method)"), targets),
    h("div", { class: "field" }, h("div", { class: "field-label" }, "Heuristics (each selects a base log)"), heuristicBox),
    h(
      "div",
      { class: "field" },
      h("div", { class: "field-label" }, "Strategies (each generates a log from a base log's segments)"),
      strategyBox,
      h("label", {}, "Segment size (frames) ", segments),
    ),
  );

  function read() {
    const errors = [];
    const chosenLogs = logChecks.filter((c) => c.input.checked).map((c) => c.name);
    if (!chosenLogs.length) errors.push([logBox, "dataset: pick at least one field-test log"]);
    if (!system.value) errors.push([system.closest("label"), "sut: no sequence system is registered"]);
    const lines = targets.value.split("\n").map((line) => line.trim()).filter(Boolean);
    if (!lines.length) errors.push([targets, "coverage.targets: name the code to cover, one target a line"]);
    const pickedHeuristics = heuristics.filter((c) => c.input.checked).map((c) => c.name);
    if (!pickedHeuristics.length) errors.push([heuristicBox, "heuristics: pick at least one"]);
    const pickedStrategies = strategies.filter((c) => c.input.checked).map((c) => c.name);
    if (!pickedStrategies.length) errors.push([strategyBox, "strategies: pick at least one"]);
    const size = Number(segments.value);
    if (segments.value.trim() === "" || !Number.isInteger(size) || size < 1) errors.push([segments.closest("label"), "segments: a whole number ≥ 1"]);
    if (errors.length) return { errors };
    const [dataset, ...logs] = chosenLogs;
    const body = { dataset, sut: system.value, coverage: { targets: lines }, heuristics: pickedHeuristics, strategies: pickedStrategies, segments: size };
    if (logs.length) body.logs = logs;
    return { body };
  }

  // campaign key → the element its errors go next to
  const fields = { dataset: logBox, logs: logBox, sut: system, coverage: targets, heuristics: heuristicBox, strategies: strategyBox, segments };
  return { element, fields, load, read };
}
