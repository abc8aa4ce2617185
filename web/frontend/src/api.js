// Talking to the lidarfuzz API: the bearer token, JSON calls, binary frames, server-sent events,
// uploads with progress, and errors turned into messages that name the file, line or field.

const TOKEN_KEY = "lidarfuzz.token";

// Opened as /?token=T: keep T for this tab and take it out of the address bar (and the history).
export function initToken() {
  const params = new URLSearchParams(window.location.search);
  const token = params.get("token");
  if (token) {
    sessionStorage.setItem(TOKEN_KEY, token);
    params.delete("token");
    const query = params.toString();
    history.replaceState(null, "", window.location.pathname + (query ? `?${query}` : "") + window.location.hash);
  }
}

export function token() {
  return sessionStorage.getItem(TOKEN_KEY);
}

export function setToken(value) {
  if (value) sessionStorage.setItem(TOKEN_KEY, value);
  else sessionStorage.removeItem(TOKEN_KEY);
}

function authHeaders(extra = {}) {
  const t = token();
  return t ? { ...extra, Authorization: `Bearer ${t}` } : extra;
}

// For URLs the browser fetches itself (EventSource, <a href>, <img>): the token as a query parameter.
export function withToken(url) {
  const t = token();
  if (!t) return url;
  return `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(t)}`;
}

export function query(params) {
  const entries = Object.entries(params).filter(([, v]) => v !== undefined && v !== null && v !== "");
  return entries.length ? `?${new URLSearchParams(entries).toString()}` : "";
}

// One problem: {message, file?, line?, field?}. FastAPI's validation list, a lidarfuzz
// "file:line: field 'x': message" string (one per line) or a list of either all map onto it.
export function problemsFrom(detail) {
  if (detail === undefined || detail === null) return [];
  if (Array.isArray(detail)) return detail.flatMap((item) => problemsFrom(item));
  if (typeof detail === "object") {
    if (Array.isArray(detail.problems)) return detail.problems.flatMap((item) => problemsFrom(item));
    if (Array.isArray(detail.loc)) {
      const loc = detail.loc.filter((part) => part !== "body" && part !== "query" && part !== "path");
      return [{ message: detail.msg ?? JSON.stringify(detail), field: loc.join(".") }];
    }
    const message = detail.message ?? detail.msg ?? detail.detail ?? JSON.stringify(detail);
    return [{ message: String(message), file: detail.file ?? detail.path, line: detail.line, field: detail.field }];
  }
  return String(detail)
    .split("\n")
    .map((line) => line.trim())
    .filter(Boolean)
    .map(parseProblemLine);
}

const PROBLEM_LINE = /^(?<file>[^\s:][^:]*?)(?::(?<line>\d+))?: (?:field '(?<field>[^']+)': )?(?<message>.+)$/;

function parseProblemLine(text) {
  const match = PROBLEM_LINE.exec(text.replace(/^[-*•]\s*/, ""));
  if (!match) return { message: text };
  const { file, line, field, message } = match.groups;
  // "dataset: no data set named x" names a field, not a file
  const looksLikeFile = /[/\\.]/.test(file) && !/\s/.test(file);
  if (!looksLikeFile) return { message: field ? `${field}: ${message}` : message, field: field ?? file };
  return { file, line: line ? Number(line) : undefined, field, message };
}

export class ApiError extends Error {
  constructor(status, detail, url) {
    const problems = problemsFrom(detail);
    const text = typeof detail === "string" ? detail : typeof detail?.detail === "string" ? detail.detail : null;
    const summary =
      text !== null && problems.length <= 1
        ? text.split("\n")[0]
        : problems.length === 1
          ? problems[0].message
          : `${problems.length || "several"} problems`;
    super(`${status === 0 ? "network error" : `HTTP ${status}`}: ${summary || "request failed"}`);
    this.status = status;
    this.detail = detail;
    this.problems = problems;
    this.url = url;
  }
}

// The error body: {detail, problems?} keeps its problem list; otherwise its detail.
function detailOf(body) {
  if (body && typeof body === "object" && !Array.isArray(body)) return Array.isArray(body.problems) ? body : (body.detail ?? body);
  return body;
}

async function errorFrom(response) {
  let detail = response.statusText;
  try {
    const text = await response.text();
    try {
      detail = detailOf(JSON.parse(text));
    } catch {
      detail = text || response.statusText;
    }
  } catch {
    // the body is gone: the status line has to do
  }
  return new ApiError(response.status, detail, response.url);
}

// JSON in, JSON out. `form`: a FormData sent as multipart instead of `body`.
export async function api(path, { method = "GET", body, form, signal } = {}) {
  const headers = authHeaders(body !== undefined ? { "Content-Type": "application/json", Accept: "application/json" } : { Accept: "application/json" });
  let response;
  try {
    response = await fetch(path, { method, headers, body: form ?? (body !== undefined ? JSON.stringify(body) : undefined), signal });
  } catch (exc) {
    if (exc.name === "AbortError") throw exc;
    throw new ApiError(0, String(exc.message ?? exc), path);
  }
  if (!response.ok) throw await errorFrom(response);
  if (response.status === 204) return null;
  const type = response.headers.get("content-type") ?? "";
  return type.includes("json") ? response.json() : response.text();
}

export async function fetchBinary(path, { signal } = {}) {
  const response = await fetch(path, { headers: authHeaders({ Accept: "application/octet-stream" }), signal });
  if (!response.ok) throw await errorFrom(response);
  return response.arrayBuffer();
}

export async function fetchBlob(path, { signal } = {}) {
  const response = await fetch(path, { headers: authHeaders(), signal });
  if (!response.ok) throw await errorFrom(response);
  return response.blob();
}

// Save what a URL returns under `filename` (the export buttons).
export async function download(path, filename) {
  const blob = await fetchBlob(path);
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

// Multipart upload with progress (fetch cannot report upload progress); resolves to the JSON reply.
export function upload(path, form, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", path);
    const t = token();
    if (t) xhr.setRequestHeader("Authorization", `Bearer ${t}`);
    xhr.setRequestHeader("Accept", "application/json");
    xhr.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable && onProgress) onProgress(event.loaded, event.total);
    });
    xhr.addEventListener("load", () => {
      let body = xhr.responseText;
      try {
        body = JSON.parse(body);
      } catch {
        // not JSON: keep the text
      }
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(new ApiError(xhr.status, detailOf(body), path));
    });
    xhr.addEventListener("error", () => reject(new ApiError(0, "the upload failed (connection lost)", path)));
    xhr.send(form);
  });
}

// Server-sent events: `handlers` maps event names to callbacks that receive the parsed JSON.
export function subscribe(path, handlers) {
  const source = new EventSource(withToken(path));
  for (const [name, handler] of Object.entries(handlers)) {
    if (name === "error" || name === "open") continue;
    source.addEventListener(name, (event) => {
      let data = event.data;
      try {
        data = JSON.parse(event.data);
      } catch {
        // plain text event
      }
      handler(data, event);
    });
  }
  if (handlers.error) source.addEventListener("error", handlers.error);
  if (handlers.open) source.addEventListener("open", handlers.open);
  return source;
}

// Lists come as arrays or wrapped ({tasks: [...], total}); this takes either.
export function listOf(reply, ...keys) {
  if (Array.isArray(reply)) return reply;
  for (const key of [...keys, "items", "results", "data"]) {
    if (Array.isArray(reply?.[key])) return reply[key];
  }
  return [];
}

export function nameOf(value) {
  if (value === null || value === undefined) return "";
  if (typeof value === "object") return value.name ?? value.id ?? "";
  return String(value);
}
