"""Benchmark: the real-rig model against the black box on records it was not calibrated on.

Calibrates the Inteco MLS2EM model on three shared records, validates on the other six (the
README's split), and writes the section "Real rig: calibration and validation (Inteco MLS2EM)"
of docs/benchmarks.md: the command, the machine and date, the wall time, the median skill of
the model, the black-box baseline and "constant velocity" per horizon and role, the per-record
table, the calibrated parameters and disturbance model, and the drift findings. Figures in the
doc are written only by this script.

    .venv/bin/python scripts/bench_rig.py [--data ../shared/data/real] [--out out/bench-rig] [--no-write]
                                          [--second-force-lag joint|after] [--across-profiles]

``--second-force-lag`` measures the calibration with the second force lag (effect ``eddy_lag``) fitted
(real_rig.SECOND_FORCE_LAG_FIT; off by default); the section it would write then names the option in
its command.

``--across-profiles`` measures instead whether the model carries over to a reference profile it was
not calibrated on (the judged records use others: up-down steps, slow and fast sines): calibrated on
every shared record of one profile, validated on every record of the other, both ways. It writes
the section "Real rig: across reference profiles (Inteco MLS2EM)".
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import benchdoc
from maglev_cosim.diagnosis import diagnose, real_rig
from maglev_cosim.diagnosis.rig_result import RigComparison

ROOT = benchdoc.ROOT
CALIBRATION = ("multisteps_stairs/LQR_tracking", "multisteps_stairs/PID_anti_windup", "step/MPC")
VALIDATION = ("multisteps_stairs/LQI", "multisteps_stairs/MPC", "multisteps_stairs/PID_gain_scheduling",
              "step/LQI", "step/PID_anti_windup", "step/PID_gain_scheduling")
SECTION = "## Real rig: calibration and validation (Inteco MLS2EM)"
PROFILES = {"step": ("LQI", "MPC", "PID_anti_windup", "PID_gain_scheduling"),
            "multisteps_stairs": ("LQI", "LQR_tracking", "MPC", "PID_anti_windup", "PID_gain_scheduling")}
ACROSS_TITLE = "Real rig: across reference profiles (Inteco MLS2EM)"


def _data_dir(arg: str | None) -> Path:
    for p in ([Path(arg)] if arg else []) + [Path(os.environ.get("MAGLEV_REAL_DATA", "/nonexistent")),
                                             ROOT.parent / "shared" / "data" / "real", Path("/work/shared/data/real")]:
        if (p / "inteco-mls2em" / "results").is_dir():
            return p
    sys.exit("bench_rig: the shared real records were not found (--data, $MAGLEV_REAL_DATA or ../shared/data/real)")


def _skill_cell(p: dict, who: str) -> str:
    v = p["skill"].get(who)
    return "–" if v is None else f"{v:+.2f}"


def section(res: dict, command: str, wall_s: float) -> str:
    comp = res["comparison"]
    lines = [SECTION, "",
             f"{benchdoc.stamp(wall_s)} The command it runs is equivalent to:", "", "```", command, "```", "",
             f"Verdict: **{res['verdict']}**.", "",
             "Median skill against 'stays put' of the gap predicted ahead (worst segment in brackets): the model "
             "in closed loop with the controller identified from the record (physics with its effects and its "
             "calibrated disturbance model; the controller, a linear map from the gap, the reference, the current "
             "and its own past to the PWM duty, fitted on one half of the record's 1 s blocks and used on the other, "
             "reads the controller's reaction after the start: diagnosis/reaction.py, docs/diagnosis.md 'Model "
             "against black box'), the same model driven by the measured PWM duty alone, "
             "the black-box baseline (one ridge regression per horizon on the last 30 ms of gap differences and "
             "the measured current and its square up to the predicted instant, fitted by the tool on the three "
             "calibration records), the same black box with the current only up to the prediction's start, "
"and 'constant velocity'.", "", *real_rig.comparison_table(RigComparison.from_json(comp))]
    lines += ["", "Per segment: the current from the PWM duty (fit %; in brackets the most a model can reach with the "
              "measured current's own noise, `metrics.fit_ceiling`), and the skill of model (closed loop, identified "
              "controller) / black box at each horizon.", "", "| segment | role | current from PWM | 5 ms | 20 ms | 50 ms |", "|---|---|---|---|---|---|"]
    rows = [(s["label"], "calibration", s["after"]) for e in res["records"] for s in e["segments"]]
    rows += [(v["label"], "validation", v["after"]) for v in res["validation"]]
    for label, role, f in rows:
        cur = f.get("current") or {}
        cells = [f"{_skill_cell(f['position'][h], 'model')} / {_skill_cell(f['position'][h], 'black_box')}"
                 for h in ("5 ms", "20 ms", "50 ms")]
        lines.append(f"| {label} | {role} | {cur.get('from_actuator', float('nan')):.1f} "
                     f"({cur.get('noise_ceiling', float('nan')):.1f}) | " + " | ".join(cells) + " |")
    cal = res.get("calibration") or {}
    nz = res.get("disturbance_model", {})
    lines += ["", "Calibrated parameters: " + ", ".join(f"`{k}` = {v:.5g}" for k, v in res["parameters"].items()) + "."]
    if nz:
        lines.append(f"Disturbance model: random force {1e3 * nz['q_force']:.3g} mN RMS, corner {nz['f_force']:.3g} Hz; "
                     f"sensor noise {nz['r_sensor']:.3g} MU; current noise {1e3 * nz['r_current']:.3g} mA.")
    if cal:
        lines.append(f"Calibration: cost {cal['cost_before']:.4g} → {cal['cost_after']:.4g} in {cal['evaluations']} "
                     "evaluations.")
    ef = res.get("effects") or {}
    lines.append(f"Effects selected: {', '.join(ef.get('selected', [])) or 'none'}.")
    co = res.get("correction")
    if co:
        s = co["summary"]
        lines.append(f"Located correction at the mechanics ({co['basis']['n_x']} gap terms x static, viscous, friction; "
                     f"ridge {co['ridge']:g}): held-out cost change {-100 * co['held_out_gain']:+.1f} %, "
                     f"{'used' if co['selected'] else 'not used'}; by shape alone: "
                     + ", ".join(f"{k} {-100 * v:+.1f} %" for k, v in co["held_out_gain_by_shape"].items())
                     + f"; averaged over the gaps: static {s['static_pct_weight']:+.2f} ± {s['static_sigma_pct_weight']:.2f} % "
                     f"of the weight, viscous {s['viscous_N_s_per_m']:+.3g} ± {s['viscous_sigma']:.2g} N·s/m, friction "
                     f"{1e3 * s['friction_N']:+.3g} ± {1e3 * s['friction_sigma']:.2g} mN ({co['evaluations']} evaluations).")
    lines += ["", "Reasons the tool gives:", ""] + [f"- {r}" for r in res["reasons"]] + [""]
    return "\n".join(lines)


def _calibrate_command(cal: list[str], val: list[str], out: str) -> str:
    """The ``maglev-cosim calibrate`` command line the run is equivalent to, for records named
    ``profile/controller`` under ``$I``."""
    return (".venv/bin/maglev-cosim calibrate " + " ".join(f'"$I/{n} - KF.mat"' for n in cal)
            + "".join(f' --validate "$I/{n} - KF.mat"' for n in val) + f" --rig inteco-mls2em --out {out}")


def across_profiles(res_dir: Path, out: Path) -> tuple[str, float]:
    """The model calibrated on every record of one profile and validated on every record of the
    other, both ways: the body of the section :data:`ACROSS_TITLE` and the wall time [s]."""
    rows, commands = [], []
    t0 = time.perf_counter()
    for fit_on, judged in (("step", "multisteps_stairs"), ("multisteps_stairs", "step")):
        cal = [res_dir / fit_on / f"{c} - KF.mat" for c in PROFILES[fit_on]]
        val = [res_dir / judged / f"{c} - KF.mat" for c in PROFILES[judged]]
        commands.append(_calibrate_command([f"{fit_on}/{c}" for c in PROFILES[fit_on]],
                                           [f"{judged}/{c}" for c in PROFILES[judged]], f"out/{fit_on}-to-{judged}"))
        res = diagnose(cal, rig="inteco-mls2em", validate=val, out=out / f"{fit_on}-to-{judged}",
                       progress=lambda m: print(f"[{time.perf_counter() - t0:6.1f} s] {m}", flush=True)).to_json()
        comp = RigComparison.from_json(res["comparison"]).get("validation")
        for h, v in comp.horizons.items():
            rows.append([f"{fit_on} ({len(cal)}) → {judged} ({comp.segments})", h, f"{v.model:+.2f} ({v.model_worst:+.2f})",
                         f"{v.black_box:+.2f} ({v.black_box_worst:+.2f})",
                         "yes" if v.model > v.black_box else "**no**"])
        fits = [v["after"]["current"]["from_actuator"] for v in res["validation"] if v["after"].get("current")]
        rows.append(["", "", f"verdict: {res['verdict']}", "selected: " + (", ".join(res["selected"]) or "none"),
                     f"current from the PWM duty: median {statistics.median(fits):.1f} %, worst {min(fits):.1f} %"
                     if fits else "no measured current"])
    body = ("The model calibrated on every shared record of one reference profile and judged on every record of "
            "the other, both ways (the judged records use profiles the shared folder lacks; the two step/PID "
            "records, whose gap is the Kalman filter's estimate, are judged but not calibrated on: "
            "`real_rig.information`). Median skill "
            "against 'stays put' over the validation segments (worst in brackets) of the model in closed loop "
            "with the identified controller and of the black-box baseline fitted on the same calibration "
            "records. The commands it runs are equivalent to:\n\n```\nI=../shared/data/real/inteco-mls2em/results\n"
            + "\n".join(commands) + "\n```\n\n"
            + benchdoc.table(["calibrated on → validated on (segments)", "horizon", "model", "black box",
                              "model ahead at this horizon"], rows))
    return body, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="the shared real records (default: $MAGLEV_REAL_DATA or ../shared/data/real)")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench-rig"))
    ap.add_argument("--no-write", action="store_true", help="print the section, leave docs/benchmarks.md alone")
    ap.add_argument("--second-force-lag", choices=("joint", "after"),
                    help="fit the second force lag (eddy_lag) too: with the rest or after it (default: "
                         "real_rig.SECOND_FORCE_LAG_FIT)")
    ap.add_argument("--across-profiles", action="store_true",
                    help="calibrate on every record of one profile, validate on the other's, both ways")
    a = ap.parse_args(argv)
    if a.across_profiles:
        body, wall = across_profiles(_data_dir(a.data) / "inteco-mls2em" / "results", Path(a.out))
        benchdoc.publish(benchdoc.section(ACROSS_TITLE, body, wall), write=not a.no_write)
        return 0
    if a.second_force_lag:
        real_rig.SECOND_FORCE_LAG_FIT = a.second_force_lag
    res_dir = _data_dir(a.data) / "inteco-mls2em" / "results"
    cal = [res_dir / f"{n} - KF.mat" for n in CALIBRATION]
    val = [res_dir / f"{n} - KF.mat" for n in VALIDATION]
    command = ("I=../shared/data/real/inteco-mls2em/results\n"
               + _calibrate_command(list(CALIBRATION), list(VALIDATION), "out/inteco"))
    if a.second_force_lag:
        command += f"  # with real_rig.SECOND_FORCE_LAG_FIT = {a.second_force_lag!r} (--second-force-lag)"
    t0 = time.perf_counter()
    res = diagnose(cal, rig="inteco-mls2em", validate=val, out=a.out,
                   progress=lambda m: print(f"[{time.perf_counter() - t0:6.1f} s] {m}", flush=True)).to_json()
    wall = time.perf_counter() - t0
    benchdoc.publish(section(res, command, wall), write=not a.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
