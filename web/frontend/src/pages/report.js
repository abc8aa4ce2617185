// Report: the task's self-contained HTML report (the thesis's AP table, charts, violations,
// findings) embedded, with export buttons for HTML, JSON, CSV and JUnit XML. The frame fills the rest
// of the window exactly, so the report scrolls inside it and the page itself does not scroll (one
// scroll bar, not a scroll inside a scroll).
import { download, fetchBlob, withToken } from "../api.js";
import { clear, h, notice } from "../dom.js";

const EXPORTS = [
  ["HTML", "report", "report.html"],
  ["JSON", "report.json", "report.json"],
  ["AP CSV", "ap.csv", "ap.csv"],
  ["Violations CSV", "violations.csv", "violations.csv"],
  ["Findings CSV", "findings.csv", "findings.csv"],
  ["Ratings CSV", "ratings.csv", "ratings.csv"],
  ["JUnit XML", "junit.xml", "junit.xml"],
];

export async function reportPage(root, id) {
  const message = h("div");
  const frame = h("iframe", {
    class: "report-frame",
    title: `report of task ${id}`,
    testid: "report-frame",
    // the report's own scripts (difficulty / R40 switches) run, but in an opaque origin
    sandbox: "allow-scripts allow-popups allow-popups-to-escape-sandbox",
  });
  const buttons = EXPORTS.map(([label, path, filename]) =>
    h(
      "button",
      {
        testid: `export-${path.replace(/\W/g, "-")}`,
        onclick: async () => {
          clear(message);
          try {
            await download(`/api/tasks/${id}/${path}`, `task-${id}-${filename}`);
          } catch (exc) {
            message.append(notice("error", exc.message));
          }
        },
      },
      label,
    ),
  );
  root.append(
    h(
      "div",
      { class: "page-head" },
      h("h1", {}, `Report of task #${id}`),
      h("span", { class: "spacer" }),
      h("a", { class: "button", href: `#/tasks/${id}` }, "Task"),
      h("a", { class: "button", href: `#/tasks/${id}/findings` }, "Findings"),
      h("a", { class: "button", href: withToken(`/api/tasks/${id}/report`), target: "_blank", rel: "noopener", testid: "report-open" }, "Open in a new tab"),
    ),
    h("div", { class: "toolbar exports", testid: "exports" }, h("span", { class: "label" }, "Export"), buttons),
    message,
    h("p", { class: "muted", testid: "report-loading" }, "Writing the report…"),
    frame,
  );
  // the frame's height: what is left of the window below its top, less any overflow of the page
  function fit() {
    if (!frame.isConnected) return;
    frame.style.minHeight = "0";
    frame.style.height = `${Math.max(240, window.innerHeight - frame.getBoundingClientRect().top - window.scrollY - 8)}px`;
    const overflow = document.documentElement.scrollHeight - window.innerHeight;
    if (overflow > 0) frame.style.height = `${Math.max(240, frame.getBoundingClientRect().height - overflow)}px`;
  }
  window.addEventListener("resize", fit);
  requestAnimationFrame(fit);
  try {
    const blob = await fetchBlob(`/api/tasks/${id}/report`);
    frame.srcdoc = await blob.text();
    root.querySelector("[data-testid=report-loading]")?.remove();
  } catch (exc) {
    root.querySelector("[data-testid=report-loading]")?.remove();
    message.append(notice("error", exc.message, exc.problems));
  }
  fit();
  return () => window.removeEventListener("resize", fit);
}
