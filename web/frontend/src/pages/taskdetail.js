// Task detail: status, live progress (server-sent events) overall and per subtask with the operator
// running now, the AP-per-operator chart (a structural task: its coverage tables and views, the page
// the server renders; a camera task: MSE_orig, Eq. 2 / Eq. 3 per transformation, the guided search's
// coverage and Table 7), the subtask table, stop / delete, report and findings.
// The reply's fields and statuses are the ones its JSON Schema declares (../contract.js).
import { api, fetchBlob, subscribe } from "../api.js";
import { apChart, apValue, classesOf } from "../chart.js";
import { statusesOf, taskSchema } from "../contract.js";
import { clear, formatNumber, formatTime, go, h, notice, progressBar, statusBadge } from "../dom.js";
import { eq3Verdict } from "./finding.js";

const fmt = (value) => (value === null || value === undefined || Number.isNaN(value) ? "—" : Number(value).toPrecision(4));
const percent = (value) => (value === null || value === undefined ? "—" : `${(100 * value).toFixed(1)} %`);
const mseOrigText = (info) => (info?.mse_orig === null || info?.mse_orig === undefined ? "—" : `${fmt(info.mse_orig)} (${info.labelled} labelled images)`);

export async function taskDetailPage(root, id) {
  const [schema, reply] = await Promise.all([taskSchema(), api(`/api/tasks/${id}`)]);
  const { isFinished } = statusesOf(schema);
  let task = reply;
  const view = { cls: "Car", difficulty: "moderate", points: "R40" };

  const head = h("div", { class: "page-head" });
  const facts = h("dl", { class: "facts", testid: "task-facts" });
  const overall = h("div", { class: "overall" });
  const running = h("div", { class: "running", testid: "running-now" });
  const message = h("div");
  const chartBox = h("div", { testid: "ap-chart-box" });
  const tableBody = h("tbody", { testid: "subtasks-body" });
  const live = h("span", { class: "live muted", testid: "live" });
  const structural = task.kind === "structural";
  // a camera task (DeepTest on a steering system): MSE_orig, Eq. 2 / Eq. 3 per transformation and the
  // search's coverage instead of AP
  const camera = task.modality === "camera";
  const cameraBox = h("div", { testid: "camera-figures" });
  // a structural task's tables and views (GET /api/tasks/{id}/structural), sandboxed as the report is
  const coverageFrame = h("iframe", { class: "report-frame", title: `coverage of task ${id}`, testid: "structural-frame", sandbox: "allow-popups" });

  async function renderStructural() {
    if (!structural) return;
    try {
      const blob = await fetchBlob(`/api/tasks/${id}/structural`);
      coverageFrame.srcdoc = await blob.text();
    } catch (exc) {
      clear(message).append(notice("error", exc.message));
    }
  }

  const clsSelect = h("select", { testid: "chart-class" });
  const diffSelect = h("select", { testid: "chart-difficulty" }, ["easy", "moderate", "hard"].map((d) => h("option", { value: d, selected: d === view.difficulty }, d)));
  const pointsSelect = h("select", { testid: "chart-points" }, ["R40", "R11"].map((p) => h("option", { value: p }, `AP|${p}`)));
  for (const [select, key] of [[clsSelect, "cls"], [diffSelect, "difficulty"], [pointsSelect, "points"]]) {
    select.addEventListener("change", () => {
      view[key] = select.value;
      renderResults();
    });
  }

  function renderHead() {
    clear(head).append(
      h("h1", {}, `Task #${task.id}`, task.name ? h("span", { class: "muted" }, ` ${task.name}`) : null),
      statusBadge(task.status),
      h("span", { class: "spacer" }),
      live,
      h("a", { class: "button", href: `#/tasks/${id}/findings`, testid: "findings-link" }, "Findings"),
      h("a", { class: "button", href: `#/tasks/${id}/report`, testid: "report-link" }, "Report"),
      h("button", { testid: "stop-task", disabled: isFinished(task.status), onclick: stop }, "Stop"),
      h("button", { class: "danger", testid: "delete-task", onclick: remove }, "Delete"),
    );
    clear(facts).append(
      ...[
        ["Data set", task.dataset],
        ["SUT", task.model],
        ["Kind", task.kind],
        ...(structural ? [] : [["Operators", task.operator_count]]),
        ...(camera ? [["MSE_orig", mseOrigText(task.camera)]] : []),
        ["Seed", task.seed],
        ["Created", formatTime(task.created_at)],
        ["Started", formatTime(task.started_at)],
        ["Finished", formatTime(task.finished_at)],
      ].flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, String(v))]),
    );
    clear(overall).append(h("span", { class: "label" }, "Overall"), progressBar(task.done, task.total, "overall-progress"));
    const now = task.running;
    clear(running);
    if (now && !isFinished(task.status)) {
      running.append(
        h("span", { class: "label" }, "Running now"),
        h("strong", { testid: "running-operator" }, now.label),
        now.total ? progressBar(now.done, now.total, "running-progress") : null,
      );
    }
    clear(message);
    if (task.error) message.append(notice("error", task.error));
  }

  function renderCamera() {
    clear(cameraBox);
    const info = task.camera ?? {};
    cameraBox.append(
      h(
        "p",
        { testid: "mse-orig" },
        info.mse_orig === null || info.mse_orig === undefined
          ? "MSE_orig appears once the original images ran (no labelled image: Eq. 2 judges nothing)."
          : `MSE_orig = ${fmt(info.mse_orig)}: the system's mean squared error against the labels over ${info.labelled} labelled of ${info.images} original images. An image violates Eq. 2 when (label − prediction)² > λ · MSE_orig; Eq. 3 keeps a transformation's violations when |MSE_t − MSE_orig| ≤ ε.`,
      ),
    );
    const guided = task.subtasks.find((s) => s.name === "guided");
    if (guided) {
      const seeds = info.seed_coverage ?? {};
      const after = guided.search?.coverage ?? {};
      const names = [...new Set([...Object.keys(seeds), ...Object.keys(after)])];
      const stats = guided.search?.stats ?? {};
      cameraBox.append(
        h("h3", {}, "Guided search: neuron coverage"),
        names.length
          ? h(
              "table",
              { class: "table compact", testid: "search-coverage" },
              h("thead", {}, h("tr", {}, ["Criterion", "Seed images", "After the search"].map((t) => h("th", {}, t)))),
              h("tbody", {}, names.map((n) => h("tr", { dataset: { criterion: n } }, h("td", {}, n.toUpperCase()), h("td", { class: "num" }, percent(seeds[n])), h("td", { class: "num" }, percent(after[n]))))),
            )
          : h("p", { class: "muted" }, "Coverage appears as the search runs."),
        stats.tests !== undefined
          ? h("p", { class: "muted", testid: "search-stats" }, `${stats.tests} tests: ${stats.accepted ?? 0} kept (new coverage), ${stats.violating ?? 0} violating Eq. 2, ${stats.findings ?? 0} unique findings.`)
          : null,
      );
    }
    const table7 = task.summary?.deeptest;
    if (table7?.counts?.length) {
      cameraBox.append(
        h("h3", {}, `Erroneous behaviours (Table 7's form; λ = ${table7.configured_lambda}, ε = ${table7.configured_epsilon} configured)`),
        h(
          "table",
          { class: "table compact", testid: "table7" },
          h("thead", {}, h("tr", {}, h("th", {}, "λ"), table7.epsilons.map((e) => h("th", {}, `ε ${e}`)), h("th", {}, "no filter"))),
          h(
            "tbody",
            {},
            table7.lambdas.map((lam, i) => h("tr", {}, h("td", {}, String(lam)), table7.counts[i].map((c) => h("td", { class: "num" }, String(c))), h("td", { class: "num" }, String(table7.unfiltered[i])))),
          ),
        ),
      );
    }
  }

  function cameraCells(s) {
    const d = s.deeptest;
    if (s.name === "original") return [h("td", { class: "num" }, fmt(task.camera?.mse_orig)), h("td", {}, "—"), h("td", {}, "—"), h("td", {}, "the originals")];
    if (!d) return [h("td", {}, "—"), h("td", {}, "—"), h("td", {}, "—"), h("td", { class: "muted" }, isFinished(s.status) ? "no labelled image judged" : "when complete")];
    return [
      h("td", { class: "num" }, fmt(d.mse)),
      h("td", { class: "num" }, fmt(d.mse - d.mse_orig)),
      h("td", { class: "num", testid: "eq2-violations" }, `${d.violated}/${d.mutants}`),
      h("td", { testid: "eq3-verdict" }, eq3Verdict(!d.filtered ? "not_filtered" : d.kept ? "kept" : "filtered_out", d.configured_epsilon)),
    ];
  }

  function renderResults() {
    renderCamera();
    const subtasks = task.subtasks;
    const classes = classesOf(subtasks);
    const options = classes.length ? [...classes, "mAP"] : ["Car", "Pedestrian", "Cyclist", "mAP"];
    if (!options.includes(view.cls)) view.cls = options[0];
    clear(clsSelect).append(...options.map((c) => h("option", { value: c, selected: c === view.cls }, c)));
    clear(chartBox);
    const withAp = subtasks.filter((s) => apValue(s, "bbox", view.cls, view.difficulty, view.points) !== null || apValue(s, "3d", view.cls, view.difficulty, view.points) !== null);
    if (withAp.length) chartBox.append(apChart(subtasks, { ...view, width: chartBox.clientWidth - 20 }));
    else chartBox.append(h("p", { class: "muted" }, "AP appears here as subtasks finish."));
    clear(tableBody);
    for (const s of subtasks) {
      tableBody.append(
        h(
          "tr",
          { testid: "subtask-row", dataset: { label: s.label, status: s.status } },
          h("td", {}, s.label),
          h("td", {}, statusBadge(s.status)),
          h("td", { class: "progress-cell" }, progressBar(s.done, s.total, "subtask-progress")),
          // a structural task's subtasks are logs: no AP (their coverage is in the tables above); a camera task's: DeepTest's figures
          ...(camera ? cameraCells(s) : structural ? [] : ["bbox", "bev", "3d"].map((m) => h("td", { class: "num" }, formatNumber(apValue(s, m, view.cls, view.difficulty, view.points))))),
        ),
      );
    }
  }

  async function refresh() {
    try {
      task = await api(`/api/tasks/${id}`);
    } catch (exc) {
      clear(message).append(notice("error", exc.message));
      return;
    }
    renderHead();
    renderResults();
    renderStructural();
  }

  async function stop() {
    try {
      await api(`/api/tasks/${id}/stop`, { method: "POST" });
    } catch (exc) {
      clear(message).append(notice("error", exc.message));
    }
    refresh();
  }

  async function remove() {
    if (!window.confirm(`Delete task #${id} and all its results?`)) return;
    try {
      await api(`/api/tasks/${id}`, { method: "DELETE" });
      go("/tasks");
    } catch (exc) {
      clear(message).append(notice("error", exc.message));
    }
  }

  // Merge one progress event (lidarfuzz.web.events.progress_snapshot: the task's counters and
  // status, its subtasks' counters and statuses, the subtask running now).
  let refreshing = null;
  function onProgress(event) {
    if (!event || typeof event !== "object") return;
    const previous = task.status;
    const { subtasks, ...counters } = event;
    Object.assign(task, counters);
    let newSubtask = false;
    for (const sub of subtasks ?? []) {
      const mine = task.subtasks.find((s) => s.id === sub.id);
      if (mine) {
        const finishedNow = sub.status !== mine.status && isFinished(sub.status);
        Object.assign(mine, sub);
        newSubtask ||= finishedNow;
      } else newSubtask = true;
    }
    live.textContent = `live · ${new Date().toLocaleTimeString()}`;
    renderHead();
    const ended = isFinished(task.status) && !isFinished(previous);
    if (newSubtask || ended) {
      // AP of a finished subtask, or the final figures: the full record has them
      refreshing ??= refresh().finally(() => (refreshing = null));
    } else renderResults();
    if (isFinished(task.status)) closeStream();
  }

  let source = null;
  let poll = null;
  function closeStream() {
    source?.close();
    source = null;
    live.textContent = isFinished(task.status) ? "" : live.textContent;
  }
  if (!isFinished(task.status)) {
    source = subscribe(`/api/tasks/${id}/events`, {
      progress: onProgress,
      message: onProgress,
      end: () => {
        closeStream();
        refresh();
      },
      error: () => {
        // the stream ended (the task finished) or the connection broke: poll until it finishes
        closeStream();
        if (!poll) {
          poll = setInterval(async () => {
            await refresh();
            if (isFinished(task.status)) {
              clearInterval(poll);
              poll = null;
            }
          }, 2000);
        }
      },
    });
  }

  root.append(
    head,
    message,
    facts,
    overall,
    running,
    ...(structural
      ? [h("h2", {}, "Structural coverage"), coverageFrame]
      : camera
        ? [h("h2", {}, "DeepTest: Eq. 2 and Eq. 3 on the steering angle"), cameraBox]
        : [
          h("h2", {}, "AP per operator"),
          h("div", { class: "toolbar" }, h("label", {}, "Class ", clsSelect), h("label", {}, "Difficulty ", diffSelect), h("label", {}, "Points ", pointsSelect)),
          chartBox,
        ]),
    h("h2", {}, "Subtasks"),
    h(
      "table",
      { class: "table", testid: "subtasks-table" },
      h("thead", {}, h("tr", {}, ["Subtask", "Status", "Progress", ...(camera ? ["MSE_t", "MSE_t − MSE_orig", "Violate Eq. 2", "Eq. 3"] : structural ? [] : ["AP bbox", "AP BEV", "AP 3D"])].map((t) => h("th", {}, t)))),
      tableBody,
    ),
  );
  renderHead();
  renderResults();
  renderStructural();
  return () => {
    closeStream();
    if (poll) clearInterval(poll);
  };
}
