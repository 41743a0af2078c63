"""Synthetic records from the rig emulator (:mod:`.emulator`), with an undeclared effect.

The record carries the controller's metadata and the reference kind and seed, never the
effect; the truth goes to a sidecar ``<record>.truth.json`` that the diagnosis never reads.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..loop.design import discrete_closed_loop
from ..loop.pid import PID
from ..plant.params import get_params
from . import emulator as _rig
from .emulation import DISTURBANCE_KEYS, checked_settings, current_truth
from .emulator import EFFECTS, RigConfig, simulate_rig
from .record import write_record

PLANT_PARAMS = ("k_DA", "u_0", "k_i", "m_k", "g", "k_c", "x_0", "k_FV", "k_x", "y_0", "k_AD", "y_MU0")


def parse_effect_spec(spec: str) -> tuple[str, dict[str, float]]:
    """``NAME:PARAM=VALUE[,PARAM=VALUE]`` -> (name, {param: value})."""
    if ":" not in spec:
        raise ValueError(f"effect {spec!r}: expected NAME:PARAM=VALUE (effects: {', '.join(EFFECTS)})")
    name, rest = spec.split(":", 1)
    name = name.strip()
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}: choose from {', '.join(EFFECTS)}")
    values: dict[str, float] = {}
    for item in rest.split(","):
        if "=" not in item:
            raise ValueError(f"effect {name}: {item!r} is not PARAM=VALUE")
        k, v = (s.strip() for s in item.split("=", 1))
        if k not in EFFECTS[name]:
            raise ValueError(f"effect {name} has no parameter {k!r}: its parameters are {', '.join(EFFECTS[name])}")
        try:
            values[k] = float(v)
        except ValueError:
            raise ValueError(f"effect {name}: {k} = {v!r} is not a number") from None
    return name, values


#: The disturbance family the acceptance benchmark draws from (issue 7): its ranges.
FAMILY = {
    "sigma_y": (1e-4, 1.5e-3),         # [MU] sensor noise, log-uniform
    "sigma_F_rel": (1e-3, 1e-2),       # random force RMS / weight, log-uniform
    "corner_hz": (5.0, 50.0),          # corner of the coloured force noise, log-uniform; or white
    "F_drift_rel": (0.0, 3e-3),        # drifting force offset RMS / weight (half the draws have none)
    "tau_drift": (1.0, 5.0),           # [s]
    "bits": (10, 14),
    "kp": (1.5, 3.0), "ki": (1.0, 6.0), "kd": (0.006, 0.014),   # PID gains, kept when the loop is stable
}


def draw_disturbance(seed: int, *, gains: bool = True) -> dict[str, float]:
    """One draw from the disturbance family :data:`FAMILY`: rig noise settings (``sigma_y``,
    ``sigma_F_rel``, ``tau_F_noise`` (0: white), ``F_drift_rel``, ``tau_drift``, ``bits``) and, with
    ``gains``, PID gains ``kp``, ``ki``, ``kd`` whose linear loop is stable and damped (every
    closed-loop pole inside the unit circle, complex pairs with a damping ratio of at least 0.15,
    at 2.0, 3.2 and 4.5 mm on the baseline plant)."""
    rng = np.random.default_rng([seed, 7])

    def logu(lo: float, hi: float) -> float:
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))

    f = FAMILY
    d: dict[str, float] = {
        "sigma_y": logu(*f["sigma_y"]),
        "sigma_F_rel": logu(*f["sigma_F_rel"]),
        "tau_F_noise": 0.0 if rng.uniform() < 0.25 else 1.0 / (2 * np.pi * logu(*f["corner_hz"])),
        "F_drift_rel": float(rng.uniform(*f["F_drift_rel"])) if rng.uniform() < 0.5 else 0.0,
        "tau_drift": float(rng.uniform(*f["tau_drift"])),
        "bits": int(rng.integers(f["bits"][0], f["bits"][1] + 1)),
    }
    if gains:
        p = get_params("baseline")

        def damped(pid: PID, x: float) -> bool:
            z = np.asarray(discrete_closed_loop(p, x, pid, None).poles()).astype(complex)
            if np.max(np.abs(z)) >= 1.0:
                return False
            s_ = np.log(z) / pid.ts
            pairs = s_[np.abs(s_.imag) > 1e-6]
            return not len(pairs) or float(np.min(-pairs.real / np.abs(pairs))) >= 0.15

        for _ in range(100):
            kp, ki, kd = (float(rng.uniform(*f[k])) for k in ("kp", "ki", "kd"))
            if all(damped(PID(kp=kp, ki=ki, kd=kd), x) for x in (2.0e-3, 3.2e-3, 4.5e-3)):
                d.update(kp=kp, ki=ki, kd=kd)
                break
    return d


def synth_record(out: Path, *, effects: dict[str, dict[str, float]] | None = None, reference: str = "steps", duration: float = 12.0, seed: int = 0, noise: bool = True,
                 params: dict[str, float] | None = None, ts: float = 1e-3, kp: float = 2.0, ki: float = 2.97,
                 kd: float = 0.01, u_min: float = 0.0, u_max: float = 1.0,
                 disturbance: dict[str, float] | None = None, period: float | None = None) -> Path:
    """Simulates the rig and writes a record at ``out`` (and ``out.truth.json``).

    ``period`` [s]: of a ``square`` or ``sine`` reference (default 3 s and 4 s, :func:`rig.reference`).

    ``disturbance``: rig noise settings (:data:`DISTURBANCE_KEYS`, e.g. from
    :func:`draw_disturbance`) over the emulator's defaults; PID gains in it override ``kp``, ``ki``, ``kd``."""
    kind = reference
    effects = effects or {}
    values, dist, (kp, ki, kd) = checked_settings(effects, params, disturbance, (kp, ki, kd), EFFECTS, PLANT_PARAMS)
    cfg = RigConfig().with_values(**{**(params or {}), **values, **dist}, seed=seed)
    if not noise:
        cfg = cfg.with_values(sigma_y=0.0, sigma_F_rel=0.0)
    w = _rig.reference(kind, duration, ts, seed, period=period)
    sim = simulate_rig(w, cfg, ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max, noise=noise)
    out = Path(out)
    write_record(out, sim["t"], sim["w"], sim["u"], sim["y"], ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max,
                 meta={"reference": kind, **({"period": str(period)} if period else {}), "seed": str(seed),
                       "source": "maglev-cosim synth (rig emulator)"})
    truth = {"effects": effects, "params": params or {}, "noise": noise, "seed": seed, "reference": kind,
             **({"period_s": period} if period else {}),
             "duration": duration, "pid": {"kp": kp, "ki": ki, "kd": kd},
             "disturbance": {k: getattr(cfg, k) for k in DISTURBANCE_KEYS},
             **current_truth(sim["i"], sim["i_limited"] > 0)}
    Path(str(out) + ".truth.json").write_text(json.dumps(truth, indent=2))
    return out
