"""Synthetic records from the rig emulator (:mod:`.rig`), with an undeclared effect.

The record carries the controller's metadata and the reference kind and seed, never the
effect; the truth goes to a sidecar ``<record>.truth.json`` that the diagnosis never reads.
"""

from __future__ import annotations

import json
from pathlib import Path

from .record import write_record
from . import rig as _rig
from .rig import RigConfig, simulate_rig

#: Effect name -> its parameters (rig names = FMU names for the catalogue).
EFFECTS: dict[str, tuple[str, ...]] = {
    "amplifier_lag": ("T_a",),
    "force_lag": ("T_F",),
    "delay": ("T_d",),
    "sensor_nonlinearity": ("k_x2",),
    "current_saturation": ("i_max",),
    "periodic_disturbance": ("A_d", "f_d", "phi_d"),
    "force_exponent": ("n",),
    "coulomb_friction": ("F_c",),
}

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


def synth_record(out: Path, *, effects: dict[str, dict[str, float]] | None = None, reference: str = "steps", duration: float = 12.0, seed: int = 0, noise: bool = True,
                 params: dict[str, float] | None = None, ts: float = 1e-3, kp: float = 2.0, ki: float = 2.97,
                 kd: float = 0.01, u_min: float = 0.0, u_max: float = 1.0) -> Path:
    """Simulates the rig and writes a record at ``out`` (and ``out.truth.json``)."""
    kind = reference
    effects = effects or {}
    values: dict[str, float] = {}
    for name, pv in effects.items():
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}: choose from {', '.join(EFFECTS)}")
        for k in pv:
            if k not in EFFECTS[name]:
                raise ValueError(f"effect {name} has no parameter {k!r}")
        values.update(pv)
    for k in params or {}:
        if k not in PLANT_PARAMS:
            raise ValueError(f"unknown plant parameter {k!r}: choose from {', '.join(PLANT_PARAMS)}")
    cfg = RigConfig().with_values(**{**(params or {}), **values}, seed=seed)
    if not noise:
        cfg = cfg.with_values(sigma_y=0.0, sigma_F_rel=0.0)
    w = _rig.reference(kind, duration, ts, seed)
    sim = simulate_rig(w, cfg, ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max, noise=noise)
    out = Path(out)
    write_record(out, sim["t"], sim["w"], sim["u"], sim["y"], ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max,
                 meta={"reference": kind, "seed": str(seed), "source": "maglev-cosim synth (rig emulator)"})
    truth = {"effects": effects, "params": params or {}, "noise": noise, "seed": seed, "reference": kind,
             "duration": duration, "sigma_y": cfg.sigma_y, "sigma_F_rel": cfg.sigma_F_rel}
    Path(str(out) + ".truth.json").write_text(json.dumps(truth, indent=2))
    return out
