// The single-page app: a hash router over the pages; each page renders into <main> and returns
// a clean-up function (close its event stream, dispose its viewer) called when the route changes.
import { api, initToken } from "./api.js";
import { clear, h, notice } from "./dom.js";
import { datasetDetailPage, datasetsPage } from "./pages/datasets.js";
import { browsePage, frameViewerPage } from "./pages/browse.js";
import { comparePage } from "./pages/compare.js";
import { findingsPage } from "./pages/findings.js";
import { findingViewerPage } from "./pages/finding.js";
import { modelDetailPage, modelsPage } from "./pages/models.js";
import { newTaskPage } from "./pages/newtask.js";
import { ratingPage } from "./pages/rating.js";
import { reportPage } from "./pages/report.js";
import { taskDetailPage } from "./pages/taskdetail.js";
import { tasksPage } from "./pages/tasks.js";

const routes = [
  [/^\/?$/, () => tasksPage, "tasks"],
  [/^\/tasks$/, () => tasksPage, "tasks"],
  [/^\/tasks\/new$/, () => newTaskPage, "tasks"],
  [/^\/compare$/, () => comparePage, "tasks"],
  [/^\/tasks\/(\d+)$/, (m) => (root) => taskDetailPage(root, Number(m[1])), "tasks"],
  [/^\/tasks\/(\d+)\/report$/, (m) => (root) => reportPage(root, Number(m[1])), "tasks"],
  [/^\/tasks\/(\d+)\/rate$/, (m) => (root, q) => ratingPage(root, Number(m[1]), q), "tasks"],
  [/^\/tasks\/(\d+)\/findings$/, (m) => (root, q) => findingsPage(root, Number(m[1]), q), "tasks"],
  [/^\/findings\/(\d+)$/, (m) => (root, q) => findingViewerPage(root, Number(m[1]), q), "tasks"],
  [/^\/datasets$/, () => datasetsPage, "datasets"],
  [/^\/datasets\/([^/]+)$/, (m) => (root) => datasetDetailPage(root, decodeURIComponent(m[1])), "datasets"],
  [/^\/models$/, () => modelsPage, "models"],
  [/^\/models\/([^/]+)$/, (m) => (root) => modelDetailPage(root, decodeURIComponent(m[1])), "models"],
  [/^\/browse$/, () => (root) => browsePage(root, null), "browse"],
  [/^\/browse\/([^/]+)$/, (m) => (root, q) => browsePage(root, decodeURIComponent(m[1]), q), "browse"],
  [
    /^\/browse\/([^/]+)\/([^/]+)$/,
    (m) => (root) => frameViewerPage(root, decodeURIComponent(m[1]), decodeURIComponent(m[2])),
    "browse",
  ],
];

let cleanup = null;
let generation = 0;

async function route() {
  const root = document.getElementById("page");
  const [path, search] = window.location.hash.replace(/^#/, "").split("?");
  const params = new URLSearchParams(search ?? "");
  if (cleanup) {
    try {
      cleanup();
    } catch (exc) {
      console.error(exc);
    }
    cleanup = null;
  }
  const mine = ++generation;
  clear(root);
  // each render draws into a view of its own: a render overtaken by a later one (two hash changes in
  // quick succession) finishes into its detached view instead of adding to the current page
  const view = h("div", { class: "view" });
  root.append(view);
  let page = null;
  let section = "";
  for (const [pattern, make, nav] of routes) {
    const match = pattern.exec(path || "/");
    if (match) {
      page = make(match);
      section = nav;
      break;
    }
  }
  for (const link of document.querySelectorAll("[data-nav]")) {
    link.classList.toggle("active", link.dataset.nav === section);
  }
  if (!page) {
    view.append(notice("error", `No page at ${path}.`), h("p", {}, h("a", { href: "#/tasks" }, "Back to the tasks")));
    return;
  }
  try {
    const result = await page(view, params);
    if (mine !== generation) {
      if (typeof result === "function") result();
      return;
    }
    cleanup = typeof result === "function" ? result : null;
  } catch (exc) {
    console.error(exc);
    if (mine === generation) view.append(notice("error", String(exc.message ?? exc), exc.problems ?? []));
  }
}

async function showServer() {
  const el = document.querySelector("[data-testid=server]");
  try {
    const health = await api("/api/health");
    el.textContent = [health.version ? `v${health.version}` : "", health.workspace ?? ""].filter(Boolean).join(" · ");
    el.title = health.token_required ? "this server requires a token" : "";
  } catch (exc) {
    el.textContent = exc.status === 401 ? "token required: open this page as /?token=…" : "server unreachable";
    el.classList.add("server-error");
  }
}

initToken();
window.addEventListener("hashchange", route);
if (document.readyState === "loading") {
  document.addEventListener("DOMContentLoaded", () => {
    route();
    showServer();
  });
} else {
  route();
  showServer();
}
