"""Runs the diagnosis on synthetic records and prints tables: the fixed matrix, and the
acceptance benchmark over the disturbance family (false-positive rate and power).

    .venv/bin/python scripts/diagnosis_matrix.py [--seed N] [--json FILE]          # the matrix (~2 min)
    .venv/bin/python scripts/diagnosis_matrix.py --family 50 [--power 5] [--seed N]  # the benchmark
    ... --emulator ivp    # either, on records of the independent emulator (maglev_cosim.emulator_ivp)

The matrix: each row the record's undeclared effect (from the rig emulator), what the diagnosis
selected, the estimates, and the RMS errors before and after.

The benchmark (``--family N``): N records with no effect, each with its own draw from the
disturbance family (``maglev_cosim.synth.FAMILY``: white or coloured force noise with corners
5 to 50 Hz at 0.1 to 1 % of the weight, a drifting force offset, sensor noise 1e-4 to 1.5e-3 MU,
10- to 14-bit converters, stable PID gains other than the paper's); the false-positive rate is
the share of them where any effect is selected. Then (``--power M``) each catalogue effect at
the matrix's magnitude on M of those draws: the power is the share where the planted effect is
selected, and "after / null" divides the after-error by what the same rig and seed leave without
the effect, by the free run and by the 20 ms prediction (which a loop near instability, whose
free run cannot follow the noise-driven ringing, is judged by). The figures in the issues'
closing notes come from this script.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from maglev_cosim.diagnosis import CATALOGUE, diagnose
from maglev_cosim.diagnosis.effects import DEFAULT_EFFECTS
from maglev_cosim.record import read_record
from maglev_cosim.synth import draw_disturbance, synth_record

#: The record writer: the rig emulator's, or with ``--emulator ivp`` the independent emulator's
#: (``maglev_cosim.emulator_ivp.synth_record``, same arguments; docs/diagnosis.md, "The independent emulator").
SYNTH = synth_record

#: The catalogue cases of the power benchmark: today's magnitudes (the matrix's).
POWER_CASES: dict[str, dict] = {
    "amplifier_lag": {"amplifier_lag": {"T_a": 0.003}},
    "force_lag": {"force_lag": {"T_F": 0.002}},
    "delay": {"delay": {"T_d": 0.0025}},
    "sensor_nonlinearity": {"sensor_nonlinearity": {"k_x2": -30000.0}},
    "current_saturation": {"current_saturation": {"i_max": 0.85}},
    "periodic_disturbance": {"periodic_disturbance": {"A_d": 0.008, "f_d": 37.0, "phi_d": 1.0}},
}

CASES: list[tuple[str, dict]] = [
    ("none", {}),
    ("parameters only", {"params": {"k_c": 7.6e-6, "x_0": 0.0088, "k_FV": 0.02}}),
    ("amplifier_lag T_a=3ms", {"effects": {"amplifier_lag": {"T_a": 0.003}}}),
    ("force_lag T_F=2ms", {"effects": {"force_lag": {"T_F": 0.002}}}),
    ("delay T_d=2.5ms", {"effects": {"delay": {"T_d": 0.0025}}}),
    ("sensor lag T_y=2ms", {"effects": {"sensor_lag": {"T_y": 0.002}}}),
    ("sensor lag, all tried", {"effects": {"sensor_lag": {"T_y": 0.002}}}),
    ("force lag, all tried", {"effects": {"force_lag": {"T_F": 0.002}}}),
    ("sensor k_x2=-3e4", {"effects": {"sensor_nonlinearity": {"k_x2": -30000.0}}}),
    ("saturation i_max=0.85", {"effects": {"current_saturation": {"i_max": 0.85}}}),
    ("pickup 8mV 37Hz", {"effects": {"periodic_disturbance": {"A_d": 0.008, "f_d": 37.0, "phi_d": 1.0}}}),
    ("delay 2ms + 50Hz", {"effects": {"delay": {"T_d": 0.002},
                                      "periodic_disturbance": {"A_d": 0.008, "f_d": 50.0, "phi_d": 0.0}}}),
    ("force exponent n=3", {"effects": {"force_exponent": {"n_F": 3.0}}}),
    ("friction F_c=2mN", {"effects": {"coulomb_friction": {"F_c": 2e-3}}}),
    ("dead zone u_dz=0.5V, tried", {"effects": {"amplifier_dead_zone": {"u_dz": 0.5}}}),
    ("OUTSIDE slew 20A/s", {"effects": {"slew_rate": {"di_max": 20.0}}}),
    ("OUTSIDE ripple 20mV/0.5mm", {"effects": {"sensor_ripple": {"A_r": 0.02, "lambda_r": 5e-4}}}),
    ("square: delay 2ms", {"effects": {"delay": {"T_d": 0.002}}, "reference": "square"}),
    # a limit that bites for tens of ms after each step up: active in 2.6 % and 10 % of the samples
    ("square 0.6s: none", {"reference": "square", "period": 0.6}),
    ("square 0.6s: i_max=0.69", {"effects": {"current_saturation": {"i_max": 0.69}}, "reference": "square",
                                 "period": 0.6}),
    ("square 0.6s: i_max=0.66", {"effects": {"current_saturation": {"i_max": 0.66}}, "reference": "square",
                                 "period": 0.6}),
    ("sine: pickup 60Hz", {"effects": {"periodic_disturbance": {"A_d": 0.004, "f_d": 60.0, "phi_d": -2.0}},
                           "reference": "sine"}),
    ("gains 2.5/4/0.008: delay", {"effects": {"delay": {"T_d": 0.0015}}, "kp": 2.5, "ki": 4.0, "kd": 0.008}),
    ("gains 2.5/4/0.008: none", {"kp": 2.5, "ki": 4.0, "kd": 0.008}),
]

#: Rows that try other entries than the default (DEFAULT_EFFECTS): the opt-in ones.
TRIED: dict[str, list[str]] = {
    "friction F_c=2mN": [*DEFAULT_EFFECTS, "coulomb_friction"],
    "dead zone u_dz=0.5V, tried": [*DEFAULT_EFFECTS, "amplifier_dead_zone"],   # the D/A offset's twin
    "sensor lag T_y=2ms": [e for e in CATALOGUE if e != "force_lag"],    # its twin left out
    "sensor lag, all tried": list(CATALOGUE),
    "force lag, all tried": list(CATALOGUE),
}


def _describe(dist: dict) -> str:
    colour = "white" if dist["tau_F_noise"] == 0 else f"{1 / (2 * 3.14159265 * dist['tau_F_noise']):.0f}Hz"
    return (f"sy={dist['sigma_y']:.1e} F={100 * dist['sigma_F_rel']:.2f}%/{colour} "
            f"drift={100 * dist['F_drift_rel']:.2f}% {dist['bits']}b "
            f"pid={dist.get('kp', 2):.2f}/{dist.get('ki', 2.97):.2f}/{dist.get('kd', 0.01):.4f}")


#: The effects the benchmark's diagnoses try (None: the default catalogue; ``--also`` adds to it).
FAMILY_EFFECTS: list[str] | None = None


def family(n_null: int, n_power: int, seed0: int, tmp: Path) -> dict:
    """The acceptance benchmark: false positives on no-effect records, power on catalogue effects."""
    out: dict = {"null": [], "power": []}
    after_null: dict[int, dict[str, float]] = {}
    print(f"\nNo-effect records over the disturbance family ({n_null}):")
    print(f"{'seed':>6}  {'disturbance':<62}{'selected':<28}{'after y/u [MU]':<22}{'s':>5}")
    for k in range(n_null):
        seed = seed0 + k
        dist = draw_disturbance(seed)
        rec = read_record(SYNTH(tmp / f"n{k}.csv", seed=seed, disturbance=dist), plausibility="warn")
        t0 = time.perf_counter()
        d = diagnose(rec, effects=FAMILY_EFFECTS)
        dt = time.perf_counter() - t0
        after_null[seed] = {"free_run": d.after["rms_u"], "prediction": d.verdict.after.prediction_rms["u"]}
        print(f"{seed:>6}  {_describe(dist):<62}{','.join(d.selected) or '-':<28}"
              f"{d.after['rms_y']:.5f}/{d.after['rms_u']:.5f}   {dt:5.1f}  {d.verdict.verdict} "
              f"(share {100 * d.verdict.predictable_share['after']:.1f} %)", flush=True)
        out["null"].append({"seed": seed, "disturbance": dist, "selected": d.selected, "after": d.after,
                            "seconds": dt, "warnings": rec.warnings, "verdict": d.verdict.verdict,
                            "predictable_share": d.verdict.predictable_share["after"]})
    fp = sum(bool(r["selected"]) for r in out["null"])
    if n_power:
        print(f"\nCatalogue effects on the first {n_power} draws:")
        print(f"{'effect':<22}{'seed':>6}  {'selected':<40}{'after/null u: free run':>23}{'20 ms ahead':>12}{'s':>6}")
    for name, planted in POWER_CASES.items():
        for k in range(n_power):
            seed = seed0 + k
            dist = draw_disturbance(seed)
            rec = read_record(SYNTH(tmp / f"p{k}.csv", seed=seed, disturbance=dist, effects=planted),
                              plausibility="warn")
            t0 = time.perf_counter()
            d = diagnose(rec, effects=FAMILY_EFFECTS)
            dt = time.perf_counter() - t0
            null = after_null.get(seed)
            ratio = d.after["rms_u"] / null["free_run"] if null else float("nan")
            ratio_k = d.verdict.after.prediction_rms["u"] / null["prediction"] if null else float("nan")
            print(f"{name:<22}{seed:>6}  {','.join(d.selected) or '-':<40}{ratio:>23.2f}{ratio_k:>12.2f}{dt:>6.1f}  "
                  f"{d.verdict.verdict}", flush=True)
            out["power"].append({"effect": name, "seed": seed, "selected": d.selected, "after_over_null": ratio,
                                 "after_over_null_prediction": ratio_k, "seconds": dt, "verdict": d.verdict.verdict,
                                 "fit_mode": d.fit_mode})
    hits = sum(r["selected"][:1] == [r["effect"]] for r in out["power"])
    explained = sum(r["verdict"] == "explained" for r in out["power"])
    print("\n| benchmark | records | rate |\n|---|---|---|")
    print(f"| false positives (any effect selected on a no-effect record) | {n_null} | {100 * fp / max(n_null, 1):.1f} % |")
    wrong = sum(r["verdict"] != "no effect" for r in out["null"])
    print(f"| no-effect records whose verdict is not 'no effect' | {n_null} | {100 * wrong / max(n_null, 1):.1f} % |")
    if out["power"]:
        print(f"| power (the planted catalogue effect selected first) | {len(out['power'])} | "
              f"{100 * hits / len(out['power']):.1f} % |")
        print(f"| catalogue records with the verdict 'explained' | {len(out['power'])} | "
              f"{100 * explained / len(out['power']):.1f} % |")
    out["false_positive_rate"] = fp / max(n_null, 1)
    out["power_rate"] = hits / len(out["power"]) if out["power"] else None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=5, help="seed of the matrix; first seed of the benchmark")
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    ap.add_argument("--family", type=int, default=0, metavar="N",
                    help="run the acceptance benchmark on N no-effect records instead of the matrix")
    ap.add_argument("--power", type=int, default=5, metavar="M",
                    help="with --family: each catalogue effect on the first M draws (default 5)")
    ap.add_argument("--emulator", choices=["rig", "ivp"], default="rig",
                    help="the records' emulator: rig (default) or ivp, the independent one written from the paper "
                         "(the matrix then skips the rows with effects it does not have)")
    ap.add_argument("--setting", action="append", default=[], metavar="NAME=VALUE",
                    help="with --emulator ivp: one of its settings (pid_offset, f_y, v_c, method, rtol), repeatable")
    ap.add_argument("--also", action="append", default=[], metavar="EFFECT",
                    help="with --family: an opt-in catalogue effect tried beside the default ones, to measure "
                         "what putting it in the default catalogue would do (repeatable)")
    a = ap.parse_args()
    global SYNTH, FAMILY_EFFECTS
    if a.also:
        FAMILY_EFFECTS = [*DEFAULT_EFFECTS, *(e for e in a.also if e not in DEFAULT_EFFECTS)]
    supported = None
    if a.setting and a.emulator != "ivp":
        ap.error("--setting belongs to --emulator ivp")
    if a.emulator == "ivp":
        from functools import partial

        from maglev_cosim import emulator_ivp

        settings = {k.strip(): (v.strip() if k.strip() == "method" else float(v))
                    for k, v in (item.split("=", 1) for item in a.setting)}
        SYNTH, supported = partial(emulator_ivp.synth_record, settings=settings), set(emulator_ivp.EFFECTS)
    if a.family:
        with tempfile.TemporaryDirectory() as tmp:
            res = family(a.family, min(a.power, a.family), a.seed, Path(tmp))
        if a.json:
            Path(a.json).write_text(json.dumps(res, indent=2, default=float))
        return
    rows = []
    print(f"{'record':<26}{'selected':<38}{'estimates':<46}{'before y/u [MU]':<20}{'after y/u [MU]':<20}"
          f"{'20 ms ahead y/u':<20}{'after u/noise':>14}{'s':>6}  verdict")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, kw) in enumerate(CASES):
            if supported is not None and not set(kw.get("effects", {})) <= supported:
                print(f"{name:<26}(skipped: the {a.emulator} emulator has no {', '.join(set(kw['effects']) - supported)})")
                continue
            path = SYNTH(Path(tmp) / f"r{k}.csv", seed=a.seed, **kw)
            rec = read_record(path)
            t0 = time.perf_counter()
            d = diagnose(rec, effects=TRIED.get(name))
            dt = time.perf_counter() - t0
            est = {p: d.parameters[p] for e in d.selected for p in CATALOGUE[e].params}
            over = d.after["rms_u"] / d.noise["rms_u_from_sensor_noise"]
            k_rms = d.verdict.after.prediction_rms
            est_s = ", ".join(f"{p}={v:.4g}" for p, v in est.items() if p != "phi_d")
            print(f"{name:<26}{','.join(d.selected) or '-':<38}{est_s:<46}"
                  f"{d.before['rms_y']:.5f}/{d.before['rms_u']:.5f}   {d.after['rms_y']:.5f}/{d.after['rms_u']:.5f}"
                  f"   {k_rms['y']:.5f}/{k_rms['u']:.5f}   {over:11.2f}  {dt:5.1f}  {d.verdict.verdict}", flush=True)
            rows.append({"record": name, "truth": kw, "selected": d.selected, "estimates": est,
                         "before": d.before, "after": d.after, "after_prediction": k_rms,
                         "after_u_over_noise": over, "seconds": dt,
                         "verdict": d.verdict.verdict, "note": d.unexplained["note"]})
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
