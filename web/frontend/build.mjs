// Builds the front end into src/lidarfuzz/web/static/ (committed, so `pip install` needs no Node):
//   index.html, app.js (+ chunks/ for the lazily loaded viewer), app.css,
//   vendor/swagger-ui/{swagger-ui-bundle.js, swagger-ui.css} for the offline API docs,
//   build.json: the sha256 of the sources (tests/web/test_bundle.py recomputes it) and of every output.
//
//   node build.mjs           build
//   node build.mjs --check   exit 1 when the committed bundle is older than its sources
import { createHash } from "node:crypto";
import { copyFileSync, mkdirSync, readdirSync, readFileSync, rmSync, statSync, writeFileSync } from "node:fs";
import { dirname, join, relative, sep } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const out = join(here, "..", "..", "src", "lidarfuzz", "web", "static");

function walk(dir) {
  return readdirSync(dir).flatMap((name) => {
    const path = join(dir, name);
    return statSync(path).isDirectory() ? walk(path) : [path];
  });
}

const posix = (path) => path.split(sep).join("/");

// The inputs (src/**, this script, package.json and its lock), as paths relative to web/frontend,
// sorted by their UTF-8 bytes (= Python's sorted()).
export function sourceFiles() {
  const files = [
    ...walk(join(here, "src")).map((p) => posix(relative(here, p))),
    "build.mjs",
    "package.json",
    "package-lock.json",
  ];
  return files.sort((a, b) => Buffer.compare(Buffer.from(a), Buffer.from(b)));
}

// sha256 over, for each file: its path, NUL, its byte length in decimal, NUL, its bytes.
export function sourceHash() {
  const hash = createHash("sha256");
  for (const path of sourceFiles()) {
    const data = readFileSync(join(here, path));
    hash.update(path);
    hash.update("\0");
    hash.update(String(data.length));
    hash.update("\0");
    hash.update(data);
  }
  return hash.digest("hex");
}

const sha256 = (data) => createHash("sha256").update(data).digest("hex");

if (process.argv.includes("--check")) {
  const recorded = JSON.parse(readFileSync(join(out, "build.json"), "utf8")).source_sha256;
  const actual = sourceHash();
  if (recorded !== actual) {
    console.error(`static/ is stale: built from ${recorded}, sources are ${actual}; run npm run build`);
    process.exit(1);
  }
  console.log("static/ is up to date");
  process.exit(0);
}

const esbuild = await import("esbuild");
rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });

const result = await esbuild.build({
  entryPoints: { app: join(here, "src", "main.js") },
  bundle: true,
  splitting: true, // the viewer (three.js) is a chunk loaded when a viewer page opens
  format: "esm",
  target: ["es2020"],
  minify: true,
  legalComments: "none",
  sourcemap: false,
  outdir: out,
  entryNames: "[name]",
  chunkNames: "chunks/[name]-[hash]",
  metafile: true,
  logLevel: "warning",
});
// app.css: one stylesheet, bundled from src/app.css and its imports
await esbuild.build({
  entryPoints: { app: join(here, "src", "app.css") },
  bundle: true,
  minify: true,
  outdir: out,
  logLevel: "warning",
});
copyFileSync(join(here, "src", "index.html"), join(out, "index.html"));
const vendor = join(out, "vendor", "swagger-ui");
mkdirSync(vendor, { recursive: true });
for (const name of ["swagger-ui-bundle.js", "swagger-ui.css", "LICENSE", "NOTICE"]) {
  copyFileSync(join(here, "node_modules", "swagger-ui-dist", name), join(vendor, name));
}
copyFileSync(join(here, "node_modules", "three", "LICENSE"), join(out, "chunks", "three.LICENSE"));

const files = {};
for (const path of walk(out).map((p) => posix(relative(out, p))).sort()) {
  if (path !== "build.json") files[path] = sha256(readFileSync(join(out, path)));
}
const lock = JSON.parse(readFileSync(join(here, "package-lock.json"), "utf8"));
const versions = Object.fromEntries(
  ["three", "swagger-ui-dist", "esbuild"].map((name) => [name, lock.packages[`node_modules/${name}`]?.version]),
);
const build = { source_sha256: sourceHash(), sources: sourceFiles(), versions, files };
writeFileSync(join(out, "build.json"), JSON.stringify(build, null, 2) + "\n");

const sizes = Object.entries(result.metafile.outputs).map(([path, o]) => `${posix(relative(out, path))} ${o.bytes}`);
console.log(`built ${posix(relative(process.cwd(), out))}: ${sizes.join(", ")}`);
