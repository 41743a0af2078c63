"""Benchmark of the record reader: how long a large record takes to be read, or refused.

Run: ``.venv/bin/python scripts/bench_records.py [--rows 1000000]``. Prints a table of wall times
and rows per second for a good record and for records whose only fault is in the last row, as a
user's logger might leave them, and writes them into their section of docs/benchmarks.md
(``--no-write``: print only). Target: 10^6 rows read or refused in at most 2 s.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import benchdoc
from maglev_cosim.records.record import RecordError, read_record

HEAD = "# ts: 0.001\n# controller: pid\n# kp: 2.0\n# ki: 2.97\n# kd: 0.01\n# u_min: 0.0\n# u_max: 1.0\nt,w,u,y\n"


def rows(n: int) -> list[str]:
    return [f"{k * 0.001:.4f},0.440000,{0.44 + 0.02 * math.sin(k / 30):.6f},{0.392 + 0.01 * math.sin(k / 50):.6f}"
            for k in range(n)]


CASES = {
    "good": lambda r: r,
    "bad last cell ('0.4x')": lambda r: r[:-1] + [r[-1][:-2] + "x"],
    "last row one field short": lambda r: r[:-1] + [r[-1].rsplit(",", 1)[0]],
    "last y out of range (1.5)": lambda r: r[:-1] + [r[-1].rsplit(",", 1)[0] + ",1.5"],
    "last time off the grid": lambda r: r[:-1] + [f"{(len(r) - 1) * 0.001 + 0.0004:.4f}" + r[-1][r[-1].index(","):]],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000, help="rows per record (default 10^6)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case; the best is shown (default 3)")
    ap.add_argument("--no-write", action="store_true", help="print the table, leave docs/benchmarks.md alone")
    a = ap.parse_args()
    t_start = time.perf_counter()
    base = rows(a.rows)
    table = []
    print(f"record reader, {a.rows} rows, best of {a.repeat}")
    print(f"{'case':30s} {'outcome':>40s} {'time [s]':>9s} {'rows/s':>11s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, change in CASES.items():
            p = Path(tmp) / "rec.csv"
            p.write_text(HEAD + "\n".join(change(list(base))) + "\n")
            best = math.inf
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                try:
                    rec = read_record(p)
                    outcome = f"read, {rec.n} samples"
                except RecordError as exc:
                    outcome = f"refused at {exc.line}:{exc.column}"
                best = min(best, time.perf_counter() - t0)
            print(f"{name:30s} {outcome:>40s} {best:9.3f} {a.rows / best:11.3g}")
            table.append([name, outcome, f"{best:.2f}", f"{a.rows / best:.3g}"])
    if not a.no_write:
        benchdoc.write_section("Record reader", f"A CE152 CSV record of {a.rows} rows, best of {a.repeat} runs; "
                               "target: read or refused in at most 2 s.\n\n"
                               + benchdoc.table(["record", "outcome", "time [s]", "rows per s"], table),
                               time.perf_counter() - t_start)
        print(f"wrote the section of {benchdoc.DOC}")


if __name__ == "__main__":
    main()
