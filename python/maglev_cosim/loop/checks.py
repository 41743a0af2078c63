"""Numerical checks of the FMU that both the tests and ``maglev-cosim bench`` report."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .fmu import FmuPlant

#: Communication steps [s] compared against the 1 ms run.
COMM_STEPS: tuple[float, ...] = (1e-5, 1e-4, 1e-3, 1e-2, 0.1)


def staircase_input(n_segments: int = 30, seed: int = 1) -> np.ndarray:
    """A piecewise-constant input [MU], one value per 0.1 s, for the Section 3 plant resting on
    the lower stop: values just above the lift-off input (0.605 MU at x = 0) make the ball rise
    slowly through the whole travel, values below let it fall back, so free flight, impacts,
    resting and lift-off all happen between the sampling instants."""
    rng = np.random.default_rng(seed)
    levels = np.array([0.0, 0.45, 0.606, 0.607, 0.608, 0.609, 0.61])
    return levels[rng.integers(0, len(levels), n_segments)]


def run_with_comm_step(start: Mapping[str, float], u_segments: Sequence[float], h: float,
                       segment: float = 0.1, sample: float = 0.01,
                       fmu: str | Path | None = None) -> np.ndarray:
    """Drives the FMU with ``u_segments`` (each held ``segment`` seconds) using communication step
    ``h``; returns ``[y, x, v, i]`` every ``max(h, sample)`` seconds (the end points of the steps)."""
    every = max(h, sample)
    per = int(round(segment / h))
    stride = int(round(every / h))
    if abs(per * h - segment) > 1e-12 or abs(stride * h - every) > 1e-12:
        raise ValueError(f"communication step {h} does not divide the segment {segment}")
    rows = []
    with FmuPlant(start, fmu=fmu) as plant:
        for s, u in enumerate(u_segments):
            plant.set_input(float(u))
            for k in range(per):
                # the importer's clock: integer multiples, as a careful master computes them
                plant.time = s * segment + k * h
                plant.step(h)
                if (k + 1) % stride == 0:
                    rows.append(plant.outputs())
    return np.array(rows)


def comm_step_study(start: Mapping[str, float], u_segments: Sequence[float],
                    steps: Sequence[float] = COMM_STEPS, fmu: str | Path | None = None) -> dict[float, dict[str, float]]:
    """Max |difference| of y [MU] and x [m] between runs with each communication step and the
    1 ms run, compared every 10 ms (every 0.1 s for the 0.1 s step)."""
    ref = run_with_comm_step(start, u_segments, 1e-3, fmu=fmu)
    res = {}
    for h in steps:
        r = run_with_comm_step(start, u_segments, h, fmu=fmu)
        stride = int(round(max(h, 0.01) / 0.01))
        ref_h = ref[stride - 1::stride]
        res[h] = {"max_dy": float(np.max(np.abs(r[:, 0] - ref_h[:, 0]))),
                  "max_dx": float(np.max(np.abs(r[:, 1] - ref_h[:, 1]))),
                  "samples": int(len(r))}
    return res
