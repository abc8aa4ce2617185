// A tiny DOM builder: h("a", {href, class, testid, onclick}, "text", child, [children]).

export function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs ?? {})) {
    if (value === undefined || value === null || value === false) continue;
    if (key === "class") el.className = value;
    else if (key === "testid") el.dataset.testid = value;
    else if (key === "dataset") Object.assign(el.dataset, value);
    else if (key === "style" && typeof value === "object") Object.assign(el.style, value);
    else if (key.startsWith("on") && typeof value === "function") el.addEventListener(key.slice(2), value);
    else if (key in el && typeof value !== "string") el[key] = value;
    else el.setAttribute(key, value === true ? "" : String(value));
  }
  append(el, children);
  return el;
}

export function append(el, children) {
  for (const child of children.flat(Infinity)) {
    if (child === undefined || child === null || child === false) continue;
    el.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return el;
}

export function clear(el) {
  while (el.firstChild) el.firstChild.remove();
  return el;
}

// SVG elements need their namespace.
export function svg(tag, attrs = {}, ...children) {
  const el = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [key, value] of Object.entries(attrs)) {
    if (value === undefined || value === null) continue;
    if (key === "testid") el.setAttribute("data-testid", value);
    else el.setAttribute(key, String(value));
  }
  append(el, children);
  return el;
}

export function progressBar(done, total, testid) {
  const fraction = total > 0 ? Math.min(1, done / total) : 0;
  return h(
    "div",
    { class: "progress", testid, role: "progressbar", "aria-valuenow": done, "aria-valuemax": total },
    h("div", { class: "progress-fill", style: { width: `${(fraction * 100).toFixed(1)}%` } }),
    h("span", { class: "progress-text" }, `${done} / ${total}`),
  );
}

export function statusBadge(status) {
  const value = String(status ?? "unknown").toLowerCase();
  return h("span", { class: `badge status-${value}`, testid: "status" }, value);
}

// ISO 8601 in local time, "YYYY-MM-DD HH:MM:SS": one format in every page, whatever the browser's locale.
export function formatTime(value) {
  if (!value) return "—";
  const date = new Date(value);
  if (Number.isNaN(date.getTime())) return String(value);
  const two = (n) => String(n).padStart(2, "0");
  const day = `${date.getFullYear()}-${two(date.getMonth() + 1)}-${two(date.getDate())}`;
  return `${day} ${two(date.getHours())}:${two(date.getMinutes())}:${two(date.getSeconds())}`;
}

export function formatNumber(value, digits = 2) {
  if (value === null || value === undefined || Number.isNaN(value)) return "—";
  return typeof value === "number" ? value.toFixed(digits) : String(value);
}

// A message box for errors and notices; `problems` renders a list (validation errors with file and line).
export function notice(kind, message, problems = [], testid = kind === "error" ? "error" : "notice") {
  return h(
    "div",
    { class: `notice notice-${kind}`, testid, role: kind === "error" ? "alert" : "status" },
    h("div", {}, message),
    problems.length
      ? h(
          "ul",
          { class: "problems", testid: "problems" },
          problems.map((p) =>
            h(
              "li",
              {},
              p.file ? h("code", { class: "problem-file" }, p.line ? `${p.file}:${p.line}` : p.file) : null,
              p.file ? " " : null,
              p.message,
            ),
          ),
        )
      : null,
  );
}

export function emptyRow(columns, text) {
  return h("tr", { class: "empty" }, h("td", { colspan: columns }, text));
}

export function go(path) {
  window.location.hash = `#${path}`;
}

// Runs `fn` every `ms` while the page is shown; returns the stop function.
export function every(ms, fn) {
  const id = setInterval(fn, ms);
  return () => clearInterval(id);
}
