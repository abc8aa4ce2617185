// Findings of a task: filter by relation, operator and class; each opens the viewer on its frames.
import { api, listOf, query } from "../api.js";
import { clear, emptyRow, formatNumber, go, h, notice } from "../dom.js";

const PAGE = 50;

export function findingKind(f) {
  return f.relation ?? f.kind ?? "";
}

export async function findingsPage(root, id, params) {
  const filters = { relation: params.get("relation") ?? "", operator: params.get("operator") ?? "", cls: params.get("cls") ?? "" };
  let offset = Number(params.get("offset") ?? 0);
  // the filter choices: the server's facets, or every value among the task's first 1,000 findings
  const first = await api(`/api/tasks/${id}/findings${query({ limit: 1000 })}`);
  const all = listOf(first, "findings");
  const distinct = (fn) => [...new Set(all.map(fn).filter((v) => v !== undefined && v !== null && v !== ""))].sort();
  const facets = first?.facets ?? {};
  const choices = {
    relation: facets.relation ?? distinct(findingKind),
    operator: facets.operator ?? distinct((f) => f.operator),
    cls: (facets.class ?? facets.cls ?? distinct((f) => f.cls ?? f.class)).filter((v) => v !== ""),
  };
  const names = { relation: "relation", operator: "operator", cls: "class" };
  const selects = Object.fromEntries(
    Object.keys(filters).map((key) => {
      const select = h(
        "select",
        { testid: `filter-${key}` },
        h("option", { value: "" }, `any ${names[key]}`),
        choices[key].map((v) => h("option", { value: v, selected: v === filters[key] }, v)),
      );
      select.addEventListener("change", () => {
        filters[key] = select.value;
        go(`/tasks/${id}/findings${query({ ...filters })}`);
      });
      return [key, select];
    }),
  );
  const body = h("tbody", { testid: "findings-body" });
  const message = h("div");
  const pager = h("div", { class: "pager" });
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, `Findings of task #${id}`),
      h("span", { class: "spacer" }),
      h("a", { class: "button", href: `#/tasks/${id}` }, "Task"),
      h("a", { class: "button", href: `#/tasks/${id}/report` }, "Report"),
    ),
    h("div", { class: "toolbar", testid: "findings-filters" }, Object.values(selects)),
    message,
    h(
      "table",
      { class: "table", testid: "findings-table" },
      h("thead", {}, h("tr", {}, ["ID", "Relation / kind", "Operator", "Severity", "Frame", "Class", "Magnitude", "Message", ""].map((t) => h("th", {}, t)))),
      body,
    ),
    pager,
  );
  let reply;
  try {
    reply = await api(`/api/tasks/${id}/findings${query({ ...filters, limit: PAGE, offset })}`);
  } catch (exc) {
    message.append(notice("error", exc.message, exc.problems));
    return;
  }
  const findings = listOf(reply, "findings");
  clear(body);
  if (!findings.length) {
    body.append(emptyRow(9, all.length ? "No finding matches these filters." : "No findings: the system held every relation."));
  }
  for (const f of findings) {
    const href = `#/findings/${f.id}?task=${id}`;
    body.append(
      h(
        "tr",
        { testid: "finding-row", dataset: { findingId: f.id } },
        h("td", {}, h("a", { href }, `#${f.id}`)),
        h("td", {}, findingKind(f)),
        h("td", {}, f.operator ?? ""),
        h("td", { class: "num" }, f.severity ?? ""),
        h("td", {}, f.frame ?? f.frame_id ?? ""),
        h("td", {}, f.cls ?? f.class ?? ""),
        h("td", { class: "num" }, formatNumber(f.magnitude)),
        h("td", { class: "message" }, f.message ?? ""),
        h("td", {}, h("a", { class: "button small", href, testid: "open-finding" }, "View")),
      ),
    );
  }
  const total = reply?.total;
  if (offset > 0) pager.append(h("a", { class: "button", href: `#/tasks/${id}/findings${query({ ...filters, offset: Math.max(0, offset - PAGE) })}` }, "← Previous"));
  if (findings.length === PAGE && (total === undefined || offset + PAGE < total)) {
    pager.append(h("a", { class: "button", href: `#/tasks/${id}/findings${query({ ...filters, offset: offset + PAGE })}` }, "Next →"));
  }
}
