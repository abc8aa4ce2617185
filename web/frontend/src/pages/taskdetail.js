// Task detail: status, live progress (server-sent events) overall and per subtask with the operator
// running now, the AP-per-operator chart (a structural task: its coverage tables and views, the page
// the server renders), the subtask table, stop / delete, report and findings.
// The reply's fields and statuses are the ones its JSON Schema declares (../contract.js).
import { api, fetchBlob, subscribe } from "../api.js";
import { apChart, apValue, classesOf } from "../chart.js";
import { statusesOf, taskSchema } from "../contract.js";
import { clear, formatNumber, formatTime, go, h, notice, progressBar, statusBadge } from "../dom.js";

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

  function renderResults() {
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
          // a structural task's subtasks are logs: no AP (their coverage is in the tables above)
          ...(structural ? [] : ["bbox", "bev", "3d"].map((m) => h("td", { class: "num" }, formatNumber(apValue(s, m, view.cls, view.difficulty, view.points))))),
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
      : [
          h("h2", {}, "AP per operator"),
          h("div", { class: "toolbar" }, h("label", {}, "Class ", clsSelect), h("label", {}, "Difficulty ", diffSelect), h("label", {}, "Points ", pointsSelect)),
          chartBox,
        ]),
    h("h2", {}, "Subtasks"),
    h(
      "table",
      { class: "table", testid: "subtasks-table" },
      h("thead", {}, h("tr", {}, ["Subtask", "Status", "Progress", ...(structural ? [] : ["AP bbox", "AP BEV", "AP 3D"])].map((t) => h("th", {}, t)))),
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
