// Rating: the thesis's first experiment (Table 6-7). A rater judges original/mutant pairs of a task as
// same, similar or different, blinded to the operator; keys 1/2/3 (or s/i/d) rate, ← goes back, → skips.
// The draw (pairs per operator, seed) and the rater's name live in the URL, so a rater who leaves comes
// back to the same pairs in the same order and goes on from the first one not rated yet.
import { api, download, query, withToken } from "../api.js";
import { clear, formatNumber, go, h, notice, progressBar } from "../dom.js";

const RATER_KEY = "lidarfuzz.rater";
const VERDICTS = [
  ["same", "Same", ["1", "s"], "every object as clearly recognisable as in the original"],
  ["similar", "Similar", ["2", "i"], "every object recognisable, some blurred"],
  ["different", "Different", ["3", "d"], "some object no longer recognisable"],
];

function drawParams(params) {
  return {
    rater: (params.get("rater") ?? "").trim(),
    n: params.get("n") ?? "",
    seed: params.get("seed") ?? "",
    operators: params.get("operators") ?? "",
  };
}

function pageHead(id, ...extra) {
  return h(
    "div",
    { class: "page-head" },
    h("h1", {}, `Rate pairs of task #${id}`),
    h("span", { class: "spacer" }),
    ...extra,
    h("a", { class: "button", href: `#/tasks/${id}` }, "Task"),
  );
}

// The start form: who rates, and which draw (the thesis's: 100 frames per operator, the task's seed).
function startForm(root, id, draw, protocol) {
  const name = h("input", { type: "text", testid: "rater-name", value: draw.rater || localStorage.getItem(RATER_KEY) || "", maxlength: 100, placeholder: "your name", required: true });
  const n = h("input", { type: "number", testid: "per-operator", min: 1, value: draw.n || 100 });
  const seed = h("input", { type: "number", testid: "draw-seed", value: draw.seed, placeholder: "the task's" });
  const operators = h("input", { type: "text", testid: "draw-operators", value: draw.operators, placeholder: "all but RAR, UIM, RIM", title: "operator names or aliases, separated by commas" });
  const message = h("div");
  const form = h(
    "form",
    { class: "rating-start", testid: "rating-start" },
    h("label", {}, "Rater ", name),
    h("label", {}, "Frames per operator ", n),
    h("label", {}, "Seed ", seed),
    h("label", {}, "Operators ", operators),
    h("button", { type: "submit", class: "primary", testid: "start-rating" }, "Start rating"),
  );
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    clear(message);
    const rater = name.value.trim();
    if (!rater) {
      message.append(notice("error", "rater: a name is needed (each rater's verdicts are kept apart)"));
      return;
    }
    localStorage.setItem(RATER_KEY, rater);
    go(`/tasks/${id}/rate${query({ rater, n: n.value, seed: seed.value, operators: operators.value.trim() })}`);
  });
  const keys = h("p", { class: "muted" }, "Keys while rating: 1 or s — same, 2 or i — similar, 3 or d — different, ← back, → skip. You can leave and come back: the page continues where you stopped.");
  root.append(pageHead(id), protocol ? h("p", { class: "muted rating-protocol", testid: "rating-protocol" }, protocol) : null, form, keys, message, tallyFold(id, "Tally so far (Table 6-7), for the experimenter").panel);
  name.focus();
}

// The tally behind a fold (it names the operators, which raters must not see while rating): loaded when
// opened; `refresh()` reloads it while open. The latest request wins (opening and a verdict may both ask).
function tallyFold(id, summary) {
  const box = h("div", { testid: "tally" });
  const panel = h("details", { class: "rating-tally", testid: "tally-panel" }, h("summary", {}, summary), box);
  let asked = 0;
  async function show() {
    const mine = ++asked;
    let content;
    try {
      content = tallyTable(await api(`/api/tasks/${id}/ratings/tally`));
    } catch (exc) {
      content = notice("error", exc.message, exc.problems);
    }
    if (mine === asked) clear(box).append(content);
  }
  panel.addEventListener("toggle", () => panel.open && show());
  return { panel, refresh: () => panel.open && show(), open: () => (panel.open ? show() : (panel.open = true)) };
}

