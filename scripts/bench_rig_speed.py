"""Benchmark: how long the real-rig commands take (issue 21, item 4), as a user runs them.

Times, through the command line (``maglev-cosim``, a fresh process each: imports included):

1. ``diagnose`` of each shared Inteco MLS2EM record alone (15 s records; target: at most 15 s
   each), and of the levitador session (``--controller levitador-cascade``);
2. ``calibrate`` on the README's three calibration records with 15 validation records (target:
   at most 90 s). The shared folder holds six validation records: the fifteen are those six, then
   the six again, then the first three, each copied under its own name (the same cost per record
   as fifteen different ones of the same length).

Every ``diagnose`` runs ``--repeat`` times (passes over all the records, one after the other), and
every run is shown: on a machine whose speed drifts by a third within minutes, the lowest of a
record's runs is the best estimate of the code's own time, and the spread says how far one run is to
be trusted.

Writes the section "Real rig: speed (issue 21, item 4)" of docs/benchmarks.md; figures in the doc
are written only by this script.

    .venv/bin/python scripts/bench_rig_speed.py [--repeat 2] [--data ../shared/data/real] [--no-write]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import benchdoc
from bench_rig import CALIBRATION, VALIDATION, _data_dir

ROOT = benchdoc.ROOT
CLI = ROOT / ".venv" / "bin" / "maglev-cosim"
TITLE = "Real rig: speed (issue 21, item 4)"
#: Targets [s]: one 15 s record diagnosed, and 3 + 15 records calibrated and validated.
TARGETS_S = (15.0, 90.0)
N_VALIDATION = 15


def _timed(args: list[str]) -> tuple[float, str]:
    """Wall time [s] of one ``maglev-cosim`` run, and its verdict line (the run must succeed)."""
    t0 = time.perf_counter()
    r = subprocess.run([str(CLI), *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"bench_rig_speed: maglev-cosim {' '.join(args)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    verdict = next((ln.split(":", 1)[1].strip() for ln in r.stdout.splitlines() if ln.startswith("verdict:")), "?")
    return wall, verdict


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="the shared real records (default: $MAGLEV_REAL_DATA or ../shared/data/real)")
    ap.add_argument("--no-write", action="store_true", help="print the section, leave docs/benchmarks.md alone")
    ap.add_argument("--repeat", type=int, default=2,
                    help="runs of each diagnose, in passes over all records (default 2)")
    a = ap.parse_args(argv)
    repeat = max(1, a.repeat)
    data = _data_dir(a.data)
    res_dir = data / "inteco-mls2em" / "results"
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        runs: dict[tuple[str, str], list[float]] = {}
        verdicts: dict[tuple[str, str], list[str]] = {}
        jobs = [((f"`{name} - KF.mat`", "inteco-mls2em"),
                 ["diagnose", str(res_dir / f"{name} - KF.mat"), "--rig", "inteco-mls2em", "--out", str(tmp / "one")])
                for name in (*CALIBRATION, *VALIDATION)]
        lev = data / "levitador-benchmark" / "data" / "sesiones_kan_pinn" / "dataset_escalon_20251217_205858.txt"
        if lev.is_file():
            jobs.append(((f"`{lev.name}`", "levitador"), ["diagnose", str(lev), "--rig", "levitador", "--controller",
                                                           "levitador-cascade", "--out", str(tmp / "lev")]))
        for k in range(repeat):
            for key, args in jobs:
                wall, verdict = _timed(args)
                runs.setdefault(key, []).append(wall)
                if verdict not in verdicts.setdefault(key, [verdict]):
                    verdicts[key].append(verdict)      # shown side by side: a verdict should not change
                    print(f"bench_rig_speed: {key[0]} said {verdicts[key][0]!r}, then {verdict!r}", flush=True)
                print(f"pass {k + 1}/{repeat}", key[0], f"{wall:.1f} s", verdict, flush=True)
        rows = [[name, rig, ", ".join(f"{w:.1f}" for w in runs[(name, rig)]), f"{min(runs[(name, rig)]):.1f}",
                 " / ".join(verdicts[(name, rig)])] for name, rig in runs]
        copies = tmp / "validation"
        copies.mkdir()
        val = []
        for k in range(N_VALIDATION):
            src = res_dir / f"{VALIDATION[k % len(VALIDATION)]} - KF.mat"
            dst = copies / f"{VALIDATION[k % len(VALIDATION)].replace('/', '_')} copy {k // len(VALIDATION) + 1}.mat"
            shutil.copyfile(src, dst)
            val.append(dst)
        args = ["calibrate", *(str(res_dir / f"{n} - KF.mat") for n in CALIBRATION)]
        for v in val:
            args += ["--validate", str(v)]
        wall_cal, verdict_cal = _timed([*args, "--rig", "inteco-mls2em", "--out", str(tmp / "cal")])
        print("calibrate 3 +", N_VALIDATION, wall_cal, verdict_cal, flush=True)
    inteco = [min(w) for (_, rig), w in runs.items() if rig == "inteco-mls2em"]
    every = [x for (_, rig), w in runs.items() if rig == "inteco-mls2em" for x in w]
    body = (f"Each run is a fresh `maglev-cosim` process (imports included), one after the other; {repeat} "
            f"pass(es) over the records, every run shown, the lowest of each record's runs beside them. Targets: "
            f"`diagnose` of one 15 s record at most {TARGETS_S[0]:g} s; `calibrate` on 3 records with "
            f"{N_VALIDATION} validation records at most {TARGETS_S[1]:g} s.\n\n"
            + benchdoc.table(["record", "rig", "diagnose wall [s], each run", "lowest [s]", "verdict"], rows)
            + f"\n\nThe Inteco records alone, by their lowest run: median {sorted(inteco)[len(inteco) // 2]:.1f} s, "
              f"longest {max(inteco):.1f} s; {sum(x <= TARGETS_S[0] for x in inteco)} of {len(inteco)} at most "
              f"{TARGETS_S[0]:g} s (target). Over every run: {sum(x <= TARGETS_S[0] for x in every)} of {len(every)} "
              f"at most {TARGETS_S[0]:g} s, the longest {max(every):.1f} s.\n\n"
            + f"`calibrate` on the README's three calibration records ({', '.join(CALIBRATION)}) with "
              f"{N_VALIDATION} validation records (the six shared ones, then the six again, then the first "
              f"three, each copied under its own name): **{wall_cal:.1f} s** wall (target {TARGETS_S[1]:g} s); "
              f"verdict {verdict_cal}.")
    benchdoc.publish(benchdoc.section(TITLE, body, time.perf_counter() - t_start), write=not a.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
