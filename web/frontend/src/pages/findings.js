// Findings of a task: counts, filters (relation, operator, severity, class, kind, subtask), sorting,
// pagination, a thumbnail per finding, and the same object flagged at several severities as one group.
// Every choice lives in the URL's query, so a filtered, sorted page can be shared and reloaded.
// With ?subtask=ID the page first shows that subtask: its AP, failures, tool errors, warnings and times.
import { api, listOf, query, withToken } from "../api.js";
import { append, clear, emptyRow, formatNumber, formatTime, go, h, notice } from "../dom.js";

const PAGE = 50;
const COLUMNS = 9;
const SORTS = [
  ["id", "ID (oldest first)"],
  ["-magnitude", "magnitude (largest first)"],
  ["magnitude", "magnitude (smallest first)"],
  ["-severity", "severity (highest first)"],
  ["severity", "severity (lowest first)"],
  ["frame", "frame"],
  ["operator", "operator"],
];
const KINDS = { violation: "relation violations", failure: "system failures" };
export const GROUP_RULE =
  "Grouped: findings of the same frame, operator, relation (or failure kind) and class that name at least one " +
  "common object of the original frame (its ground-truth box, else its detection) are one row, with the severities " +
  "they were found at; findings about no object group by frame, operator, kind and class.";

export function findingKind(f) {
  return f.relation ?? f.kind ?? "";
}

// The page's state from its URL query: filters, sort, grouping (on unless group=0) and offset.
function stateOf(params) {
  const get = (key) => params.get(key) ?? "";
  return {
    relation: get("relation"),
    operator: get("operator"),
    severity: get("severity"),
    cls: get("cls"),
    kind: get("kind"),
    subtask: get("subtask"),
    sort: get("sort") || "id",
    group: params.get("group") === "0" ? "0" : "",
    offset: Math.max(0, Number(params.get("offset") ?? 0) || 0),
    // rows per page: 50 unless the URL says otherwise (1-200)
    limit: Math.min(200, Math.max(1, Number(params.get("limit") ?? PAGE) || PAGE)),
  };
}

function pageUrl(id, state, changes = {}) {
  const next = { ...state, offset: 0, ...changes };
  return `/tasks/${id}/findings${query({
    ...next,
    sort: next.sort === "id" ? "" : next.sort,
    offset: next.offset || "",
    limit: next.limit === PAGE ? "" : next.limit,
  })}`;
}

function filterSelect(key, label, values, state, id, show = (v) => v) {
  const select = h(
    "select",
    { testid: `filter-${key}`, "aria-label": label },
    h("option", { value: "" }, `any ${label}`),
    values.map((v) => h("option", { value: String(v), selected: String(v) === state[key] }, show(v))),
  );
  select.addEventListener("change", () => go(pageUrl(id, state, { [key]: select.value })));
  return select;
}

function toolbar(id, state, facets) {
  const sort = h(
    "select",
    { testid: "sort", "aria-label": "sort by" },
    SORTS.map(([value, text]) => h("option", { value, selected: value === state.sort }, `sort: ${text}`)),
  );
  sort.addEventListener("change", () => go(pageUrl(id, state, { sort: sort.value })));
  const group = h("input", { type: "checkbox", checked: state.group !== "0", testid: "group-toggle" });
  group.addEventListener("change", () => go(pageUrl(id, state, { group: group.checked ? "" : "0" })));
  return h(
    "div",
    { class: "toolbar", testid: "findings-filters" },
    filterSelect("relation", "relation", facets.relation ?? [], state, id),
    filterSelect("operator", "operator", facets.operator ?? [], state, id),
    filterSelect("severity", "severity", facets.severity ?? [], state, id, (v) => `severity ${v}`),
    filterSelect("cls", "class", (facets.class ?? []).filter((v) => v !== ""), state, id),
    filterSelect("kind", "kind", facets.kind ?? [], state, id, (v) => KINDS[v] ?? v),
    sort,
    h("label", { class: "inline" }, group, " group severities"),
  );
}

