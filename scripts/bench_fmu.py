"""Measures the FMU and the fast path and writes their sections of docs/benchmarks.md:

- the FMU against the pure-Python reference (a 0.05 MU closed-loop step, 2 s);
- the closed loop at 1 kHz through fmpy, the cffi fast path and the reference (``maglev-cosim bench``);
- communication-step independence of the FMU;
- the diagnosis time of a 12 s record with one and with two effects (issue 22's targets: 3 s and 5 s);
- the linearisation against the paper's Eq. 18/19.

    .venv/bin/python scripts/bench_fmu.py [--repeat 3] [--no-diagnose] [--no-write]

The diagnosis is timed ``--repeat`` times back to back and every run is shown (the machine may be
shared: the lowest is the best estimate of the code's own time).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import benchdoc
from maglev_cosim.loop.pid import PID
from maglev_cosim.loop.simulate import reference_signal, simulate
from maglev_cosim.plant.linear import EQ18_POLES, PAPER_OPERATING_POINT, linearize, operating_point
from maglev_cosim.plant.params import get_params
from maglev_cosim.report.bench import run_bench


def fmu_against_reference() -> tuple[str, float]:
    t0 = time.perf_counter()
    p = get_params("section3")
    w = reference_signal("step", 2.0, PID().ts, base=operating_point(p, 0.0032).y_MU, amplitude=0.05)
    a = simulate(p, w, controller=PID(), backend="fmu")
    b = simulate(p, w, controller=PID(), backend="reference")
    dy, du = (float(np.max(np.abs(a[k] - b[k]))) for k in ("y", "u"))
    body = (f"0.05 MU closed-loop step of 2 s at 1 kHz, Section 3 parameters, the paper's PID (Eq. 24/25): "
            f"max |Δy| = {dy:.2g} MU, max |Δu| = {du:.2g} MU between the FMU (through fmpy) and the pure-Python "
            "reference (solve_ivp). `tests/test_cosim.py` holds the bound.")
    return body, time.perf_counter() - t0


def linearisation() -> tuple[str, float]:
    t0 = time.perf_counter()
    x, _, i = PAPER_OPERATING_POINT
    poles = np.sort(np.real(np.asarray(linearize(get_params("eq18"), x, i=i).poles())))[::-1]
    paper = np.sort(np.asarray(EQ18_POLES))[::-1]
    rows = [[f"{q:.1f}", f"{r:.1f}", f"{100 * (q - r) / abs(r):+.2f} %"] for q, r in zip(poles, paper)]
    body = (f"`linearize(get_params('eq18'), {x}, i={i})` (`maglev-cosim linearize --params eq18 --current {i}`): "
            "the poles of the linear plant against Eq. 19's denominator.\n\n"
            + benchdoc.table(["pole [1/s]", "the paper's", "difference"], rows))
    return body, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="diagnosis runs per record, back to back (default 3)")
    ap.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis timing")
    ap.add_argument("--no-write", action="store_true", help="print the sections, leave docs/benchmarks.md alone")
    a = ap.parse_args(argv)
    sections = []
    body, wall = fmu_against_reference()
    sections.append(("FMU against the pure-Python reference", body, wall))
    body, wall = linearisation()
    sections.append(("Linearisation against the paper", body, wall))

    t0 = time.perf_counter()
    runs = [run_bench(diagnose=not a.no_diagnose and k < a.repeat) for k in range(max(a.repeat, 1))]
    wall = time.perf_counter() - t0
    cl = runs[0]["closed_loop"]
    rows = [["fmpy loop (the FMU, the Python PID)", f"{cl['fmpy_s'] * 1e3:.1f}", f"{cl['fmpy_us_per_step']:.2f}",
             f"{cl['fmpy_vs_fast']:.1f}×"],
            ["cffi fast path (the C replay)", f"{cl['fast_s'] * 1e3:.2f}", f"{cl['fast_us_per_step']:.3f}", "1×"],
            ["pure-Python reference (solve_ivp)", f"{cl['reference_s'] * 1e3:.0f}",
             f"{cl['reference_us_per_step']:.1f}", f"{cl['fast_vs_reference']:.0f}×"]]
    sections.append(("Closed loop at 1 kHz: fmpy, cffi fast path, reference",
                     f"{cl['steps']} steps (10 s), square reference, the paper's PID; best of several runs.\n\n"
                     + benchdoc.table(["path", "total [ms]", "per step [µs]", "against the fast path"], rows)
                     + "\n\nTargets: fmpy ≤ 10 µs per step, the fast path ≤ 20 ms for 10 s and ≥ 100× the reference.",
                     wall))
    cs = runs[0]["comm_step"]
    steps = list(next(iter(cs.values())).keys())
    rows = [[label] + [f"{r[h]['max_dy']:.1e}" for h in steps] for label, r in cs.items()]
    sections.append(("Communication-step independence",
                     "Max |y − y(1 ms run)| [MU], 3 s open loop through the stops, for each communication step [s].\n\n"
                     + benchdoc.table(["parameters"] + steps, rows), wall))
    if not a.no_diagnose:
        labels = list(runs[0]["diagnosis"])
        rows = [[label, ", ".join(f"{r['diagnosis'][label]['seconds']:.1f}" for r in runs),
                 ", ".join(f"{r['diagnosis'][label]['cpu_seconds']:.1f}" for r in runs),
                 ", ".join(runs[0]["diagnosis"][label]["selected"]) or "—",
                 str(runs[0]["diagnosis"][label]["candidates"])] for label in labels]
        sections.append(("Diagnosis time of a 12 s record",
                         f"The default catalogue, {len(runs)} run{'s' if len(runs) > 1 else ''} back to back (`maglev-cosim bench`). Targets "
                         "(issue 22): 3 s wall with one effect, 5 s with two.\n\n"
                         + benchdoc.table(["record", "wall [s]", "CPU [s]", "selected", "fits"], rows), wall))
    for title, body, w in sections:
        text = benchdoc.section(title, body, w)
        print(text)
        if not a.no_write:
            benchdoc.replace_section(text)
    if not a.no_write:
        print(f"wrote {len(sections)} sections of {benchdoc.DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
