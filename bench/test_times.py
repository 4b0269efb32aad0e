"""Test-suite time per file: each test file run alone (one process, no xdist), its wall and CPU seconds.

Usage: python bench/test_times.py [--json bench/results/test_times.json] [--markers "not slow"] [FILE ...]
       python bench/test_times.py --from-json RESULTS.json [...] --write-slow tests/slow_tests.txt [--slow-cpu 0.5]

Prints a table (files by CPU, slowest first, with their slowest tests) and writes JSON. CPU is user + system
time of the pytest process and the children it waited for (Xvfb, CLI subprocesses), so it stays meaningful
on a busy machine where wall time does not; the table in docs/development.md comes from this script.
Per-test times come from tests/conftest.py (``$HOLO_TEST_TIMES``): [wall, CPU, main thread blocked] seconds;
blocked (sleeping, polling with a timeout, waiting for a child: ``/proc/self/schedstat``) leaves a core idle in
a ``make test`` run unless another worker takes it. ``--write-slow`` lists the tests that took
more than ``--slow-cpu`` (0.5) seconds of CPU (set-up and tear-down included) in tests/slow_tests.txt, which conftest
turns into the ``slow`` marker (left out of ``make test-fast``); each file keeps its cheapest test fast, so the
fast run still covers every file, unless even that test takes over KEEP_LIMIT (5 s; the Ray cluster's file).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: make test's pytest-xdist workers (JOBS): each file runs with the torch threads one of them has
WORKERS = 2


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def time_file(path: Path, markers: str | None) -> dict:
    """Run one test file; its wall and CPU seconds, pytest's exit code and summary line, per-test times."""
    with tempfile.TemporaryDirectory() as tmp:
        per_test = Path(tmp) / "times.json"
        # torch's threads as a make test worker has them (tests/conftest.py: the cores shared by JOBS=2 workers)
        threads = str(max(1, (os.cpu_count() or 1) // WORKERS))
        env = {"OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads, **os.environ,
               "HOLO_TEST_TIMES": str(per_test)}
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist", str(path)]
        if markers:
            cmd += ["-m", markers]
        c0, w0 = _children_cpu(), time.perf_counter()
        run = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - w0, _children_cpu() - c0
        tests = json.loads(per_test.read_text()) if per_test.is_file() else {}
    lines = [ln for ln in run.stdout.strip().splitlines() if ln.strip()]
    return {"file": str(path.relative_to(ROOT)), "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "torch_threads": env["OMP_NUM_THREADS"], "load_average": [round(x, 1) for x in os.getloadavg()],
            "exit_code": run.returncode, "summary": lines[-1] if lines else "",
            "blocked_s": round(sum(v[2] for v in tests.values() if len(v) > 2), 2),
            "tests": {k: [round(x, 3) for x in v] for k, v in tests.items()}}


def _write_json(path: Path, markers: str | None, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"markers": markers, "cpus": os.cpu_count(), "python": platform.python_version(),
                                "load_average_end": os.getloadavg(),
                                "total_wall_s": round(sum(r["wall_s"] for r in rows), 1),
                                "total_cpu_s": round(sum(r["cpu_s"] for r in rows), 1), "files": rows}, indent=1))
    tmp.replace(path)


#: a file's cheapest test stays in the fast run unless it takes more CPU seconds than this (a Ray cluster)
KEEP_LIMIT = 5.0


def slow_tests(rows: list[dict], cpu_limit: float) -> list[str]:
    """Node ids over ``cpu_limit`` CPU seconds, except each file's cheapest test when it is under KEEP_LIMIT
    (so every file but those whose every test is that costly stays in the fast run)."""
    out = []
    for r in rows:
        tests = sorted(r["tests"].items(), key=lambda kv: kv[1][1])
        keep = 1 if tests and tests[0][1][1] <= KEEP_LIMIT else 0
        out += [k for k, v in tests[keep:] if v[1] > cpu_limit]
    return sorted(out)