// The AP table of one subtask: AP|R40 at moderate difficulty per metric, per class and mAP; "—" says why.
function apTable(sub) {
  const moderate = sub.ap_moderate;
  if (sub.deeptest) return deeptestFacts(sub.deeptest);
  if (!moderate) {
    return h("p", { class: "muted", testid: "subtask-ap-note" }, `AP: — ${sub.ap_note ?? (sub.status === "done" ? "not computed for this subtask" : "appears when the subtask is done")}`);
  }
  const metrics = ["bbox", "bev", "3d"].filter((m) => moderate[m]);
  const classes = [...new Set(metrics.flatMap((m) => Object.keys(moderate[m])))].filter((c) => c !== "mAP").sort();
  const why = sub.ap_note ?? "undefined: no labelled object of the class at moderate difficulty";
  const absent = metrics.some((m) => [...classes, "mAP"].some((c) => moderate[m][c] === null || moderate[m][c] === undefined));
  const table = h(
    "table",
    { class: "table compact", testid: "subtask-ap" },
    h("thead", {}, h("tr", {}, h("th", {}, "AP|R40, moderate"), [...classes, "mAP"].map((c) => h("th", { class: "num" }, c)))),
    h(
      "tbody",
      {},
      metrics.map((m) =>
        h(
          "tr",
          { dataset: { metric: m } },
          h("th", {}, m === "3d" ? "3D" : m.toUpperCase()),
          [...classes, "mAP"].map((c) => {
            const value = moderate[m][c];
            return h("td", { class: "num", title: value === null || value === undefined ? why : "", dataset: { cls: c } }, formatNumber(value));
          }),
        ),
      ),
    ),
  );
  return absent ? h("div", {}, table, h("p", { class: "muted small", testid: "subtask-ap-note" }, `—: ${why}`)) : table;
}

// A camera subtask's figures instead of AP: DeepTest's MSE of the transformation against MSE_orig,
// the mutants over λ·MSE_orig (Eq. 2) and Eq. 3's verdict.
function deeptestFacts(d) {
  const verdict = !d.filtered ? "not filtered (a composite transformation)" : d.kept ? "kept" : "filtered out";
  return h(
    "dl",
    { class: "facts", testid: "subtask-deeptest" },
    h("dt", {}, "MSE_t"),
    h("dd", {}, formatNumber(d.mse, 4)),
    h("dt", {}, "MSE_orig"),
    h("dd", {}, formatNumber(d.mse_orig, 4)),
    h("dt", {}, "Eq. 2 violations"),
    h("dd", {}, `${d.violated} of ${d.mutants}`),
    h("dt", {}, "Eq. 3"),
    h("dd", {}, verdict),
  );
}

// What GET /api/tasks/{id} says of one subtask, above its findings.
function subtaskPanel(id, sub, state) {
  const tools = sub.tool_errors ?? {};
  const toolCount = Object.values(tools).reduce((a, b) => a + b, 0);
  return h(
    "section",
    { class: "subtask-panel", testid: "subtask-panel", dataset: { subtask: sub.id } },
    h(
      "div",
      { class: "page-head" },
      h("h2", {}, `Subtask ${sub.label}`),
      h("span", { class: `badge status-${sub.status}` }, sub.status),
      h("span", { class: "spacer" }),
      h("a", { class: "button small", href: `#${pageUrl(id, state, { subtask: "" })}`, testid: "all-subtasks" }, "All findings of the task"),
    ),
    h(
      "dl",
      { class: "facts" },
      h("dt", {}, "Started"),
      h("dd", { testid: "subtask-started" }, formatTime(sub.started_at)),
      h("dt", {}, "Finished"),
      h("dd", { testid: "subtask-finished" }, formatTime(sub.finished_at)),
      h("dt", {}, "Frames"),
      h("dd", {}, `${sub.done} of ${sub.total}`),
      h("dt", {}, "System failures"),
      h("dd", { testid: "subtask-failures", title: "the system under test's crashes, timeouts and invalid outputs" }, String(sub.failures ?? 0)),
      h("dt", {}, "lidarfuzz's own errors"),
      h(
        "dd",
        { testid: "subtask-tool-errors", title: "errors of lidarfuzz (an operator or a relation raised), never the system's" },
        toolCount ? Object.entries(tools).filter(([, n]) => n).map(([k, n]) => `${n} ${k.replace("_", " ")}${n === 1 ? "" : "s"}`).join(", ") : "none",
      ),
    ),
    apTable(sub),
    (sub.sample_warnings ?? []).length
      ? h("ul", { class: "warnings", testid: "subtask-warnings" }, sub.sample_warnings.map((w) => h("li", {}, `⚠ ${w}`)))
      : null,
  );
}

