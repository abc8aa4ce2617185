"""A seeded mutation fuzzer over every file a user can hand lidarfuzz.

A :class:`Target` says how to make valid files (``seeds``, from lidarfuzz's own writers) and
what lidarfuzz does with a user's file (``read``, through the Python API; ``cli``, a command
line). :func:`fuzz` mutates the seeds (byte flips, truncations, insertions, splices between
seeds, integer extremes in binary header fields and in the numbers of text, very long lines,
deep nesting), runs every case in a persistent child process under an address-space limit and
a per-case time limit, and sorts each case into one of :data:`OUTCOMES`:

``ok``       read without error;
``refused``  a :class:`~lidarfuzz.errors.LidarfuzzError` (the one-line refusal a user should get);
``foreign``  any other exception escaped (its type and the innermost lidarfuzz frame are kept);
``hang``     the case ran past the time limit (the child is killed and restarted);
``abort``    the child died by a signal (a native library's SIGABRT or SIGSEGV);
``memory``   ``MemoryError`` escaped, or the child died of the address-space limit.

The last four are escapes: each is shrunk (truncation and chunk removal while its outcome holds)
and saved under the results folder with the command that reproduces it. Cases are reproducible:
case ``i`` of a target depends only on ``(seed, target name, i)``.

Reproduce a saved case::

    python -m tests.fuzz.harness reproduce --module tests.fuzz.targets_points --target pcd-binary FILE
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import random
import re
import resource
import select
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
OUTCOMES = ("ok", "refused", "foreign", "hang", "abort", "memory")
ESCAPES = ("foreign", "hang", "abort", "memory")
GIB = 1 << 30
#: Address-space limit of the child that reads the cases (the issue's budget).
DEFAULT_MEMORY = 4 * GIB
#: Seconds one case may take before it counts as a hang.
DEFAULT_TIME_LIMIT = 10.0


@dataclass(frozen=True)
class Target:
    """One kind of file a user can hand lidarfuzz, and what lidarfuzz does with it.

    Attributes:
        name: ``"pcd-binary"``, ``"kitti-label"``, ``"campaign-yaml"``, ...
        filename: The mutated case is written as ``<case folder>/<filename>``.
        seeds: Valid files made by lidarfuzz's own writers, given a scratch folder.
        read: What lidarfuzz does with a user's file through the Python API; may create
            sibling files next to the case (a KITTI folder around a label file, say).
        cli: A command line with ``"{path}"`` for the case, e.g. ``("info", "{path}")``.
    """

    name: str
    filename: str
    seeds: Callable[[Path], list[bytes]]
    read: Callable[[Path], object]
    cli: tuple[str, ...] | None = None


# --------------------------------------------------------------------------- mutation

#: Integers that break size arithmetic: zero, -1, sign and width boundaries.
EXTREME_INTS = (0, -1, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1, 10**12, 10**6)
#: Tokens put in place of a number in a text file.
EXTREME_TOKENS = (b"0", b"-1", b"2147483648", b"4294967295", b"9223372036854775808", b"18446744073709551616",
                  b"1000000000000", b"1e308", b"-1e308", b"1e309", b"nan", b"inf", b"-inf", b"1" * 400, b"0x10",
                  b"", b"1.5", b"-0")
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _flip(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    out = bytearray(data)
    for _ in range(rng.choice((1, 1, 2, 4, 16))):
        if out:
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
    return bytes(out)


def _random_bytes(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    out = bytearray(data)
    for _ in range(rng.choice((1, 2, 8))):
        if out:
            out[rng.randrange(len(out))] = rng.randrange(256)
    return bytes(out)


def _truncate(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    return data[: rng.randrange(len(data) + 1)] if data else data


def _insert(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    at = rng.randrange(len(data) + 1)
    chunk = rng.choice((bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64))), b"\x00" * 64, b"\xff" * 8,
                        b"\n", b" ", data[at:at + rng.randrange(1, 256)]))
    return data[:at] + chunk + data[at:]


def _delete(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    if not data:
        return data
    at = rng.randrange(len(data))
    return data[:at] + data[at + rng.randrange(1, 128):]


def _splice(rng: random.Random, data: bytes, seeds: Sequence[bytes]) -> bytes:
    other = rng.choice(seeds)
    return data[: rng.randrange(len(data) + 1)] + other[rng.randrange(len(other) + 1):]


def _binary_extreme(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    """An extreme integer written over a header field (little- or big-endian, 1 to 8 bytes)."""
    if not data:
        return data
    width = rng.choice((1, 2, 4, 4, 8))
    window = min(len(data), rng.choice((64, 256, 512, 4096)))
    at = rng.randrange(max(window - width, 0) + 1) & ~(rng.choice((0, width - 1)))
    value = rng.choice(EXTREME_INTS) % (1 << (8 * width))
    raw = value.to_bytes(width, rng.choice(("little", "little", "big")))
    return data[:at] + raw + data[at + width:]


def _text_extreme(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    """An extreme token put in place of one number in the first 8 KB (headers, text values)."""
    numbers = list(_NUMBER.finditer(data[:8192]))
    if not numbers:
        return _binary_extreme(rng, data, _)
    match = rng.choice(numbers)
    return data[: match.start()] + rng.choice(EXTREME_TOKENS) + data[match.end():]


def _long_line(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    at = rng.randrange(len(data) + 1)
    return data[:at] + rng.choice((b"A", b"1", b" ", b"1 ", b"#")) * rng.choice((10_000, 1_000_000)) + data[at:]


def _deep_nesting(rng: random.Random, data: bytes, _: Sequence[bytes]) -> bytes:
    at = rng.randrange(len(data) + 1)
    depth = rng.choice((200, 5_000, 100_000))
    opener, closer = rng.choice(((b"[", b"]"), (b"{", b"}"), (b"(", b")"), (b"- ", b""), (b"{a: ", b"}")))
    return data[:at] + opener * depth + closer * rng.choice((0, depth)) + data[at:]


MUTATORS: tuple[Callable[[random.Random, bytes, Sequence[bytes]], bytes], ...] = (
    _flip, _flip, _random_bytes, _truncate, _insert, _delete, _splice, _binary_extreme, _binary_extreme,
    _text_extreme, _text_extreme, _text_extreme, _long_line, _deep_nesting,
)


def mutate(seeds: Sequence[bytes], seed: int, target: str, index: int) -> bytes:
    """Case ``index`` of a target: one to three mutations of one of its seeds (reproducible)."""
    rng = random.Random(f"{seed}:{target}:{index}")
    data = rng.choice(seeds)
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        data = rng.choice(MUTATORS)(rng, data, seeds)
    return data


# --------------------------------------------------------------------------- the child

def _innermost_lidarfuzz_frame(tb: Any) -> str:
    where = "?"
    for frame in traceback.extract_tb(tb):
        if f"{os.sep}lidarfuzz{os.sep}" in frame.filename and f"{os.sep}tests{os.sep}" not in frame.filename:
            where = f"{frame.filename.rsplit(os.sep + 'lidarfuzz' + os.sep, 1)[-1]}:{frame.lineno} ({frame.name})"
    return where


def classify_call(read: Callable[[Path], object], path: Path) -> dict[str, str]:
    """Run one case in this process and classify what came out of it."""
    from lidarfuzz.errors import LidarfuzzError

    try:
        read(path)
    except LidarfuzzError as exc:
        return {"outcome": "refused", "message": str(exc)[:500]}
    except MemoryError as exc:
        return {"outcome": "memory", "type": "MemoryError", "where": _innermost_lidarfuzz_frame(exc.__traceback__),
                "message": str(exc)[:500]}
    except BaseException as exc:  # sorting every escape is the point
        if isinstance(exc, KeyboardInterrupt):
            raise
        kind = type(exc)
        return {"outcome": "foreign", "type": f"{kind.__module__}.{kind.__qualname__}",
                "where": _innermost_lidarfuzz_frame(exc.__traceback__), "message": str(exc)[:500]}
    return {"outcome": "ok"}


def _load_targets(modules: Iterable[str]) -> dict[str, Target]:
    targets: dict[str, Target] = {}
    for module in modules:
        for target in importlib.import_module(module).TARGETS:
            targets[target.name] = target
    return targets


def _limit_memory(limit: int, pid: int = 0) -> None:
    """Cap process ``pid``'s address space (0: this process) and switch off its core dumps. A
    child is capped once started, never by a ``preexec_fn`` (Python code between fork and exec
    can deadlock on a lock another thread held at the fork)."""
    resource.prlimit(pid, resource.RLIMIT_AS, (limit, limit))
    resource.prlimit(pid, resource.RLIMIT_CORE, (0, 0))


def _worker(modules: list[str], memory: int) -> None:
    """The child: reads ``{"target": name, "path": file}`` lines, answers one JSON line each."""
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever a reader prints goes to stderr, never into the answers
    targets = _load_targets(modules)
    _limit_memory(memory)
    answers.write(json.dumps({"ready": True}) + "\n")
    for line in sys.stdin:
        request = json.loads(line)
        answer = classify_call(targets[request["target"]].read, Path(request["path"]))
        answers.write(json.dumps(answer) + "\n")


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    # One thread per BLAS/Arrow pool: a pool's reserved stacks would count against the limit.
    # RUST_BACKTRACE=0: a Rust library's abort leaves its one-line reason ("memory allocation of …
    # bytes failed") at the end of stderr, not under a 40-frame backtrace
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", ARROW_NUM_THREADS="1",
               PYTHONFAULTHANDLER="", RUST_BACKTRACE="0",
               PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")])))
    return env


class Child:
    """A persistent child process that reads cases under the memory limit."""

    def __init__(self, modules: Sequence[str], memory: int = DEFAULT_MEMORY) -> None:
        self.modules = list(modules)
        self.memory = memory
        self.proc: subprocess.Popen[bytes] | None = None
        self.stderr_path = Path(tempfile.mkstemp(prefix="lidarfuzz-fuzz-", suffix=".stderr")[1])
        self._buffer = b""

    def _start(self) -> subprocess.Popen[bytes]:
        code = ("import sys; from tests.fuzz.harness import _worker; "
                f"_worker({self.modules!r}, {self.memory})")
        with open(self.stderr_path, "wb") as err:
            proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=err, cwd=REPO, env=_child_env(), start_new_session=True)
        self.proc, self._buffer = proc, b""
        try:
            ready = self._answer(120.0)
        except EOFError:
            ready = None
        if ready is None or not ready.get("ready"):
            tail = self.stderr_path.read_text(errors="replace")[-2000:]
            self.stop()
            raise RuntimeError(f"the fuzzing child did not start: {tail}")
        return proc

    def _answer(self, timeout: float) -> dict[str, Any] | None:
        assert self.proc is not None and self.proc.stdout is not None
        deadline = time.monotonic() + timeout
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                return None
            chunk = os.read(fd, 65536)
            if not chunk:
                raise EOFError  # the child died
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        answer: dict[str, Any] = json.loads(line)
        return answer

    def run(self, target: str, path: Path, time_limit: float) -> dict[str, Any]:
        """One case: its classification (``hang``/``abort``/``memory`` when the child had to go)."""
        proc = self.proc if self.proc is not None and self.proc.poll() is None else self._start()
        assert proc.stdin is not None
        self.stderr_path.write_bytes(b"")
        started = time.monotonic()
        try:
            proc.stdin.write((json.dumps({"target": target, "path": str(path)}) + "\n").encode())
            proc.stdin.flush()
        except BrokenPipeError:
            pass
        try:
            answer = self._answer(time_limit)
        except EOFError:
            answer = None
            proc.wait(timeout=30)
        if answer is not None:
            answer["seconds"] = time.monotonic() - started
            return answer
        if proc.poll() is None:
            self.stop()
            return {"outcome": "hang", "message": f"over {time_limit:g} s", "seconds": time.monotonic() - started}
        code = proc.wait()
        tail = self.stderr_path.read_text(errors="replace")[-1500:]
        self.proc = None
        out_of_memory = re.search(r"bad_alloc|memory allocation|out of memory|MemoryError|Cannot allocate", tail)
        if out_of_memory:
            outcome = "memory"
        elif code < 0:
            outcome = "abort"
        else:
            outcome = "foreign"  # the child exited on its own: a reader called sys.exit or os._exit
        name = signal.Signals(-code).name if code < 0 else f"exit {code}"
        return {"outcome": outcome, "type": name, "message": tail.strip().splitlines()[-1][:500] if tail.strip()
                else name, "seconds": time.monotonic() - started}

    def stop(self) -> None:
        if self.proc is not None:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            for stream in (self.proc.stdin, self.proc.stdout):
                if stream is not None:
                    stream.close()
            self.proc = None

    def close(self) -> None:
        self.stop()
        self.stderr_path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- CLI cases

def _lidarfuzz_command() -> list[str]:
    script = Path(sys.executable).with_name("lidarfuzz")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from lidarfuzz.cli.app import main; main()"]


def cli_failure(returncode: int, stderr: str, stdout: str = "") -> str | None:
    """Why a CLI run on a bad file is an escape (None when it refused or read the file properly, or
    reported it as a problem: ``info`` lists an unreadable frame on stdout and exits 1)."""
    if returncode < 0 or returncode >= 128:
        return f"exit code {returncode}"
    if "Traceback (most recent call last)" in stderr:
        return "a traceback on stderr"
    lines = [line for line in stderr.splitlines() if line.strip() and not line.startswith("lidarfuzz: warning:")]
    if len(lines) > 1:
        return f"an error of {len(lines)} lines, not one"
    if returncode != 0 and not lines and not stdout.strip():
        return f"exit code {returncode} without a word"
    return None


def run_cli(target: Target, path: Path, time_limit: float, memory: int = DEFAULT_MEMORY) -> dict[str, Any]:
    """Run the target's command line on one case (its own process, same limits)."""
    assert target.cli is not None
    argv = _lidarfuzz_command() + [part.replace("{path}", str(path)) for part in target.cli]
    started = time.monotonic()
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace",
                          cwd=path.parent, env=_child_env()) as process:
        with contextlib.suppress(ProcessLookupError):
            _limit_memory(memory, process.pid)
        try:
            stdout, stderr = process.communicate(timeout=time_limit)
        except subprocess.TimeoutExpired:
            process.kill()
            process.communicate()
            return {"outcome": "hang", "message": f"over {time_limit:g} s", "argv": argv}
    why = cli_failure(process.returncode, stderr, stdout)
    result: dict[str, Any] = {"outcome": "escape" if why else "ok", "returncode": process.returncode, "argv": argv,
                              "seconds": time.monotonic() - started}
    if why:
        result["message"] = f"{why}: {stderr.strip()[-800:]}"
    return result