def write_slow_list(path: Path, rows: list[dict], cpu_limit: float) -> list[str]:
    """Write the slow list, each line ``node id  # CPU seconds`` (conftest orders the files by them).

    Merges rather than overwrites: a line already in ``path`` whose test was not measured here (a file not
    run, or a test added since), or whose comment says ``by hand``, is kept as it was; other measured tests are
    listed by this run alone."""
    names = slow_tests(rows, cpu_limit)
    cpu = {k: v[1] for r in rows for k, v in r["tests"].items()}
    kept: dict[str, str] = {}
    if path.is_file():
        for ln in path.read_text().splitlines():
            node = ln.split("#", 1)[0].strip()
            if node and (node not in cpu or "by hand" in ln.split("#", 1)[-1]):
                kept.setdefault(node, ln.strip())
    head = (f"# tests over {cpu_limit} s of CPU when their file runs alone (bench/test_times.py --write-slow), "
            "with those CPU seconds; conftest marks them slow and runs the costliest files first\n")
    lines = [f"{n}  # {cpu[n]:.1f}" for n in names if n not in kept] + list(kept.values())
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(head + "".join(f"{ln}\n" for ln in sorted(lines)))
    tmp.replace(path)
    return [n for n in names if n not in kept] + list(kept)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, help="test files (default: every tests/test_*.py)")
    ap.add_argument("--markers", default=None, help='pytest -m expression, e.g. "not slow" (make test-fast)')
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--top", type=int, default=3, help="slowest tests listed per file")
    ap.add_argument("--from-json", type=Path, nargs="*", default=None, help="report earlier results, run nothing")
    ap.add_argument("--write-slow", type=Path, default=None, help="write the slow-test list (tests/slow_tests.txt)")
    ap.add_argument("--slow-cpu", type=float, default=0.5, help="CPU seconds over which a test is slow")
    ap.add_argument("--markdown", action="store_true", help="print the per-file table as markdown (docs/development.md)")
    args = ap.parse_args()
    rows = []
    if args.from_json:  # a file measured in several results: the last one given wins
        by_file: dict[str, dict] = {}
        for p in args.from_json:
            for r in json.loads(p.read_text())["files"]:
                by_file[r["file"]] = r
        rows = list(by_file.values())
    else:
        files = [p.resolve() for p in args.files] or sorted((ROOT / "tests").glob("test_*.py"))
        for path in files:
            r = time_file(path, args.markers)
            rows.append(r)
            print(f"{r['file']:<42} {r['wall_s']:>7.1f} s wall {r['cpu_s']:>7.1f} s CPU  {r['summary']}", flush=True)
            if args.json:  # after every file, so an interrupted run keeps what it measured
                _write_json(args.json, args.markers, rows)
    rows.sort(key=lambda r: -r["cpu_s"])
    print(f"\n{'file':<42} {'wall s':>7} {'CPU s':>7}  slowest tests (CPU s)")
    for r in rows:
        slow = sorted(r["tests"].items(), key=lambda kv: -kv[1][1])[: args.top]
        names = ", ".join(f"{k.split('::', 1)[1][:40]} {v[1]:.1f}" for k, v in slow)
        print(f"{r['file']:<42} {r['wall_s']:>7.1f} {r['cpu_s']:>7.1f}  {names}")
    total_wall, total_cpu = sum(r["wall_s"] for r in rows), sum(r["cpu_s"] for r in rows)
    print(f"{'total':<42} {total_wall:>7.1f} {total_cpu:>7.1f}  ({len(rows)} files, load average "
          f"{os.getloadavg()[0]:.1f} at the end)")
    if args.markdown:
        listed = ROOT / "tests" / "slow_tests.txt"
        slow = {ln.split("#", 1)[0].strip() for ln in listed.read_text().splitlines()} if listed.is_file() else set()
        print("\n| file | tests | CPU s | slow | CPU s of the others | slowest test (CPU s) |\n|---|---:|---:|---:|---:|---|")
        for r in rows:
            top = max(r["tests"].items(), key=lambda kv: kv[1][1], default=("::-", [0, 0]))
            n_slow = sum(k in slow for k in r["tests"])
            fast = sum(v[1] for k, v in r["tests"].items() if k not in slow)
            old = "" if "torch_threads" in r else " *"  # measured before torch had a worker's threads
            print(f"| `{Path(r['file']).name}`{old} | {len(r['tests'])} | {r['cpu_s']:.1f} | {n_slow} | {fast:.1f} | "
                  f"`{top[0].split('::', 1)[1][:50]}` {top[1][1]:.1f} |")
        print(f"| total | {sum(len(r['tests']) for r in rows)} | {sum(r['cpu_s'] for r in rows):.1f} | "
              f"{sum(k in slow for r in rows for k in r['tests'])} | "
              f"{sum(v[1] for r in rows for k, v in r['tests'].items() if k not in slow):.1f} | |")
    if args.write_slow:
        names = write_slow_list(args.write_slow, rows, args.slow_cpu)
        fast = sum(v[1] for r in rows for k, v in r["tests"].items() if k not in set(names))
        print(f"wrote {args.write_slow}: {len(names)} slow tests; the others took {fast:.1f} s of CPU")
    if args.json:  # with --from-json: the merged results
        _write_json(args.json, args.markers, rows)
    return 0 if all(r["exit_code"] in (0, 5) for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