// Table 6-7: per operator × severity, verdicts summed over raters, shares, same + similar, Fleiss' kappa.
export function tallyTable(tally) {
  const pct = (v) => (v === null || v === undefined ? "—" : `${(100 * v).toFixed(1)}%`);
  const row = (r, total) =>
    h(
      "tr",
      { testid: total ? "tally-total" : "tally-row", class: total ? "total" : "" },
      h("td", {}, total ? h("b", {}, "all") : r.alias ? `${r.label} (${r.alias})` : r.label),
      VERDICTS.map(([key]) => h("td", { class: "num" }, `${r[key]} `, h("small", { class: "muted" }, pct(r.shares[key])))),
      h("td", { class: "num" }, r.total),
      h("td", { class: "num" }, pct(r.same_or_similar)),
      h("td", { class: "num" }, r.pairs),
      h("td", { class: "num" }, r.raters),
      h("td", { class: "num" }, formatNumber(r.kappa, 3)),
    );
  if (!tally.rows.length) return h("p", { class: "muted", testid: "tally-empty" }, "No verdicts yet.");
  return h(
    "div",
    {},
    h(
      "table",
      { class: "table tally-table", testid: "tally-table" },
      h("thead", {}, h("tr", {}, ["Operator", "Same", "Similar", "Different", "Verdicts", "Same + similar", "Pairs", "Raters", "Fleiss' κ"].map((t) => h("th", {}, t)))),
      h("tbody", {}, tally.rows.map((r) => row(r, false)), row(tally.total, true)),
    ),
    h(
      "p",
      { class: "muted" },
      `Raters: ${tally.raters.join(", ")}. Counts are summed over raters, as in the thesis (valid operators: same + similar above 95%). ` +
        "Fleiss' kappa (not in the thesis) is over the pairs rated by two or more; — when undefined.",
    ),
  );
}

