"""What the two emulators (:mod:`maglev_cosim.records.emulator` and :mod:`maglev_cosim.records.emulator_ivp`) share
that is not physics: the position references a synthetic record follows, the check of a synthetic
record's settings, and the truth sidecar's figures of the coil current. Imports nothing of the package, so the independent emulator stays
apart from the model (``tests/test_emulator_ivp.py``)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

#: The rig noise and converter settings a synthetic record takes (:func:`maglev_cosim.records.synth.draw_disturbance`).
DISTURBANCE_KEYS = ("sigma_y", "sigma_F_rel", "tau_F_noise", "F_drift_rel", "tau_drift", "bits")


def emulated_effects(table: Mapping[str, tuple[str, ...]], settings: Iterable[str],
                     extra: Mapping[str, tuple[str, ...]] | None = None) -> dict[str, tuple[str, ...]]:
    """Effect name -> its parameters, for an emulator whose configuration has the fields ``settings``:
    each effect of the C variable table (``table``, :data:`maglev_cosim.plant.params.EFFECT_PARAMS`)
    with at least one of its parameters among them, with those of its parameters the emulator has
    (it writes each effect's physics in its own way, and may leave out a parameter the model needs
    only for its form, such as ``x_n``); then the emulator's own effects outside the catalogue, ``extra``."""
    names = set(settings)
    out = {e: tuple(p for p in ps if p in names) for e, ps in table.items()}
    return {**{e: ps for e, ps in out.items() if ps}, **dict(extra or {})}


def checked_settings(effects: dict[str, dict[str, float]], params: dict[str, float] | None,
                     disturbance: dict[str, float] | None, gains: tuple[float, float, float],
                     known_effects: dict[str, tuple[str, ...]], plant_params: tuple[str, ...],
                     ) -> tuple[dict[str, float], dict[str, float], tuple[float, float, float]]:
    """A synthetic record's settings, checked against what its emulator knows (``known_effects``,
    ``plant_params``, :data:`DISTURBANCE_KEYS`): the effects' parameter values merged, the
    disturbance settings without the PID gains (``bits`` as an int), and the gains ``(kp, ki, kd)``,
    which a disturbance draw may override. Raises ``ValueError`` naming what is unknown."""
    values: dict[str, float] = {}
    for name, pv in effects.items():
        if name not in known_effects:
            raise ValueError(f"effect {name!r} is not in this emulator: choose from {', '.join(known_effects)}")
        for k in pv:
            if k not in known_effects[name]:
                raise ValueError(f"effect {name} has no parameter {k!r}: its parameters are "
                                 f"{', '.join(known_effects[name])}")
        values.update({k: float(v) for k, v in pv.items()})
    for k in params or {}:
        if k not in plant_params:
            raise ValueError(f"unknown plant parameter {k!r}: choose from {', '.join(plant_params)}")
    dist = dict(disturbance or {})
    gains = tuple(float(dist.pop(k, v)) for k, v in zip(("kp", "ki", "kd"), gains))
    bad = sorted(set(dist) - set(DISTURBANCE_KEYS))
    if bad:
        raise ValueError(f"unknown disturbance setting(s) {', '.join(bad)}: choose from {', '.join(DISTURBANCE_KEYS)}")
    if "bits" in dist:
        dist["bits"] = int(dist["bits"])
    return values, dist, gains


def current_truth(i: np.ndarray, limited: np.ndarray) -> dict:
    """What a record's truth sidecar says of the coil current [A], for benchmarks that plant a
    current limit by the share of samples it acts in: the percentiles 0..100 of the current, and the
    share of the samples in which the amplifier is at its limit ``i_max``."""
    return {"current_percentiles": np.percentile(i, np.arange(101)).tolist(),
            "i_limited_share": float(np.mean(limited))}


#: The position references a synthetic record may follow (:func:`reference_positions`).
REFERENCE_KINDS = ("square", "sine", "steps", "chirp")


def reference_positions(kind: str, duration: float, ts: float, rng: np.random.Generator,
                        period: float | None = None) -> np.ndarray:
    """A position reference [m] sampled every ``ts`` over ``duration`` [s]: ``square`` (3.0 ↔ 3.5 mm,
    period 3 s as the paper's Sec. 5, or ``period`` [s]), ``sine`` (3.2 mm ± 0.6 mm, period 4 s or
    ``period``), ``steps`` (a random staircase across 2.0–4.5 mm, steps of 0.15–0.5 mm held 0.6–1.4 s,
    drawn from ``rng``: the most informative), ``chirp`` (3.2 mm ± 0.25 mm, 0.1 → 5 Hz). Each emulator
    turns it into readings with its own sensor."""
    if period is not None and not (period > 0 and kind in ("square", "sine")):
        raise ValueError(f"a period (here {period!r}) is given to a square or a sine reference, and it is > 0 s")
    if kind not in REFERENCE_KINDS:
        raise ValueError(f"unknown reference {kind!r}: choose square, sine, steps or chirp")
    n = int(round(duration / ts))
    t = np.arange(n) * ts
    if kind == "square":
        return np.where(np.floor(t / ((period or 3.0) / 2)).astype(int) % 2 == 0, 3.0e-3, 3.5e-3)
    if kind == "sine":
        return 3.2e-3 + 0.6e-3 * np.sin(2 * np.pi * t / (period or 4.0))
    if kind == "chirp":
        f0, f1 = 0.1, 5.0
        return 3.2e-3 + 0.25e-3 * np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * duration)))
    x = np.empty(n)
    level, k = 3.2e-3, 0
    while k < n:
        length = int(rng.uniform(0.6, 1.4) / ts)
        x[k:k + length] = level
        k += length
        delta = rng.uniform(0.15e-3, 0.5e-3) * rng.choice([-1.0, 1.0])
        if not 2.0e-3 <= level + delta <= 4.5e-3:
            delta = -delta
        level += delta
    return x
