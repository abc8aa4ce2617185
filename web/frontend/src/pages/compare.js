// Two or more tasks side by side (#/compare?tasks=3,5[,7]): the same operators on two systems, or
// before and after retraining. AP at moderate difficulty per class and mAP, with ΔAP against each
// task's own originals, for any tasks; violation rates, with each task tested against the first (the
// baseline) where their mutants are identical, and the significant differences marked. The server
// (GET /api/compare) says what is tested; the page shows its sentence.
import { api } from "../api.js";
import { clear, h, notice } from "../dom.js";

const METRICS = [
  ["3d", "3D"],
  ["bev", "BEV"],
  ["bbox", "bbox (image)"],
];

function signed(value) {
  if (value === null || value === undefined) return "";
  const text = Math.abs(value).toFixed(1);
  return value > 0 ? `+${text}` : value < 0 ? `−${text}` : `±${text}`;
}

function percent(violated, checked) {
  return checked ? `${violated}/${checked} (${((violated / checked) * 100).toFixed(0)} %)` : "—";
}

function taskTitle(task, baseline) {
  return h(
    "span",
    {},
    h("a", { href: `#/tasks/${task.id}` }, `#${task.id}`),
    ` ${task.name || "(no name)"} · ${task.model} · ${task.dataset}`,
    task.id === baseline ? h("span", { class: "badge baseline", testid: "baseline" }, "baseline") : null,
  );
}

// The small-sample warnings that concern `cls` in a cell: its own ("Car: too few objects ...") and those
// about the whole evaluation ("AP from a single frame ..."); mAP: all of them.
function warningsFor(cell, cls, classes) {
  const all = cell?.sample_warnings ?? [];
  if (cls === "mAP") return all;
  return all.filter((w) => w.startsWith(`${cls}:`) || !classes.some((c) => w.startsWith(`${c}:`)));
}

// The classes the AP table shows: every class any cell has, mAP last.
function classesOf(rows, metric) {
  const seen = new Set();
  for (const row of rows) for (const cell of row.cells) for (const cls of Object.keys(cell?.ap?.[metric] ?? {})) seen.add(cls);
  seen.delete("mAP");
  return [...seen, "mAP"];
}

function apTable(reply, metric) {
  const classes = classesOf(reply.rows, metric);
  const top = h("tr", {}, h("th", { rowspan: 2 }, "Operator × severity"));
  const sub = h("tr", {});
  for (const task of reply.tasks) {
    top.append(h("th", { colspan: classes.length, class: "group" }, `#${task.id} ${task.model}`));
    for (const cls of classes) sub.append(h("th", { class: "num" }, cls));
  }
  const body = h("tbody", {});
  for (const row of reply.rows) {
    const tr = h("tr", { testid: "ap-row", dataset: { label: row.label } }, h("th", { scope: "row" }, row.label));
    reply.tasks.forEach((task, index) => {
      const cell = row.cells[index];
      for (const cls of classes) {
        const value = cell?.ap?.[metric]?.[cls];
        if (value === null || value === undefined) {
          const why = !cell ? `task ${task.id} has no ${row.label}` : (cell.ap_note ?? "no AP for this class");
          tr.append(h("td", { class: "num muted", title: why, dataset: { task: task.id, cls } }, "—"));
          continue;
        }
        const delta = cell.delta?.[metric]?.[cls];
        const warnings = warningsFor(cell, cls, classes);
        tr.append(
          h(
            "td",
            { class: "num", testid: "ap-cell", dataset: { task: task.id, cls } },
            value.toFixed(1),
            warnings.length ? h("span", { class: "ap-warning", testid: "ap-warning", title: warnings.join("\n") }, " ⚠") : null,
            delta === null || delta === undefined
              ? null
              : h("span", { class: `delta ${delta < 0 ? "down" : delta > 0 ? "up" : ""}`, testid: "delta" }, ` ${signed(delta)}`),
          ),
        );
      }
    });
    body.append(tr);
  }
  return h("table", { class: "table compare-table", testid: "compare-ap" }, h("thead", {}, top, sub), body);
}

