// What the data-set and model pages share: notes (shown truncated in a list, edited on a detail
// page), the facts of one data set or model, and deleting one — a refusal (a task uses it) stays
// next to its row, naming the tasks with links, until the next action.
import { api } from "../api.js";
import { clear, go, h, notice } from "../dom.js";

// Notes in a list cell: clamped to two lines (CSS), the whole text on hover.
export function notesCell(notes) {
  const text = String(notes ?? "");
  return h("td", { class: "notes-cell", title: text, testid: "notes-cell" }, text ? h("span", { class: "clamp" }, text) : h("span", { class: "muted" }, "—"));
}

// Links to the tasks that use a data set or model: "#3 noise, #5 fog".
export function taskLinks(tasks) {
  return (tasks ?? []).flatMap((task, index) => [
    index ? ", " : "",
    h("a", { href: `#/tasks/${task.id}`, testid: "used-by-task" }, `#${task.id}${task.name ? ` ${task.name}` : ""}`),
  ]);
}

// A refused action's notice: the server's one line, and the tasks it names as links.
export function refusalNotice(message, tasks = [], testid = "refusal") {
  const text = String(message ?? "").replace(/^HTTP \d+: /, "");
  return notice(
    "error",
    [h("span", {}, text), tasks.length ? h("div", { class: "used-by" }, "Open them: ", taskLinks(tasks)) : null],
    [],
    testid,
  );
}

// Delete `url` after asking; resolves to null when it was deleted or the user said no, else to the
// refusal (message and, for a 409, the tasks using it: read from `detailUrl`).
export async function forget(url, detailUrl, question) {
  if (!window.confirm(question)) return { cancelled: true };
  try {
    await api(url, { method: "DELETE" });
    return null;
  } catch (exc) {
    let tasks = [];
    if (exc.status === 409) tasks = await api(detailUrl).then((d) => d.used_by ?? [], () => []);
    return { message: exc.message, tasks };
  }
}

// A detail page's Delete button: asks, deletes `url`, goes back to `listPath`; a refusal goes into
// `message` (with the tasks that use it).
export function deleteButton({ url, question, listPath, message, testid }) {
  return h(
    "button",
    {
      class: "danger",
      testid,
      onclick: async () => {
        clear(message);
        const refused = await forget(url, url, question);
        if (refused?.cancelled) return;
        if (!refused) go(listPath);
        else message.append(refusalNotice(refused.message, refused.tasks));
      },
    },
    "Delete",
  );
}

// Facts as a two-column list: [label, value] pairs (a null value is left out).
export function factsList(rows, testid = "facts") {
  return h(
    "dl",
    { class: "facts", testid },
    rows.filter(([, value]) => value !== null && value !== undefined && value !== "").flatMap(([label, value, id]) => [
      h("dt", {}, label),
      h("dd", { testid: id }, value),
    ]),
  );
}

// The notes editor of a detail page: a textarea and Save; `save(text)` sends them (PATCH) and
// resolves to the saved row. A refusal names the field.
export function notesEditor(notes, save) {
  const area = h("textarea", { rows: 5, maxlength: 10000, testid: "notes-edit" });
  area.value = notes ?? "";
  const message = h("div", { testid: "notes-message" });
  const button = h("button", { type: "submit", class: "primary", testid: "notes-save" }, "Save notes");
  area.addEventListener("input", () => clear(message));
  return h(
    "form",
    {
      class: "card form notes-form",
      testid: "notes-form",
      onsubmit: async (event) => {
        event.preventDefault();
        clear(message);
        button.disabled = true;
        try {
          const row = await save(area.value);
          area.value = row?.notes ?? area.value;
          message.append(notice("ok", "Notes saved.", [], "notes-saved"));
        } catch (exc) {
          const field = exc.problems?.[0]?.field;
          message.append(notice("error", `${field && !exc.message.includes(field) ? `${field}: ` : ""}${exc.message.replace(/^HTTP \d+: /, "")}`, [], "notes-error"));
        } finally {
          button.disabled = false;
        }
      },
    },
    h("h2", {}, "Notes"),
    area,
    h("div", { class: "form-actions" }, button),
    message,
  );
}