function thumbnail(f) {
  return h("img", {
    class: "finding-thumb",
    src: withToken(`/api/findings/${f.id}/thumb.png`),
    alt: `finding #${f.id} from above`,
    width: 160,
    height: 120,
    loading: "lazy",
    decoding: "async",
    testid: "finding-thumb",
    // its frame cannot be rebuilt any more (the data set moved): a line instead of a broken image
    onerror: (e) => e.target.replaceWith(h("span", { class: "muted thumb-missing", testid: "thumb-missing" }, "no picture: its frame cannot be read")),
  });
}

// One finding (or a group's first finding) and, for a group, its members in a row that expands.
function findingRows(f, id) {
  const href = `#/findings/${f.id}?task=${id}`;
  const group = f.group ?? { size: 1, severities: [f.severity], members: [] };
  const toggle =
    group.size > 1
      ? h("button", { type: "button", class: "small", testid: "group-toggle-row", "aria-expanded": "false" }, `${group.size} findings ▸`)
      : null;
  const row = h(
    "tr",
    { testid: "finding-row", dataset: { findingId: f.id, groupSize: group.size } },
    h("td", { class: "thumb-cell" }, h("a", { href, tabindex: -1 }, thumbnail(f)), h("a", { href }, `#${f.id}`)),
    h("td", { class: f.failure ? "failure-kind" : "", title: f.failure ? "the system under test failed here" : "" }, findingKind(f)),
    h("td", {}, f.operator ?? ""),
    h("td", { class: "num", testid: "severities" }, group.severities.join(", ")),
    h("td", {}, f.frame_id ?? f.frame ?? ""),
    h("td", {}, f.class ?? f.cls ?? ""),
    h("td", { class: "num" }, formatNumber(f.magnitude)),
    h("td", { class: "message" }, f.message ?? "", toggle ? h("div", {}, toggle) : null),
    h("td", {}, h("a", { class: "button small", href, testid: "open-finding" }, "View")),
  );
  if (!toggle) return [row];
  const members = h(
    "tr",
    { class: "group-members", hidden: true, testid: "group-members" },
    h(
      "td",
      { colspan: COLUMNS },
      h(
        "table",
        { class: "table compact" },
        h("tbody", {}, group.members.map((m) =>
          h(
            "tr",
            { testid: "group-member", dataset: { findingId: m.id } },
            h("td", {}, h("a", { href: `#/findings/${m.id}?task=${id}` }, `#${m.id}`)),
            h("td", {}, m.label),
            h("td", { class: "num" }, m.trial ? `trial ${m.trial}` : ""),
            h("td", { class: "num" }, formatNumber(m.magnitude)),
            h("td", { class: "message" }, m.message ?? ""),
          ),
        ), group.size > group.members.length
          ? h("tr", {}, h("td", { colspan: 5, class: "muted" }, `and ${group.size - group.members.length} more: filter by severity to see them`))
          : null),
      ),
    ),
  );
  toggle.addEventListener("click", () => {
    members.hidden = !members.hidden;
    toggle.setAttribute("aria-expanded", String(!members.hidden));
    toggle.textContent = `${group.size} findings ${members.hidden ? "▸" : "▾"}`;
  });
  return [row, members];
}