// (label, relation) → {task id → [violated, checked]} from each task's own subtasks, and the tests.
function rateRows(reply) {
  const rows = new Map();
  const key = (label, relation) => `${label}\u0000${relation}`;
  const at = (label, relation) => {
    const k = key(label, relation);
    if (!rows.has(k)) rows.set(k, { label, relation, counts: {}, tests: {} });
    return rows.get(k);
  };
  reply.rows.forEach((row) => {
    reply.tasks.forEach((task, index) => {
      for (const rate of row.cells[index]?.violations ?? []) at(row.label, rate.relation).counts[task.id] = [rate.violated, rate.checked];
    });
  });
  for (const pair of reply.pairs) {
    for (const test of pair.rows) {
      const entry = at(test.label, test.relation);
      entry.tests[pair.task] = test;
      entry.counts[pair.task] ??= [test.violated, test.checked]; // objects lost: counted by the comparison only
      entry.counts[pair.baseline] ??= [test.violated_baseline, test.checked_baseline];
    }
  }
  return [...rows.values()];
}

function verdictMark(test) {
  if (!test?.significant) return null;
  const worse = test.significant === "worse";
  const p = worse ? test.p_worse : test.p_better;
  return h(
    "span",
    {
      class: `significant ${test.significant}`,
      testid: "significant",
      dataset: { verdict: test.significant },
      title: `significantly ${test.significant} than the baseline (adjusted p = ${p.toPrecision(2)})`,
    },
    worse ? " ▲ worse" : " ▼ better",
  );
}

function ratesTable(reply) {
  const head = h("tr", {}, h("th", {}, "Operator × severity"), h("th", {}, "Relation"));
  for (const task of reply.tasks) head.append(h("th", { class: "num" }, `#${task.id} ${task.model}`));
  const body = h("tbody", {});
  for (const entry of rateRows(reply)) {
    const tr = h("tr", { testid: "rate-row", dataset: { label: entry.label, relation: entry.relation } }, h("td", {}, entry.label), h("td", {}, entry.relation));
    for (const task of reply.tasks) {
      const counts = entry.counts[task.id];
      tr.append(
        h(
          "td",
          { class: "num", testid: "rate-cell", dataset: { task: task.id } },
          counts
            ? percent(counts[0], counts[1])
            : h("span", { class: "muted", title: entry.relation === "objects_lost" ? "objects lost are counted where two tasks are tested" : "not checked" }, "—"),
          verdictMark(entry.tests[task.id]),
        ),
      );
    }
    body.append(tr);
  }
  return h("table", { class: "table compare-table", testid: "compare-rates" }, h("thead", {}, head), body);
}

function pairLine(pair) {
  if (pair.comparable) {
    const marked = pair.rows.filter((r) => r.significant).length;
    return h(
      "li",
      { testid: "pair", dataset: { task: pair.task, comparable: "yes" } },
      `#${pair.task} against #${pair.baseline}: the same mutants; violation rates tested — ${marked} significant difference${marked === 1 ? "" : "s"}.`,
    );
  }
  return h(
    "li",
    { class: "not-comparable", testid: "pair", dataset: { task: pair.task, comparable: "no" } },
    `#${pair.task} against #${pair.baseline}: not tested — ${pair.reason}.`,
  );
}

export async function comparePage(root, params) {
  const ids = params?.get("tasks") ?? "";
  root.append(h("div", { class: "page-head" }, h("h1", {}, "Compare tasks"), h("span", { class: "spacer" }), h("a", { href: "#/tasks" }, "← Tasks")));
  let reply;
  try {
    reply = await api(`/api/compare?tasks=${encodeURIComponent(ids)}`);
  } catch (exc) {
    root.append(notice("error", exc.message, exc.problems));
    return;
  }
  const metric = h(
    "select",
    { testid: "compare-metric", onchange: () => clear(apHolder).append(apTable(reply, metric.value)) },
    METRICS.map(([value, label]) => h("option", { value }, label)),
  );
  const apHolder = h("div", { class: "table-scroll" }, apTable(reply, METRICS[0][0]));
  root.append(
    h(
      "ul",
      { class: "compare-tasks", testid: "compare-tasks" },
      reply.tasks.map((task) => h("li", { dataset: { task: task.id } }, taskTitle(task, reply.baseline))),
    ),
    h("ul", { class: "compare-pairs", testid: "compare-pairs" }, reply.pairs.map(pairLine)),
    h("p", { class: "hint", testid: "compare-tested" }, reply.tested),
    h(
      "h2",
      {},
      "AP, moderate (AP|R40, %) ",
      h("span", { class: "hint" }, "and ΔAP against each task's originals; ⚠ small sample (hover for why)"),
      " ",
      metric,
    ),
    apHolder,
    h("h2", {}, "Violation rates ", h("span", { class: "hint" }, "violated / checked frames; ▲ ▼ significant against the baseline")),
    h("div", { class: "table-scroll" }, ratesTable(reply)),
  );
}