# --------------------------------------------------------------------------- the campaign

@dataclass
class TargetReport:
    """What one target's cases came to."""

    name: str
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(OUTCOMES, 0))
    seconds: float = 0.0
    escapes: list[dict[str, Any]] = field(default_factory=list)
    cli_cases: int = 0
    cli_escapes: list[dict[str, Any]] = field(default_factory=list)

    @property
    def cases(self) -> int:
        return sum(self.counts.values())

    @property
    def escaped(self) -> int:
        return sum(self.counts[o] for o in ESCAPES)


def _write_case(folder: Path, filename: str, data: bytes) -> Path:
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    path = folder / filename
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def shrink(data: bytes, holds: Callable[[bytes], bool], *, budget: int = 200) -> bytes:
    """Smallest input found (truncation, then chunk removal) for which ``holds`` stays true."""
    tries = 0
    low, high = 0, len(data)
    while low < high and tries < budget // 4:  # shortest prefix that still holds (binary search)
        middle = (low + high) // 2
        tries += 1
        if holds(data[:middle]):
            high = middle
        else:
            low = middle + 1
    if high < len(data) and holds(data[:high]):
        data = data[:high]
    chunk = max(len(data) // 2, 1)
    while chunk >= 1 and tries < budget:
        at = 0
        while at < len(data) and tries < budget:
            candidate = data[:at] + data[at + chunk:]
            tries += 1
            if candidate != data and holds(candidate):
                data = candidate
            else:
                at += chunk
        chunk //= 2
    return data


def _save_escape(results: Path, target: Target, module: str, index: int, data: bytes,
                 answer: dict[str, Any]) -> Path:
    folder = results / target.name
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{answer['outcome']}-{index:06d}"
    case = folder / f"{stem}-{target.filename}"
    case.write_bytes(data)
    command = (f"cd {shlex.quote(str(REPO))} && {shlex.quote(sys.executable)} -m tests.fuzz.harness reproduce "
               f"--module {module} --target {target.name} {shlex.quote(str(case))}")
    (folder / f"{stem}.json").write_text(json.dumps({**answer, "index": index, "bytes": len(data),
                                                     "reproduce": command}, indent=2) + "\n")
    return case


def fuzz(
    targets: Sequence[tuple[str, Target]],
    *,
    cases: int,
    seed: int = 0,
    time_limit: float = DEFAULT_TIME_LIMIT,
    memory: int = DEFAULT_MEMORY,
    results: Path | None = None,
    cli_cases: int = 0,
    shrink_budget: int = 120,
    progress: Callable[[TargetReport], None] | None = None,
) -> list[TargetReport]:
    """Run ``cases`` mutated cases per target (``(module, target)`` pairs) and classify each.

    Escapes are shrunk and saved under ``results`` when given; ``cli_cases`` cases per target
    (the first ones) are also run through the target's command line.
    """
    reports: list[TargetReport] = []
    child = Child(sorted({module for module, _ in targets}), memory)
    scratch = Path(tempfile.mkdtemp(prefix="lidarfuzz-fuzz-"))
    try:
        for module, target in targets:
            run = _TargetRun(child, module, target, scratch, seed, time_limit, memory, results, shrink_budget)
            report = run.api(cases)
            if target.cli is not None:
                run.cli(report, cli_cases)
            reports.append(report)
            if progress is not None:
                progress(report)
    finally:
        child.close()
        shutil.rmtree(scratch, ignore_errors=True)
    return reports


class _TargetRun:
    """One target's cases through the child (and its command line)."""

    def __init__(self, child: Child, module: str, target: Target, scratch: Path, seed: int, time_limit: float,
                 memory: int, results: Path | None, shrink_budget: int) -> None:
        self.child, self.module, self.target = child, module, target
        self.seed, self.time_limit, self.memory = seed, time_limit, memory
        self.results, self.shrink_budget = results, shrink_budget
        self.folder = scratch / "case"
        self.seeds = [s for s in target.seeds(scratch / "seeds" / target.name) if s]
        if not self.seeds:
            raise RuntimeError(f"target {target.name} made no seed files")

    def _run(self, data: bytes) -> dict[str, Any]:
        return self.child.run(self.target.name, _write_case(self.folder, self.target.filename, data), self.time_limit)

    def api(self, cases: int) -> TargetReport:
        report = TargetReport(self.target.name)
        for index in range(cases):
            data = mutate(self.seeds, self.seed, self.target.name, index)
            started = time.monotonic()
            answer = self._run(data)
            report.seconds += time.monotonic() - started
            report.counts[answer["outcome"]] += 1
            if answer["outcome"] in ESCAPES:
                report.escapes.append(self._escape(index, data, answer))
        return report

    def _escape(self, index: int, data: bytes, answer: dict[str, Any]) -> dict[str, Any]:
        """Shrink an escape while its outcome (and exception type) holds, and save it."""
        if self.results is None:
            return {**answer, "index": index, "bytes": len(data)}

        def holds(candidate: bytes) -> bool:
            again = self._run(candidate)
            return bool(again["outcome"] == answer["outcome"] and again.get("type") == answer.get("type"))

        budget = self.shrink_budget if answer["outcome"] != "hang" else min(self.shrink_budget, 12)
        small = shrink(data, holds, budget=budget)
        saved = _save_escape(self.results, self.target, self.module, index, small, answer)
        return {**answer, "index": index, "bytes": len(small), "saved": str(saved)}

    def cli(self, report: TargetReport, cases: int) -> None:
        for index in range(cases):
            data = mutate(self.seeds, self.seed, self.target.name, index)
            path = _write_case(self.folder, self.target.filename, data)
            result = run_cli(self.target, path, max(self.time_limit, 60.0), self.memory)
            report.cli_cases += 1
            if result["outcome"] != "ok":
                report.cli_escapes.append({**result, "index": index})
                if self.results is not None:
                    _save_escape(self.results, self.target, self.module, index, data, {**result, "outcome": "cli"})


def table(reports: Sequence[TargetReport]) -> str:
    """The figures as a Markdown table, one row per target."""
    head = "| target | cases | " + " | ".join(OUTCOMES) + " | cases/s | CLI cases | CLI escapes |"
    rows = [head, "|" + "---|" * (len(OUTCOMES) + 5)]
    for r in reports:
        rate = r.cases / r.seconds if r.seconds else 0.0
        rows.append(f"| {r.name} | {r.cases:,} | " + " | ".join(f"{r.counts[o]:,}" for o in OUTCOMES)
                    + f" | {rate:,.0f} | {r.cli_cases:,} | {len(r.cli_escapes):,} |")
    return "\n".join(rows)


def _reproduce(args: argparse.Namespace) -> int:
    target = _load_targets([args.module])[args.target]
    path = Path(args.file).resolve()
    if args.here:
        target.read(path)  # an escape shows its traceback
        print(json.dumps({"outcome": "ok"}))
        return 0
    child = Child([args.module], args.memory)
    try:
        answer = child.run(target.name, path, args.time_limit)
    finally:
        child.close()
    print(json.dumps(answer))
    return 0 if answer["outcome"] in ("ok", "refused") else 1


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fuzz.harness", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("reproduce", help="run one saved case and print its outcome")
    rep.add_argument("--module", default="tests.fuzz.targets_points")
    rep.add_argument("--target", required=True)
    rep.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT)
    rep.add_argument("--memory", type=int, default=DEFAULT_MEMORY)
    rep.add_argument("--here", action="store_true", help="in this process, with the traceback (no limits)")
    rep.add_argument("file")
    args = parser.parse_args(argv)
    return _reproduce(args)


if __name__ == "__main__":
    sys.exit(main())