export async function ratingPage(root, id, params) {
  const draw = drawParams(params);
  if (!draw.rater) {
    let protocol = "";
    try {
      protocol = (await api(`/api/tasks/${id}/ratings/pairs?per_operator=1`)).protocol;
    } catch (exc) {
      root.append(pageHead(id), notice("error", exc.message, exc.problems));
      return;
    }
    startForm(root, id, draw, protocol);
    return;
  }
  const args = { rater: draw.rater, per_operator: draw.n, seed: draw.seed, operators: draw.operators };
  let reply;
  try {
    reply = await api(`/api/tasks/${id}/ratings/pairs${query(args)}`);
  } catch (exc) {
    root.append(pageHead(id), notice("error", exc.message, exc.problems));
    return;
  }
  const pairs = reply.pairs;
  const firstOpen = pairs.findIndex((p) => !p.verdict);
  let index = firstOpen === -1 ? Math.max(0, pairs.length - 1) : firstOpen;
  const picture = h("img", { class: "rating-picture", testid: "pair-picture", alt: "original (left) and mutant (right) from above" });
  const camera = h("img", { class: "rating-camera", testid: "camera-image", alt: "the frame's camera image", hidden: true });
  camera.addEventListener("error", () => (camera.hidden = true));
  camera.addEventListener("load", () => (camera.hidden = false));
  const progress = h("div", { class: "rating-progress" });
  const position = h("span", { class: "muted", testid: "pair-position" });
  const message = h("div");
  const buttons = Object.fromEntries(
    VERDICTS.map(([key, label, keys, meaning]) => [
      key,
      h("button", { class: "verdict", testid: `verdict-${key}`, title: meaning, onclick: () => rate(key) }, label, " ", h("kbd", {}, keys[0]), "/", h("kbd", {}, keys[1])),
    ]),
  );
  const back = h("button", { testid: "rating-back", onclick: () => move(-1) }, "← Back");
  const skip = h("button", { testid: "rating-skip", onclick: () => move(1) }, "Skip →");
  const tally = tallyFold(id, "Tally (Table 6-7) — it names the operators: open it once you are done");
  const done = h("div", { testid: "rating-done" });
  const csv = h("button", { testid: "export-ratings-csv", onclick: () => download(`/api/tasks/${id}/ratings.csv`, `task-${id}-ratings.csv`).catch((exc) => message.append(notice("error", exc.message))) }, "Ratings CSV");

  root.append(
    pageHead(id, h("span", { class: "muted", testid: "rater" }, `rater: ${draw.rater}`), h("a", { class: "button", href: `#/tasks/${id}/rate${query({ n: draw.n, seed: draw.seed, operators: draw.operators })}`, testid: "change-rater", onclick: () => localStorage.removeItem(RATER_KEY) }, "Change rater"), csv),
    h("p", { class: "muted rating-protocol" }, reply.protocol, reply.excluded.length ? ` Left out here: ${reply.excluded.join(", ")}.` : ""),
    h("div", { class: "toolbar" }, progress, position),
    message,
    done,
    h("div", { class: "rating-actions toolbar", testid: "rating-actions" }, back, Object.values(buttons), skip),
    h("div", { class: "rating-stage" }, picture, camera),
    tally.panel,
  );

  function render() {
    const rated = pairs.filter((p) => p.verdict).length;
    clear(progress).append(progressBar(rated, pairs.length, "rating-progress"));
    clear(done);
    if (!pairs.length) {
      done.append(notice("notice", "This draw has no pairs: the task has no mutants to rate yet."));
      return;
    }
    const pair = pairs[index];
    position.textContent = `pair ${index + 1} of ${pairs.length} · frame ${pair.frame_id}${pair.verdict ? ` · your verdict: ${pair.verdict}` : ""}`;
    picture.dataset.pairId = String(pair.id);
    picture.dataset.index = String(index);
    picture.src = withToken(pair.picture);
    camera.hidden = true;
    camera.src = withToken(pair.camera);
    for (const [key, button] of Object.entries(buttons)) button.classList.toggle("chosen", pair.verdict === key);
    back.disabled = index === 0;
    skip.disabled = index === pairs.length - 1;
    if (rated === pairs.length) {
      done.append(notice("notice", `All ${pairs.length} pairs rated — thank you. The tally is below; change a verdict with ← and a key.`, [], "rating-complete"));
      tally.open();
    }
    const next = pairs[index + 1];
    if (next) new Image().src = withToken(next.picture); // the next picture is ready when it is asked for
  }

  function move(step) {
    const target = index + step;
    if (target < 0 || target >= pairs.length) return;
    index = target;
    clear(message);
    render();
  }

  async function rate(verdict) {
    const pair = pairs[index];
    if (!pair) return;
    clear(message);
    try {
      const saved = await api(`/api/tasks/${id}/ratings/pairs/${pair.id}`, { method: "PUT", body: { rater: draw.rater, verdict } });
      pair.verdict = saved.verdict;
      pair.rated_at = saved.rated_at;
    } catch (exc) {
      message.append(notice("error", exc.message, exc.problems));
      return;
    }
    // on to the next pair not rated yet (after this one, else from the start); stay when all are rated
    const after = pairs.findIndex((p, i) => i > index && !p.verdict);
    const open = after !== -1 ? after : pairs.findIndex((p) => !p.verdict);
    if (open !== -1) index = open;
    tally.refresh();
    render();
  }

  function onKey(event) {
    if (event.altKey || event.ctrlKey || event.metaKey) return;
    if (event.target instanceof HTMLElement && event.target.closest("input, textarea, select")) return;
    const key = event.key.toLowerCase();
    const verdict = VERDICTS.find(([, , keys]) => keys.includes(key));
    if (verdict) {
      event.preventDefault();
      rate(verdict[0]);
    } else if (key === "arrowleft") {
      event.preventDefault();
      move(-1);
    } else if (key === "arrowright") {
      event.preventDefault();
      move(1);
    }
  }

  document.addEventListener("keydown", onKey);
  render();
  return () => document.removeEventListener("keydown", onKey);
}
