"""A synthetic record of the example rig of docs/bringing-your-rig.md, in the SI text format a
real rig's logger should write: the MagLev-X200 (maglev-x200.toml) levitating under its LQI
(x200-lqi.toml) through a staircase of gap references with a small multisine on top (the loop
must move for a record to tell anything), logged as the rig's firmware would log it.

The plant that "runs" is the rig file's, except for its coil: 6 % more resistance than the rig
file states (warmer than when it was measured), which `maglev-cosim calibrate` should find.

    python examples/bring_your_rig/simulate_record.py runs/x200-record.txt [--seed 1] [--duration 12]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from maglev_cosim.loop.controllers import load_controller
from maglev_cosim.loop.simulate import simulate
from maglev_cosim.rigs import load_rig

HERE = Path(__file__).resolve().parent
R_FACTOR = 1.06   # the run's coil resistance over the rig file's


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="record file to write")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=12.0, help="[s]")
    a = ap.parse_args()
    rig = load_rig(HERE / "maglev-x200.toml")
    ctl = load_controller(HERE / "x200-lqi.toml", rig).controller
    rng = np.random.default_rng(a.seed)
    ts = rig.ts
    n = int(round(a.duration / ts))
    t = np.arange(n) * ts
    # the reference: a gap staircase between 6 and 10 mm (a step every 0.8-1.6 s) plus a multisine
    # of 0.15 mm (0.7, 1.9, 4.3 Hz), in the rig's convention [m]
    edges = np.cumsum(rng.uniform(0.8, 1.6, size=int(a.duration) + 2))
    levels = rng.uniform(0.006, 0.010, size=len(edges) + 1)
    gap_ref = levels[np.searchsorted(edges, t)] + 0.15e-3 * sum(
        np.sin(2 * np.pi * f * t + ph) for f, ph in ((0.7, 0.0), (1.9, 1.0), (4.3, 2.0))) / 3
    truth = rig.params.replace(R_c=R_FACTOR * rig.params.R_c)
    r = simulate(truth, rig.reading(gap_ref), controller=ctl, x_op=float(rig.to_x(gap_ref[0])))
    # what the firmware logs: the gap through 5 um of sensor noise and the 12-bit A/D, the current
    # with 3 mA of noise to 0.1 mA, the 10-bit PWM duty it applied
    q = 0.02 / 4095
    gap = np.round((rig.from_x(r["x"]) + rng.normal(0, 5e-6, n)) / q) * q
    cur = np.round((r["i"] + rng.normal(0, 3e-3, n)) / 1e-4) * 1e-4
    duty = np.round(r["u"] * 1023) / 1023          # the plant's input [MU] is the duty here
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", encoding="utf-8") as fh:
        fh.write(f"# MagLev-X200 synthetic record (examples/bring_your_rig/simulate_record.py, seed {a.seed})\n"
                 f"# rig: {rig.name}\n# controller: x200-lqi\n# Ts: {ts:g}s\n# Samples: {n}\n"
                 "# Columns: t y i u yd\n")
        for k in range(n):
            fh.write(f"{t[k]:.3f}\t{gap[k]:.7f}\t{cur[k]:.4f}\t{duty[k]:.4f}\t{gap_ref[k]:.7f}\n")
    print(f"wrote {out}: {n} samples at {ts * 1e3:g} ms, gap {1e3 * gap.min():.2f}-{1e3 * gap.max():.2f} mm, "
          f"current {cur.min():.3f}-{cur.max():.3f} A, duty {duty.min():.3f}-{duty.max():.3f}")


if __name__ == "__main__":
    main()
