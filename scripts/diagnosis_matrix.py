"""Runs the diagnosis on a matrix of synthetic records and prints a table (about 5 minutes).

    .venv/bin/python scripts/diagnosis_matrix.py [--seed N] [--json FILE]

Each row: the record's undeclared effect (from the rig emulator), what the diagnosis selected,
the estimates, and the RMS errors before and after. The figures in the issues' closing notes
come from this script.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from maglev_cosim.diagnosis import CATALOGUE, diagnose
from maglev_cosim.record import read_record
from maglev_cosim.synth import synth_record

CASES: list[tuple[str, dict]] = [
    ("none", {}),
    ("parameters only", {"params": {"k_c": 7.6e-6, "x_0": 0.0088, "k_FV": 0.02}}),
    ("amplifier_lag T_a=3ms", {"effects": {"amplifier_lag": {"T_a": 0.003}}}),
    ("force_lag T_F=2ms", {"effects": {"force_lag": {"T_F": 0.002}}}),
    ("delay T_d=2.5ms", {"effects": {"delay": {"T_d": 0.0025}}}),
    ("sensor k_x2=-3e4", {"effects": {"sensor_nonlinearity": {"k_x2": -30000.0}}}),
    ("saturation i_max=0.85", {"effects": {"current_saturation": {"i_max": 0.85}}}),
    ("pickup 8mV 37Hz", {"effects": {"periodic_disturbance": {"A_d": 0.008, "f_d": 37.0, "phi_d": 1.0}}}),
    ("delay 2ms + 50Hz", {"effects": {"delay": {"T_d": 0.002},
                                      "periodic_disturbance": {"A_d": 0.008, "f_d": 50.0, "phi_d": 0.0}}}),
    ("OUTSIDE force n=3", {"effects": {"force_exponent": {"n": 3.0}}}),
    ("OUTSIDE friction", {"effects": {"coulomb_friction": {"F_c": 2e-3}}}),
    ("square: delay 2ms", {"effects": {"delay": {"T_d": 0.002}}, "reference": "square"}),
    ("sine: pickup 60Hz", {"effects": {"periodic_disturbance": {"A_d": 0.004, "f_d": 60.0, "phi_d": -2.0}},
                           "reference": "sine"}),
    ("gains 2.5/4/0.008: delay", {"effects": {"delay": {"T_d": 0.0015}}, "kp": 2.5, "ki": 4.0, "kd": 0.008}),
    ("gains 2.5/4/0.008: none", {"kp": 2.5, "ki": 4.0, "kd": 0.008}),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    rows = []
    print(f"{'record':<26}{'selected':<38}{'estimates':<46}{'before y/u [MU]':<20}{'after y/u [MU]':<20}{'s':>5}")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, kw) in enumerate(CASES):
            path = synth_record(Path(tmp) / f"r{k}.csv", seed=a.seed, **kw)
            rec = read_record(path)
            t0 = time.perf_counter()
            d = diagnose(rec)
            dt = time.perf_counter() - t0
            est = {p: d.parameters[p] for e in d.selected for p in CATALOGUE[e].params}
            est_s = ", ".join(f"{p}={v:.4g}" for p, v in est.items() if p != "phi_d")
            print(f"{name:<26}{','.join(d.selected) or '-':<38}{est_s:<46}"
                  f"{d.before['rms_y']:.5f}/{d.before['rms_u']:.5f}   {d.after['rms_y']:.5f}/{d.after['rms_u']:.5f}"
                  f"   {dt:5.1f}", flush=True)
            rows.append({"record": name, "truth": kw, "selected": d.selected, "estimates": est,
                         "before": d.before, "after": d.after, "seconds": dt, "note": d.unexplained["note"]})
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
