"""Runs the stateful FMI fuzz test (docs/fuzz.md) of both models behind the glue, the plant FMU and
the PID FMU, in the sanitizer build, and writes the figures into their section of docs/benchmarks.md.

    .venv/bin/python scripts/bench_fuzz.py [--seeds 1:12001] [--random 200] [--build build-asan] [--no-write]

The sanitizer build is the one ``scripts/test.sh`` makes (``cmake -S . -B build-asan
-DMAGLEV_SANITIZE=ON``). CI runs fewer seeds (CMakeLists.txt, ``fmu_fuzz``).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time

import benchdoc

SUMMARY = re.compile(r"(\d+) sequences, (\d+) calls in ([\d.]+) s = \d+ calls/s, (\d+) failures")
SLOWEST = re.compile(r"slowest call: (\S+) ([\d.]+) ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1:12001")
    ap.add_argument("--random", type=int, default=200, help="random seeds beside --seeds")
    ap.add_argument("--build", default=str(benchdoc.ROOT / "build-asan"))
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=1:abort_on_error=1",
               UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    rows, t_start, failed = [], time.perf_counter(), False
    for model, exe in (("plant", "fuzz_fmu"), ("PID", "fuzz_fmu_pid")):
        path = os.path.join(a.build, exe)
        if not os.access(path, os.X_OK):
            sys.exit(f"bench_fuzz: {path} is missing: build the sanitizer build first (scripts/test.sh does)")
        cmd = [path, "--seeds", a.seeds, "--random", str(a.random)]
        print("$", " ".join(cmd), flush=True)
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        out = proc.stdout + proc.stderr
        print(out[-3000:])
        m, s = SUMMARY.search(out), SLOWEST.search(out)
        if m is None:
            sys.exit(f"bench_fuzz: {exe} printed no summary (exit status {proc.returncode})")
        failed |= proc.returncode != 0 or int(m.group(4)) > 0
        rows.append([model, f"`{exe} --seeds {a.seeds} --random {a.random}`", f"{int(m.group(1)):,}",
                     f"{int(m.group(2)) / 1e6:.1f} million", f"{float(m.group(3)):.0f}", m.group(4),
                     f"{s.group(1)} {float(s.group(2)):.0f} ms" if s else "–"])
    body = ("ASan + UBSan build (`build-asan`), random FMI 2.0 call sequences on interleaved instances "
            "([fuzz.md](fuzz.md)); a failure is a sanitizer report, a crash, a hang, a NaN returned as OK, or a "
            "status the model's state table does not allow.\n\n"
            + benchdoc.table(["model", "command", "sequences", "calls", "time [s]", "failures", "slowest call"], rows))
    if not a.no_write:
        benchdoc.write_section("FMI fuzz test", body, time.perf_counter() - t_start)
        print(f"wrote the section of {benchdoc.DOC}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
