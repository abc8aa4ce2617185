// Tasks: the run tracker. Sortable by any column (the server sorts, in SQL), searchable, filtered by
// status and tags; status, search, tags, sort and page are kept in the address (#/tasks?status=done&q=fog
// &sort=-map), so a reload or a shared link shows the same list. Tags and notes are edited in place
// (PATCH /api/tasks/{id}); tasks ticked in the list open side by side in #/compare?tasks=3,5.
// The statuses (the filter's choices, which ones still move) come from the task schema (../contract.js).
import { api, query } from "../api.js";
import { statusesOf, taskSchema } from "../contract.js";
import { clear, emptyRow, every, formatTime, go, h, notice, progressBar, statusBadge } from "../dom.js";

const PAGE = 50;
const MAP_TITLE = "mAP of the originals: 3D, moderate, AP|R40 (%)";
const DELTA_TITLE =
  "worst ΔmAP over the mutants: the lowest (mutant − originals) 3D mAP, moderate, AP|R40, over every operator × severity";

// [label, sort key (null: not sortable), title, class]
const COLUMNS = [
  ["", null, "tick two or more tasks to compare them (the first ticked is the baseline)"],
  ["ID", "id"],
  ["Name", "name", "the task's name; its tags and notes below"],
  ["Status", "status"],
  ["Data set", "dataset"],
  ["System", "model", "the system under test"],
  ["mAP", "map", MAP_TITLE, "num"],
  ["ΔmAP (worst)", "delta_map", DELTA_TITLE, "num"],
  ["Violations", "violations", "violated checks over every relation and mutant (frame level)", "num"],
  ["Failures", "failures", "the system's crashes, timeouts and invalid outputs", "num"],
  ["Started", "started"],
  ["Finished", "finished"],
  ["Progress", "progress"],
  ["", null],
];

// The list's state, read from and written to the address: {status, q, tags[], sort, offset}.
function stateFrom(params) {
  return {
    status: params?.get("status") ?? "",
    q: params?.get("q") ?? "",
    tags: params?.getAll("tag") ?? [],
    sort: params?.get("sort") || "-id",
    offset: Math.max(0, Number(params?.get("offset")) || 0),
  };
}

function addressOf(state) {
  const params = new URLSearchParams();
  if (state.status) params.set("status", state.status);
  if (state.q) params.set("q", state.q);
  for (const tag of state.tags) params.append("tag", tag);
  if (state.sort && state.sort !== "-id") params.set("sort", state.sort);
  if (state.offset) params.set("offset", String(state.offset));
  const text = params.toString();
  return `#/tasks${text ? `?${text}` : ""}`;
}

function fixed(value, digits = 1) {
  return value === null || value === undefined ? null : Number(value).toFixed(digits);
}

function signed(value) {
  if (value === null || value === undefined) return null;
  const text = Math.abs(value).toFixed(1);
  return value > 0 ? `+${text}` : value < 0 ? `−${text}` : text;
}

function figure(text, title) {
  return text === null ? h("span", { class: "muted", title }, "—") : h("span", { title }, text);
}

// The headline cells: what a finished task has; "—" says why it has not.
function headlineCells(task) {
  const figures = task.headline;
  const why = figures ? "this task has no such figure (no AP: a camera or structural task, or no labels)" : "the task has not finished";
  const f = figures ?? {};
  const rate = f.violation_rate === null || f.violation_rate === undefined ? "" : ` (${(f.violation_rate * 100).toFixed(1)} %)`;
  return [
    h(
      "td",
      { class: "num", testid: "cell-map" },
      figure(fixed(f.map), figures ? MAP_TITLE : why),
      f.ap_warnings && f.map !== null
        ? h(
            "span",
            { class: "ap-warning", testid: "ap-warning", title: `small sample: ${f.ap_warnings} warning${f.ap_warnings === 1 ? "" : "s"} on this task's AP (few objects or one frame); see the task's page` },
            " ⚠",
          )
        : null,
    ),
    h("td", { class: "num", testid: "cell-delta-map" }, figure(signed(f.delta_map), figures ? DELTA_TITLE : why)),
    h(
      "td",
      { class: "num", testid: "cell-violations" },
      figure(f.violations ?? null, f.checked ? `${f.violations} of ${f.checked} checks${rate}` : why),
    ),
    h("td", { class: "num", testid: "cell-failures" }, figure(f.failures ?? null, figures ? "the system's failures" : why)),
  ];
}