function countText(reply, state) {
  const total = reply.total ?? 0;
  const all = reply.total_all ?? total;
  const filtered = total === all ? `${all} finding${all === 1 ? "" : "s"}` : `${total} of ${all} findings`;
  return state.group !== "0" && reply.groups !== null && reply.groups !== undefined
    ? `${filtered} in ${reply.groups} row${reply.groups === 1 ? "" : "s"} (same object at several severities grouped)`
    : filtered;
}

export async function findingsPage(root, id, params) {
  const state = stateOf(params);
  const apiQuery = {
    relation: state.relation,
    operator: state.operator,
    severity: state.severity,
    cls: state.cls,
    kind: state.kind,
    subtask: state.subtask,
    sort: state.sort,
    group: state.group === "0" ? "" : "true",
    limit: state.limit,
    offset: state.offset,
  };
  const [reply, task] = await Promise.all([
    api(`/api/tasks/${id}/findings${query(apiQuery)}`).catch((exc) => exc),
    state.subtask ? api(`/api/tasks/${id}`).catch((exc) => exc) : null,
  ]);
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, `Findings of task #${id}`),
      h("span", { class: "spacer" }),
      h("a", { class: "button", href: `#/tasks/${id}` }, "Task"),
      h("a", { class: "button", href: `#/tasks/${id}/report` }, "Report"),
    ),
  );
  if (task instanceof Error) root.append(notice("error", task.message, task.problems));
  else if (task) {
    const sub = (task.subtasks ?? []).find((s) => String(s.id) === state.subtask);
    root.append(sub ? subtaskPanel(id, sub, state) : notice("error", `subtask: task #${id} has no subtask ${state.subtask}.`));
  }
  if (reply instanceof Error) {
    root.append(notice("error", reply.message, reply.problems));
    return;
  }
  const findings = listOf(reply, "findings");
  const grouped = state.group !== "0";
  const body = h("tbody", { testid: "findings-body" });
  const pager = h("div", { class: "pager", testid: "pager" });
  append(root, [
    toolbar(id, state, reply.facets ?? {}),
    h("p", { class: "count", testid: "findings-count" }, countText(reply, state)),
    grouped ? h("p", { class: "muted small", testid: "group-rule" }, GROUP_RULE) : null,
    h(
      "table",
      { class: "table findings-table", testid: "findings-table" },
      h("thead", {}, h("tr", {}, ["Finding", "Relation / kind", "Operator", grouped ? "Severities" : "Severity", "Frame", "Class", "Magnitude", "Message", ""].map((t) => h("th", {}, t)))),
      body,
    ),
    pager,
  ]);
  clear(body);
  if (!findings.length) {
    body.append(emptyRow(COLUMNS, reply.total_all ? "No finding matches these filters." : "No findings: the system held every relation."));
  }
  for (const f of findings) body.append(...findingRows(f, id));
  const count = grouped && reply.groups !== null && reply.groups !== undefined ? reply.groups : reply.total ?? 0;
  if (count > 0) {
    pager.append(h("span", { class: "muted", testid: "page-range" }, `${state.offset + 1}–${state.offset + findings.length} of ${count}`));
  }
  if (state.offset > 0) {
    pager.append(h("a", { class: "button", href: `#${pageUrl(id, state, { offset: Math.max(0, state.offset - state.limit) })}`, testid: "page-previous" }, "← Previous"));
  }
  if (state.offset + state.limit < count) {
    pager.append(h("a", { class: "button", href: `#${pageUrl(id, state, { offset: state.offset + state.limit })}`, testid: "page-next" }, "Next →"));
  }
}
