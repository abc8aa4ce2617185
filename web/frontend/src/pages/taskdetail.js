// Task detail: status, live progress (server-sent events) overall and per subtask with the operator
// running now, the AP-per-operator chart (a structural task: its coverage tables and views, the page
// the server renders; a camera task: MSE_orig, Eq. 2 / Eq. 3 per transformation, the guided search's
// coverage and Table 7), the subtask table, stop / delete, report and findings.
// The system's failures (crashes, timeouts, invalid outputs) are shown apart from lidarfuzz's own
// errors (an operator or relation that raised), in the summary line and per subtask; AP shown as "—"
// says why; small samples carry a warning. Stop asks first (in the page); Resume takes a stopped,
// failed or interrupted task up again; a refused action says why until the next one.
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
  // what the last action (stop, resume, delete) said: kept until the next action
  const actionMessage = h("div", { testid: "action-message" });
  const confirmBox = h("div", { testid: "confirm-box" });
  const summaryLine = h("p", { class: "failures-summary", testid: "failures-summary" });
  const warnings = h("div", { testid: "sample-warnings" });
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

  // set only when the tables changed: every refresh setting it again would reload the frame under
  // the user's scroll (and under a test's locator)
  let shownStructural = null;
  async function renderStructural() {
    if (!structural) return;
    try {
      const blob = await fetchBlob(`/api/tasks/${id}/structural`);
      const text = await blob.text();
      if (text !== shownStructural) {
        shownStructural = text;
        coverageFrame.srcdoc = text;
      }
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

  // stopped, failed, or interrupted, and not queued or run now: the server says (task.resumable)
  const resumable = () => Boolean(task.resumable);

  function renderHead() {
    clear(head).append(
      h("h1", { class: "task-title" }, `Task #${task.id}`, task.name ? h("span", { class: "muted" }, ` ${task.name}`) : null),
      statusBadge(task.status),
      h("span", { class: "spacer" }),
      live,
      h("a", { class: "button", href: `#/tasks/${id}/findings`, testid: "findings-link" }, "Findings"),
      h("a", { class: "button", href: `#/tasks/${id}/report`, testid: "report-link" }, "Report"),
      // the thesis's first experiment: people judge original / mutant pairs (point clouds only)
      ...(camera || structural ? [] : [h("a", { class: "button", href: `#/tasks/${id}/rate`, testid: "rate-pairs" }, "Rate pairs")]),
      ...(resumable() ? [h("button", { class: "primary", testid: "resume-task", onclick: resume }, "Resume")] : []),
      h("button", { testid: "stop-task", disabled: isFinished(task.status), onclick: askStop }, "Stop"),
      h("button", { class: "danger", testid: "delete-task", onclick: askRemove }, "Delete"),
    );
    clear(facts).append(
      ...[
        ["Data set", task.dataset],
        ["SUT", task.model],
        ["Kind", task.kind],
        ...(structural ? [] : [["Operators", task.operator_count]]),
        ...(camera ? [["MSE_orig", mseOrigText(task.camera)]] : []),
        ["Seed", task.seed],
        ...(task.tags?.length ? [["Tags", h("span", { class: "chips", testid: "task-tags" }, task.tags.map((t) => h("span", { class: "chip" }, t)))]] : []),
        ...(task.notes ? [["Notes", h("span", { class: "wrap-code", testid: "task-notes" }, task.notes)]] : []),
        ["Created", formatTime(task.created_at)],
        ["Started", formatTime(task.started_at)],
        ["Finished", formatTime(task.finished_at)],
      ].flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, v instanceof Node ? v : String(v))]),
    );
    clear(overall).append(h("span", { class: "label" }, "Overall"), progressBar(task.done, task.total, "overall-progress"));
    const now = task.running;
    clear(running);
    if (loadingSystem()) {
      running.append(h("span", { class: "label" }, "Running now"), h("strong", { testid: "loading-system" }, `loading the system under test (${task.model})…`));
    } else if (now && !isFinished(task.status)) {
      running.append(
        h("span", { class: "label" }, "Running now"),
        h("strong", { testid: "running-operator" }, now.label),
        now.total ? progressBar(now.done, now.total, "running-progress") : null,
      );
    }
    clear(message);
    // a final status with an error failed; an error on a task still to run is why it was interrupted
    if (task.error) message.append(notice(isFinished(task.status) ? "error" : "warning", task.error, [], "task-error"));
    renderSummary();
  }

  // running, and no unit of this run done yet: the task's reply and its events say so (lidarfuzz.web.events)
  function loadingSystem() {
    return Boolean(task.loading);
  }

  // The summary line: the system's failures and lidarfuzz's own errors, summed over the subtasks
  // the table lists (so the two agree); the small-sample warnings of the subtasks and the summary.
  function renderSummary() {
    const subs = task.subtasks ?? [];
    const failures = subs.reduce((n, s) => n + (s.failures ?? 0), 0);
    const operatorErrors = subs.reduce((n, s) => n + (s.tool_errors?.operator_error ?? 0), 0);
    const oracleErrors = subs.reduce((n, s) => n + (s.tool_errors?.oracle_error ?? 0), 0);
    const dataFaults = subs.reduce((n, s) => n + (s.tool_errors?.data_error ?? 0), 0);
    clear(summaryLine).append(
      h("span", { testid: "system-failures", dataset: { count: failures } }, `The system failed on ${failures} ${failures === 1 ? "unit" : "units"} (crashes, timeouts, invalid outputs).`),
      " ",
      h(
        "span",
        { class: operatorErrors + oracleErrors ? "tool-errors" : "muted", testid: "tool-errors", dataset: { count: operatorErrors + oracleErrors } },
        operatorErrors + oracleErrors
          ? `lidarfuzz's own errors, not the system's: ${operatorErrors} operator ${operatorErrors === 1 ? "error" : "errors"}, ${oracleErrors} oracle ${oracleErrors === 1 ? "error" : "errors"}.`
          : "No errors of lidarfuzz's own.",
      ),
      ...(dataFaults
        ? [" ", h("span", { class: "tool-errors", testid: "data-faults", dataset: { count: dataFaults } }, `${dataFaults} ${dataFaults === 1 ? "unit" : "units"} whose frame could not be read: data faults, not the system's, left out of AP (restore the files and resume).`)]
        : []),
    );
    const lines = [...(task.summary?.ap_warnings ?? [])];
    if (!lines.length) for (const s of subs) for (const w of s.sample_warnings ?? []) lines.push(`${s.label}: ${w}`);
    clear(warnings);
    if (lines.length) warnings.append(notice("warning", "Small samples: these AP figures may not mean what they seem.", lines.map((message) => ({ message })), "ap-warnings"));
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

  // why a subtask's AP is "—": not complete yet, the note the server gives, or what is missing
  function apReason(s) {
    if (!isFinished(s.status)) return "AP when the subtask completes";
    if (s.ap_note) return s.ap_note;
    if (s.frames > 0 && (s.failures ?? 0) + Object.values(s.tool_errors ?? {}).reduce((a, b) => a + b, 0) >= s.frames) return "no AP: no frame gave an output to score";
    return "no AP: the data set has no labels";
  }

  const toolErrorCount = (s) => Object.values(s.tool_errors ?? {}).reduce((a, b) => a + b, 0);
  const toolErrorText = (s) => {
    const e = s.tool_errors ?? {};
    const parts = [["operator", e.operator_error ?? 0], ["oracle", e.oracle_error ?? 0], ["data fault", e.data_error ?? 0]].filter(([, n]) => n).map(([k, n]) => `${n} ${k}`);
    return parts.length ? parts.join(", ") : "0";
  };

  // the columns every kind shares: the system's failures, lidarfuzz's errors, the times, the view link
  function sharedCells(s) {
    return [
      h("td", { class: "num", testid: "subtask-failures", title: "the system's crashes, timeouts and invalid outputs" }, String(s.failures ?? 0)),
      h("td", { class: toolErrorCount(s) ? "num tool-errors" : "num", testid: "subtask-tool-errors", title: "not the system's: lidarfuzz's own errors (an operator or a relation raised) and data faults (a frame could not be read)" }, toolErrorText(s)),
      h("td", { class: "time", testid: "subtask-started" }, formatTime(s.started_at)),
      h("td", { class: "time", testid: "subtask-finished" }, formatTime(s.finished_at)),
      h("td", {}, h("a", { href: `#/tasks/${id}/findings?subtask=${s.id}`, testid: "subtask-view" }, "view")),
    ];
  }

  function apCells(s) {
    const values = ["bbox", "bev", "3d"].map((m) => apValue(s, m, view.cls, view.difficulty, view.points));
    const cells = values.map((v) => h("td", { class: "num" }, formatNumber(v)));
    const notes = [];
    if (values.every((v) => v === null)) notes.push(h("span", { class: "ap-note", testid: "ap-note" }, apReason(s)));
    // the subjects in a line (which classes, or "a single frame"), each warning in full when unfolded
    const warned = s.sample_warnings ?? [];
    if (warned.length) {
      const subjects = warned.map((w) => (w.startsWith("AP from a single frame") ? "one frame" : w.split(":", 1)[0]));
      notes.push(
        h(
          "details",
          { class: "sample-warning", testid: "sample-warning" },
          h("summary", {}, `⚠ small sample: ${subjects.join(", ")}`),
          warned.map((w) => h("div", {}, w)),
        ),
      );
    }
    return [...cells, h("td", { class: "notes" }, notes)];
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
          ...(camera ? cameraCells(s) : structural ? [] : apCells(s)),
          ...sharedCells(s),
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

  // An in-page question with two buttons (a window.confirm cannot be styled, and blocks the page).
  function ask(text, yes, action) {
    clear(actionMessage);
    clear(confirmBox).append(
      h(
        "div",
        { class: "notice notice-warning confirm", role: "alertdialog" },
        h("span", {}, text),
        h("button", { class: "danger", testid: "confirm-yes", onclick: () => (clear(confirmBox), action()) }, yes),
        h("button", { testid: "confirm-no", onclick: () => clear(confirmBox) }, "Cancel"),
      ),
    );
    confirmBox.querySelector("[data-testid=confirm-yes]").focus();
  }

  // the answer to an action, kept until the next one
  const said = (kind, text) => clear(actionMessage).append(notice(kind, text, [], kind === "error" ? "action-error" : "action-notice"));

  const askStop = () => ask(`Stop task #${id}? What is done is kept; Resume goes on from there.`, "Stop the task", stop);
  const askRemove = () => ask(`Delete task #${id} and all its results?`, "Delete", remove);

  async function stop() {
    try {
      const reply = await api(`/api/tasks/${id}/stop`, { method: "POST" });
      said(reply.refused ? "error" : "ok", reply.message);
    } catch (exc) {
      said("error", `Stop refused: ${exc.message}`);
    }
    refresh();
  }

  async function resume() {
    clear(confirmBox);
    try {
      const reply = await api(`/api/tasks/${id}/resume`, { method: "POST" });
      said(reply.refused ? "error" : "ok", reply.message);
      if (!reply.refused) {
        task.status = reply.status; // not final any more: its events are followed again
        subscribeEvents();
      }
    } catch (exc) {
      said("error", `Resume refused: ${exc.message}`);
    }
    refresh();
  }

  async function remove() {
    try {
      await api(`/api/tasks/${id}`, { method: "DELETE" });
      go("/tasks");
    } catch (exc) {
      said("error", `Delete refused: ${exc.message}`);
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
    connected(true);
    renderHead();
    const ended = isFinished(task.status) && !isFinished(previous);
    if (newSubtask || ended) {
      // AP of a finished subtask, or the final figures: the full record has them
      refreshing ??= refresh().finally(() => (refreshing = null));
    } else renderResults();
    if (isFinished(task.status)) closeStream();
  }

  // "live" while the server answers; "disconnected — retrying" while it does not (the events'
  // connection broke, or a poll failed), until it answers again
  function connected(ok) {
    live.dataset.state = ok ? "live" : "disconnected";
    live.classList.toggle("disconnected", !ok);
    live.textContent = ok ? `live · ${formatTime(new Date().toISOString()).slice(11)}` : "disconnected — retrying";
  }

  let source = null;
  let poll = null;
  function closeStream() {
    source?.close();
    source = null;
    if (isFinished(task.status)) {
      live.textContent = "";
      delete live.dataset.state;
    }
  }
  function startPolling() {
    if (poll) return;
    poll = setInterval(async () => {
      try {
        task = await api(`/api/tasks/${id}`);
        connected(true);
      } catch {
        connected(false);
        return;
      }
      renderHead();
      renderResults();
      if (!isFinished(task.status)) {
        // the server is back: live events again
        clearInterval(poll);
        poll = null;
        subscribeEvents();
      } else {
        clearInterval(poll);
        poll = null;
        closeStream();
      }
    }, 2000);
  }
  function subscribeEvents() {
    if (source || isFinished(task.status)) return;
    source = subscribe(`/api/tasks/${id}/events`, {
      progress: onProgress,
      message: onProgress,
      open: () => connected(true),
      end: () => {
        closeStream();
        refresh();
      },
      error: () => {
        // the connection broke (the server stopped, the network): say so; the browser retries an
        // open stream by itself, a closed one is polled until the server answers
        connected(false);
        if (source && source.readyState === EventSource.CLOSED) {
          source = null;
          startPolling();
        }
      },
    });
  }
  subscribeEvents();

  root.append(
    head,
    confirmBox,
    actionMessage,
    message,
    summaryLine,
    warnings,
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
      h(
        "thead",
        {},
        h(
          "tr",
          {},
          [
            "Subtask",
            "Status",
            "Progress",
            ...(camera ? ["MSE_t", "MSE_t − MSE_orig", "Violate Eq. 2", "Eq. 3"] : structural ? [] : ["AP bbox", "AP BEV", "AP 3D", "Notes"]),
            "System failures",
            "lidarfuzz errors",
            "Started",
            "Finished",
            "",
          ].map((t) => h("th", {}, t)),
        ),
      ),
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
