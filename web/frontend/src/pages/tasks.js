// Tasks: id, status, data set, SUT, operators, start/finish, progress; refreshed while any runs.
// The statuses (the filter's choices, which ones still move) come from the task schema (../contract.js).
import { api, query } from "../api.js";
import { statusesOf, taskSchema } from "../contract.js";
import { clear, emptyRow, every, formatTime, h, notice, progressBar, statusBadge } from "../dom.js";

const PAGE = 50;

export async function tasksPage(root) {
  const { statuses, isFinished } = statusesOf(await taskSchema());
  let status = "";
  let offset = 0;
  const body = h("tbody", { testid: "tasks-body" });
  const message = h("div");
  const pager = h("div", { class: "pager" });
  const filter = h(
    "select",
    {
      testid: "status-filter",
      onchange: () => {
        status = filter.value;
        offset = 0;
        load();
      },
    },
    ["", ...statuses].map((s) => h("option", { value: s }, s || "any status")),
  );
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, "Tasks"),
      h("span", { class: "spacer" }),
      filter,
      h("a", { class: "button primary", href: "#/tasks/new", testid: "new-task" }, "New task"),
    ),
    message,
    h(
      "table",
      { class: "table", testid: "tasks-table" },
      h(
        "thead",
        {},
        h(
          "tr",
          {},
          ["ID", "Name", "Status", "Data set", "SUT", "Operators", "Started", "Finished", "Progress", ""].map((t) =>
            h("th", {}, t),
          ),
        ),
      ),
      body,
    ),
    pager,
  );

  let active = false;
  async function load() {
    let reply;
    try {
      reply = await api(`/api/tasks${query({ limit: PAGE, offset, status })}`);
    } catch (exc) {
      clear(message).append(notice("error", exc.message, exc.problems));
      return;
    }
    clear(message);
    const { items: tasks, total } = reply;
    active = tasks.some((task) => !isFinished(task.status));
    clear(body);
    if (!tasks.length) body.append(emptyRow(10, "No tasks yet: create one with New task."));
    for (const task of tasks) {
      body.append(
        h(
          "tr",
          { testid: "task-row", dataset: { taskId: task.id, status: task.status } },
          h("td", {}, h("a", { href: `#/tasks/${task.id}` }, `#${task.id}`)),
          h("td", {}, task.name || h("span", { class: "muted" }, task.kind && task.kind !== "mutation" ? task.kind : "—")),
          h("td", {}, statusBadge(task.status)),
          h("td", {}, task.dataset),
          h("td", {}, task.model),
          h("td", { class: "num" }, task.operator_count),
          h("td", {}, formatTime(task.started_at)),
          h("td", {}, formatTime(task.finished_at)),
          h("td", { class: "progress-cell" }, progressBar(task.done, task.total, "task-progress")),
          h("td", {}, h("a", { href: `#/tasks/${task.id}`, testid: "task-detail-link" }, "Details")),
        ),
      );
    }
    clear(pager);
    if (offset > 0) pager.append(h("button", { onclick: () => ((offset -= PAGE), load()) }, "← Newer"));
    if (tasks.length === PAGE && offset + PAGE < total) {
      pager.append(h("button", { onclick: () => ((offset += PAGE), load()) }, "Older →"));
    }
  }
  await load();
  return every(2000, () => {
    if (active && !document.hidden) load();
  });
}