// Tags as typed in the editor: separated by commas or spaces.
function tagsFrom(text) {
  return text
    .split(/[\s,]+/)
    .map((t) => t.trim())
    .filter(Boolean);
}

export async function tasksPage(root, params) {
  const { statuses, isFinished } = statusesOf(await taskSchema());
  const state = stateFrom(params);
  const selected = []; // task ids in the order ticked: the first is the comparison's baseline
  let editing = null; // the task id whose tags and notes are open
  let active = false;

  const body = h("tbody", { testid: "tasks-body" });
  const message = h("div");
  const pager = h("div", { class: "pager" });
  const tagFilter = h("span", { class: "tag-filter", testid: "tag-filter" });
  const search = h("input", {
    type: "search",
    placeholder: "search tasks",
    title: "in the name, system, data set, status, tags and notes (any case)",
    value: state.q,
    testid: "task-search",
    "aria-label": "search the tasks",
  });
  let typing = null;
  search.addEventListener("input", () => {
    clearTimeout(typing);
    typing = setTimeout(() => update({ q: search.value.trim(), offset: 0 }), 250);
  });
  const filter = h(
    "select",
    { testid: "status-filter", onchange: () => update({ status: filter.value, offset: 0 }) },
    ["", ...statuses].map((s) => h("option", { value: s }, s || "any status")),
  );
  filter.value = state.status;
  const compare = h(
    "button",
    {
      testid: "compare",
      disabled: true,
      title: "tick two or more tasks; the first ticked is the baseline",
      onclick: () => go(`/compare?tasks=${selected.join(",")}`),
    },
    "Compare",
  );
  const head = h("tr", {});
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, "Tasks"),
      h("span", { class: "spacer" }),
      tagFilter,
      search,
      filter,
      compare,
      h("a", { class: "button primary", href: "#/tasks/new", testid: "new-task" }, "New task"),
    ),
    message,
    h("table", { class: "table tasks-table", testid: "tasks-table" }, h("thead", {}, head), body),
    pager,
  );

  function update(change) {
    Object.assign(state, change);
    history.replaceState(null, "", addressOf(state)); // no hashchange: the page stays, the address follows
    load();
  }

  function drawHead() {
    clear(head);
    const key = state.sort.replace(/^-/, "");
    const descending = state.sort.startsWith("-");
    for (const [label, sortKey, title, cls] of COLUMNS) {
      if (!sortKey) {
        head.append(h("th", { title }, label));
        continue;
      }
      const current = sortKey === key;
      const next = current && !descending ? `-${sortKey}` : sortKey;
      head.append(
        h(
          "th",
          { class: cls, title, "aria-sort": current ? (descending ? "descending" : "ascending") : "none" },
          h(
            "button",
            { class: "sort", testid: `sort-${sortKey}`, onclick: () => update({ sort: next, offset: 0 }) },
            label,
            current ? (descending ? " ▼" : " ▲") : "",
          ),
        ),
      );
    }
  }

  function drawTagFilter() {
    clear(tagFilter);
    for (const tag of state.tags) {
      tagFilter.append(
        h(
          "button",
          {
            class: "chip active",
            testid: "tag-filter-chip",
            dataset: { tag },
            title: "showing tasks with this tag: click to show all",
            onclick: () => update({ tags: state.tags.filter((t) => t !== tag), offset: 0 }),
          },
          tag,
          " ×",
        ),
      );
    }
  }

  function chips(task) {
    return (task.tags ?? []).map((tag) =>
      h(
        "button",
        {
          class: "chip",
          testid: "tag-chip",
          dataset: { tag },
          title: "show the tasks with this tag",
          onclick: () => {
            if (!state.tags.includes(tag)) update({ tags: [...state.tags, tag], offset: 0 });
          },
        },
        tag,
      ),
    );
  }

  function toggle(taskId, on) {
    const at = selected.indexOf(taskId);
    if (on && at < 0) selected.push(taskId);
    if (!on && at >= 0) selected.splice(at, 1);
    compare.disabled = selected.length < 2;
    compare.textContent = selected.length >= 2 ? `Compare ${selected.length}` : "Compare";
  }

  function editorRow(task) {
    const tags = h("input", { value: (task.tags ?? []).join(", "), testid: "tags-input", "aria-label": "tags" });
    const notes = h("textarea", { rows: 3, testid: "notes-input", "aria-label": "notes" }, task.notes ?? "");
    const problem = h("div");
    const save = async () => {
      try {
        await api(`/api/tasks/${task.id}`, { method: "PATCH", body: { tags: tagsFrom(tags.value), notes: notes.value } });
      } catch (exc) {
        // one line naming the field ("tags.1: 'a/b' is not a tag ..."), not the status line and a list of one
        const line = exc.problems?.length === 1 ? exc.problems[0].message : exc.message;
        clear(problem).append(notice("error", `Not saved: ${line}`, exc.problems?.length > 1 ? exc.problems : [], "editor-error"));
        return;
      }
      editing = null;
      load();
    };
    return h(
      "tr",
      { class: "editor-row", testid: "task-editor", dataset: { taskId: task.id } },
      h(
        "td",
        { colspan: COLUMNS.length },
        h(
          "div",
          { class: "task-editor" },
          h("label", {}, "Tags ", h("span", { class: "hint" }, "(comma or space separated: letters, digits, . _ : + -)"), tags),
          h("label", {}, "Notes", notes),
          problem,
          h(
            "div",
            { class: "form-actions" },
            h("button", { class: "primary", testid: "save-task", onclick: save }, "Save"),
            h("button", { testid: "cancel-edit", onclick: () => ((editing = null), load()) }, "Cancel"),
          ),
        ),
      ),
    );
  }

  function row(task) {
    const tick = h("input", {
      type: "checkbox",
      testid: "select-task",
      checked: selected.includes(task.id),
      "aria-label": `compare task ${task.id}`,
      onchange: () => toggle(task.id, tick.checked),
    });
    const name = task.name || h("span", { class: "muted" }, task.kind && task.kind !== "mutation" ? task.kind : "—");
    const notes = task.notes
      ? h("div", { class: "task-notes muted", testid: "task-notes", title: task.notes }, task.notes.split("\n")[0])
      : null;
    return h(
      "tr",
      { testid: "task-row", dataset: { taskId: task.id, status: task.status } },
      h("td", {}, tick),
      h("td", {}, h("a", { href: `#/tasks/${task.id}` }, `#${task.id}`)),
      h("td", { class: "task-name" }, h("div", {}, name), h("div", { class: "chips" }, chips(task)), notes),
      h("td", {}, statusBadge(task.status)),
      h("td", {}, task.dataset),
      h("td", {}, task.model),
      headlineCells(task),
      h("td", { class: "time" }, formatTime(task.started_at)),
      h("td", { class: "time" }, formatTime(task.finished_at)),
      h("td", { class: "progress-cell" }, progressBar(task.done, task.total, "task-progress")),
      h(
        "td",
        { class: "row-actions" },
        h("a", { href: `#/tasks/${task.id}`, testid: "task-detail-link" }, "Details"),
        " · ",
        h(
          "button",
          { class: "link", testid: "edit-task", onclick: () => ((editing = task.id), load()) },
          "Tags & notes",
        ),
      ),
    );
  }

  async function load() {
    let reply;
    try {
      const params = { limit: PAGE, offset: state.offset, status: state.status, q: state.q, sort: state.sort };
      const tags = state.tags.map((t) => `&tag=${encodeURIComponent(t)}`).join("");
      const base = query(params);
      reply = await api(`/api/tasks${base || "?"}${tags}`);
    } catch (exc) {
      clear(message).append(notice("error", exc.message, exc.problems));
      return;
    }
    clear(message);
    drawHead();
    drawTagFilter();
    const { items: tasks, total } = reply;
    active = tasks.some((task) => !isFinished(task.status));
    clear(body);
    const filtered = state.status || state.q || state.tags.length;
    if (!tasks.length) {
      body.append(emptyRow(COLUMNS.length, filtered ? "No task matches." : "No tasks yet: create one with New task."));
    }
    for (const task of tasks) {
      body.append(row(task));
      if (editing === task.id) body.append(editorRow(task));
    }
    clear(pager);
    pager.append(h("span", { class: "muted", testid: "tasks-total" }, `${total} task${total === 1 ? "" : "s"}`));
    if (state.offset > 0) pager.append(h("button", { testid: "newer", onclick: () => update({ offset: Math.max(0, state.offset - PAGE) }) }, "← Previous"));
    if (state.offset + PAGE < total) pager.append(h("button", { testid: "older", onclick: () => update({ offset: state.offset + PAGE }) }, "Next →"));
  }
  await load();
  return every(2000, () => {
    if (active && editing === null && !document.hidden) load();
  });
}
