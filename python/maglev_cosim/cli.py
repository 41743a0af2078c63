"""``maglev-cosim``: the command line.

Commands: ``step``, ``linearize``, ``bench``, ``diagnose``, ``identify``, ``synth``, ``demo``.
Every failure ends in one line on stderr (``maglev-cosim: error: ...``) and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

# Imported inside functions, on purpose: matplotlib (heavy, only `step` plots).
from . import __version__
from .diagnosis import CATALOGUE, DiagnosisResult, diagnose
from .diagnosis.effects import DEFAULT_EFFECTS
from .diagnosis.identify import PAPER, identify
from .diagnosis.replay import baseline_params
from .loop.controllers import ControllerError, load_controller
from .loop.design import closed_loop_report, plot_closed_loop_bode, plot_root_locus
from .loop.fmu import FmuError, ensure_fmu
from .loop.pid import PID
from .loop.simulate import reference_signal, simulate
from .plant.calibrated_fmu import calibrated_fmu
from .plant.fast import param_table
from .plant.formulas import point
from .plant.linear import linearize, operating_point, transfer_function
from .plant.params import as_params, set_label
from .records import emulator_ivp
from .records.load import Recording, WrongRig, load_all
from .records.record import RecordError, read_record
from .records.synth import parse_effect_spec, synth_record
from .report.bench import run_bench
from .rigs import load_rig


class CliError(Exception):
    """A failure to report in one line."""


def _progress(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not np.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"{text} must be a positive finite number")
    return v


def _finite(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not np.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text} is not finite")
    return v


#: Units a quantity on the command line may carry, as factors to SI.
_LENGTH = {"mm": 1e-3, "m": 1.0, "um": 1e-6, "µm": 1e-6}
_CURRENT = {"A": 1.0, "mA": 1e-3}


def _quantity(units: dict[str, float], default: str):
    """An argparse type for a number with an optional unit suffix (``3.2``, ``3.2mm``, ``0.0032 m``);
    a bare number is in ``default``. Returns the value in SI units."""

    def parse(text: str) -> float:
        t = text.strip()
        for unit in sorted(units, key=len, reverse=True):
            if t.endswith(unit):
                number, factor = t[: -len(unit)].strip(), units[unit]
                break
        else:
            number, factor = t, units[default]
        try:
            v = float(number)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a number with an optional unit ({', '.join(units)})") from None
        if not np.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text} is not finite")
        return v * factor

    parse.__name__ = f"quantity in {default}"
    return parse


_length = _quantity(_LENGTH, "mm")
_current = _quantity(_CURRENT, "A")


def _check_position(x: float, p, option: str = "--position") -> None:
    """A position [m] must lie on the ball's travel, between the stops."""
    if not p.x_min <= x <= p.x_max:
        raise CliError(f"{option} {x * 1e3:g} mm lies outside the travel between the stops "
                       f"[{p.x_min * 1e3:g}, {p.x_max * 1e3:g}] mm (positions are in mm; add 'm' for metres)")


# ----------------------------------------------------------------------------- step

def cmd_step(a: argparse.Namespace) -> dict:
    import control   # (with the matplotlib.pyplot it loads: half a second that `diagnose` need not pay)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(a.out)
    p = as_params(a.params)
    _check_position(a.position, p)
    pid = PID()
    if a.duration is None:   # a step settles in 2 s; a square or sine wave shows two 3 s periods
        a.duration = 2.0 if a.reference == "step" else 6.0
    n = int(round(a.duration / pid.ts))
    if n < 10:
        raise CliError(f"--duration {a.duration} s is shorter than 10 controller samples")
    op = operating_point(p, a.position)
    lo, hi = point(p, p.x_min).y, point(p, p.x_max).y
    for level in (op.y_MU + a.amplitude, op.y_MU - a.amplitude if a.reference == "sine" else op.y_MU):
        if not lo <= level <= hi:
            raise CliError(f"--amplitude {a.amplitude:g} MU takes the reference to {level:.4g} MU, outside the "
                           f"readings of the travel [{lo:.4g}, {hi:.4g}] MU from {a.position * 1e3:g} mm")
    fmu = ensure_fmu(a.fmu)
    w = reference_signal(a.reference, a.duration, pid.ts, base=op.y_MU, amplitude=a.amplitude)
    _progress(f"closed loop on the FMU: {a.reference} of {a.amplitude} MU from x = {a.position * 1e3:.2f} mm, "
              f"{a.duration} s at {1 / pid.ts:.0f} Hz (parameters: {a.params})")
    t0 = time.perf_counter()
    res = simulate(p, w, controller=pid, backend="fmu", x_op=a.position, fmu=fmu)
    t_fmu = time.perf_counter() - t0
    _progress("same experiment on the independent pure-Python reference plant")
    ref = simulate(p, w, controller=pid, backend="reference", x_op=a.position)
    dy = float(np.max(np.abs(res["y"] - ref["y"])))
    du = float(np.max(np.abs(res["u"] - ref["u"])))
    out.mkdir(parents=True, exist_ok=True)
    res.to_csv(out / "step.csv")
    info = {}
    if a.reference == "step":
        k0 = int(np.argmax(res["w"] != res["w"][0]))
        yk = res["y"][k0:] - res["y"][k0 - 1 if k0 > 0 else 0]
        si = control.step_info(yk, T=res["t"][k0:] - res["t"][k0], yfinal=float(res["w"][-1] - res["w"][0]))
        info = {k: float(v) for k, v in si.items()}
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(res["t"], res["w"], color="0.5", lw=1, label="reference w")
    ax[0].plot(res["t"], res["y"], color="tab:blue", lw=1, label="y (FMU)")
    ax[0].plot(res["t"], ref["y"], color="tab:orange", lw=1, ls="--", label="y (Python reference)")
    ax[0].set_ylabel("position y [MU]")
    ax2 = ax[0].twinx()
    ax2.plot(res["t"], res["x"] * 1e3, alpha=0)
    ax2.set_ylabel("x [mm]")
    lo, hi = ax[0].get_ylim()    # the same axis in mm (Eq. 12, 13 inverted; beyond the stops: linear)
    slope, base = op_slope(p, a.position)
    ax2.set_ylim((lo - base) / slope * 1e3 + a.position * 1e3, (hi - base) / slope * 1e3 + a.position * 1e3)
    ax[0].legend(loc="lower right", fontsize=8)
    ax[1].plot(res["t"], res["u"], color="tab:green", lw=1, label="u (controller output)")
    # u's limits: the D/A converter's range ±1 MU (Eq. 1), and the PID's output limits inside it
    ax[1].axhspan(-1.0, 1.0, color="tab:green", alpha=0.06, lw=0)
    for lim in (-1.0, 1.0):
        ax[1].axhline(lim, color="tab:red", lw=1, ls="--", label="D/A range ±1 MU" if lim > 0 else None)
    ax[1].axhline(pid.u_min, color="0.4", lw=0.8, ls=":", label=f"PID limits [{pid.u_min:g}, {pid.u_max:g}] MU")
    ax[1].set_ylim(-1.1, 1.1)
    ax[1].set_ylabel("u [MU]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="lower right", fontsize=8, ncol=3)
    fig.suptitle(f"CE152 closed loop, paper's discrete PID (Eq. 24/25), {set_label(a.params)}", fontsize=11)
    fig.tight_layout()
    fig.savefig(out / "step.png", dpi=110)
    plt.close(fig)
    report = {"reference": a.reference, "amplitude": a.amplitude, "duration": a.duration, "position": a.position,
              "params": a.params, "step_info": info, "fmu_vs_reference": {"max_abs_dy": dy, "max_abs_du": du},
              "fmu_loop_seconds": t_fmu, "samples": n}
    (out / "step.json").write_text(json.dumps(report, indent=2))
    print(f"wrote {out / 'step.csv'}, {out / 'step.png'}, {out / 'step.json'}")
    if info:
        print("step_info: " + ", ".join(f"{k} {v:.4g}" for k, v in info.items()))
    print(f"FMU vs pure-Python reference: max |dy| = {dy:.3e} MU, max |du| = {du:.3e} MU")
    return report


def op_slope(p, x: float) -> tuple[float, float]:
    """The reading's slope [MU/m] and value [MU] at ``x`` [m] (Eq. 12, 13)."""
    pt = point(p, x)
    return pt.dy_dx, pt.y


# ----------------------------------------------------------------------------- linearize

def cmd_linearize(a: argparse.Namespace) -> dict:
    p = as_params(a.params)
    _check_position(a.position, p)
    op = operating_point(p, a.position)
    i = a.current if a.current is not None else op.i
    if not 0 < i <= p.i_max:
        raise CliError(f"--current {i:g} A lies outside the amplifier's range (0, i_max = {p.i_max:g}] A")
    sys_ = linearize(p, a.position, i=i)
    tf = transfer_function(p, a.position, i=i)
    poles = np.sort_complex(np.asarray(sys_.poles()))
    zeros = np.asarray(tf.zeros())
    np.set_printoptions(precision=6, suppress=False, linewidth=120)
    print(f"operating point: x = {a.position * 1e3:g} mm, v = 0, i = {i:.6g} A, u = {op.u_MU:.6g} MU, y = {op.y_MU:.6g} MU "
          f"(parameters: {a.params})")
    print("A =\n", sys_.A, "\nB =\n", sys_.B, "\nC =\n", sys_.C, "\nD =\n", sys_.D)
    print("poles:", poles)
    print("zeros:", zeros)
    print("H(s) =", tf)
    cfg = PID()
    cl = closed_loop_report(p, a.position, cfg)
    print("closed loop with the discrete PID: " + ", ".join(
        f"{k} {_short(v)}" for k, v in cl.items() if not isinstance(v, (dict, list, tuple, np.ndarray))))
    if a.plots:
        outdir = Path(a.plots)
        outdir.mkdir(parents=True, exist_ok=True)
        plot_root_locus(p, a.position, cfg, outdir / "root_locus.png")
        plot_closed_loop_bode(p, a.position, cfg, outdir / "closed_loop_bode.png")
        print(f"wrote {outdir / 'root_locus.png'}, {outdir / 'closed_loop_bode.png'}")
    data = {"operating_point": {"x": a.position, "v": 0.0, "i": i, "u": op.u_MU, "y": op.y_MU},
            "A": np.asarray(sys_.A).tolist(), "B": np.asarray(sys_.B).tolist(), "C": np.asarray(sys_.C).tolist(),
            "D": np.asarray(sys_.D).tolist(),
            "poles": [[float(z.real), float(z.imag)] for z in poles],
            "zeros": [[float(z.real), float(z.imag)] for z in zeros],
            "tf": {"num": np.asarray(tf.num[0][0]).tolist(), "den": np.asarray(tf.den[0][0]).tolist()},
            "closed_loop": _jsonable(cl)}
    if a.json:
        Path(a.json).write_text(json.dumps(data, indent=2))
        print(f"wrote {a.json}")
    return data


def _short(v) -> str:
    return f"{v:.4g}" if isinstance(v, (float, np.floating)) else str(v)


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, complex):
        return [o.real, o.imag]
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.complexfloating):
        return [float(o.real), float(o.imag)]
    return o


# ----------------------------------------------------------------------------- bench

def cmd_bench(a: argparse.Namespace) -> dict:
    res = run_bench(fmu=a.fmu, record_seconds=a.duration, diagnose=not a.no_diagnose, json_path=a.json)
    if a.json:
        print(f"wrote {a.json}")
    return res


# ----------------------------------------------------------------------------- records

def _load(path: str, implausible: bool = False):
    rec = read_record(path, plausibility="warn" if implausible else "refuse")
    for w in rec.warnings:
        print(f"warning: {path}: {w}", file=sys.stderr)
    return rec


def _records(paths, rig, a: argparse.Namespace) -> list[Recording]:
    """Every record of the command read (:func:`maglev_cosim.records.load.load`) before anything
    runs: a record that does not fit ``--rig`` or lacks a column the command needs (the drive; the
    reference of a declared controller) is refused in one line naming the file."""
    require = ("drive", "reference") if getattr(a, "controller", None) else ("drive",)
    recs = load_all(paths, rig, resample=a.resample, require=require,
                    plausibility="warn" if getattr(a, "accept_implausible", False) else "refuse")
    for r in recs:
        for w in r.warnings:
            print(f"warning: {r.path}: {w}", file=sys.stderr)
    return recs


def _print_result(res: DiagnosisResult, recs: list[Recording] = ()) -> None:
    """What a diagnosis found, from the typed result: the verdict with its fits, the warnings and
    reasons, the selected effects with ±σ, before/after, and for a real rig each segment's skill,
    the checks of the rig file and of a declared controller, and the model / black box / naive table."""
    fit = res.fit.prediction if res.fit else None
    free = res.fit.free_run if res.fit else None
    figures = []
    if free is not None:
        figures.append(f"free run {free.y:.1f}/{free.u:.1f} %")
    if fit is not None and fit.y is not None:
        figures.append(f"{fit.horizon_s * 1e3:.0f} ms ahead {fit.y:.1f}"
                       + (f"/{fit.second:.1f} %" if fit.second is not None else " %"))
    what = "y/u" if res.kind == "ce152" else "gap/current"
    print(f"verdict: {res.verdict}" + (f" (fit {what}: {', '.join(figures)})" if figures else ""))
    for r in res.reasons:
        print(f"  {r}")
    said = {w for r in recs for w in r.warnings}      # on stderr as the records were read
    for w in res.warnings:
        if w not in said or res.kind == "ce152":
            print(f"warning: {w}")
    print(f"selected: {res.selected or 'none'}")

    def rms(x) -> str:
        if x is None or x.rms_y is None:
            return "-"
        return (f"rms_y {x.rms_y:.6f} MU" + (f", rms_u {x.rms_u:.6f} MU" if x.rms_u is not None else "")
                + (f" ({x.horizon_s * 1e3:.0f} ms ahead)" if x.horizon_s is not None else ""))

    print(f"before: {rms(res.before)}")
    print(f"after:  {rms(res.after)}")
    for e in res.selected:
        for p in (CATALOGUE[e].params if e in CATALOGUE else ()):
            if p in res.parameters and res.parameters[p].value is not None:
                print(f"  {res.parameters[p]}")
    for s in res.segments if res.kind == "rig" else ():     # a CE152 record's are its comparison's
        cur = s.current_from_actuator
        skill = "  ".join(f"{h}: skill {k:+.2f}" for h, k in s.skill.items() if k is not None)
        print(f"{'validation ' if s.role == 'validation' else ''}{s.label}: current from actuator "
              f"{'-' if cur is None else f'{cur:.1f}'} %  {skill}")
    for c in res.checks:
        if c.force_balance:
            med, p10, p90 = c.force_balance
            print(f"{c.label}: the force law carries {100 * med:.0f} % of the weight at the measured gap and current "
                  f"(median; 10-90 %: {100 * p10:.0f}-{100 * p90:.0f} %)")
        if c.controller:
            loops = "".join(f"; {k} {v:.1f} %" for k, v in c.loop_fits.items())
            cl = ", ".join(f"gap {g:.1f} % / actuator {u:.1f} %" for g, u in c.closed_loop)
            print(f"{c.label}: declared controller {c.controller}: actuator fit {c.actuator_fit:.1f} %{loops}; "
                  f"closed loop 20 ms ahead: {cl or 'no segment'}")
    if res.comparison:
        print("median skill against 'stays put' (worst): model in closed loop / model driven by the actuator "
              "signal / black box / black box with the actuator signal only up to the start / constant velocity")
        fmt = lambda v: "nan" if v is None else f"{v:+.2f}"  # noqa: E731
        for c in res.comparison:
            for h, k in c.horizons.items():     # one record's blocks: no worst to show beside the median
                print(f"  {c.role} ({c.segments}) {h:>6}: " + " / ".join(
                    fmt(getattr(k, w)) + (f" ({fmt(getattr(k, w + '_worst'))})" if c.segments > 1 else "")
                    for w in k.WHO))
    if res.written:
        print("wrote " + ", ".join(str(p) for p in res.written))


def cmd_fmu(a: argparse.Namespace) -> dict:
    rig = load_rig(a.rig)
    params = rig.params
    if a.calibration:
        try:
            cal = json.loads(Path(a.calibration).read_text())["parameters"]
            params = params.replace(**cal)
            params.validate()
        except (OSError, KeyError, TypeError, json.JSONDecodeError) as e:
            raise CliError(f"{a.calibration}: not a calibrate/diagnose JSON with 'parameters' ({e})") from None
    out = Path(a.out)
    if out.suffix != ".fmu":
        raise CliError(f"--out {out}: an FMU file name must end in .fmu")
    out.parent.mkdir(parents=True, exist_ok=True)
    calibrated_fmu(ensure_fmu(a.fmu), out, params.to_start_values(),
                   resources={"rig.toml": rig.path.read_bytes()},
                   description=f"{rig.description} (rig file {rig.name}, maglev-cosim plant)")
    print(f"wrote {out} (rig {rig.name}{', calibrated by ' + a.calibration if a.calibration else ''})")
    return {"fmu": str(out)}


def cmd_calibrate(a: argparse.Namespace) -> DiagnosisResult:
    recs = _records([*a.records, *(a.validate or ())], a.rig, a)
    train, held = recs[:len(a.records)], recs[len(a.records):]
    res = diagnose(train, validate=held, out=a.out, progress=_progress, controller=_controller_file(a, train[0].rig))
    _print_result(res, recs)
    return res


def _controller_file(a: argparse.Namespace, rig):
    """The declared controller of --controller, read and checked before anything runs."""
    if not getattr(a, "controller", None):
        return None

    try:
        return load_controller(a.controller, rig)
    except ControllerError as e:
        raise CliError(str(e)) from None


def cmd_diagnose(a: argparse.Namespace) -> DiagnosisResult:
    (rec,) = _records([a.record], a.rig, a)       # fails before anything is written
    ctl = _controller_file(a, rec.rig)
    if rec.kind == "ce152" and ctl is not None:
        raise CliError(f"--controller {a.controller}: a CE152 record declares its controller in its metadata "
                       "(docs/record-format.md); --controller is for a real rig's record")
    effects = a.effects.split(",") if a.effects else None
    res = diagnose(rec, effects=effects, out=a.out, progress=_progress, workers=a.workers, fmu=a.fmu,
                   controller=ctl, per_record=False)
    _print_result(res, [rec])
    return res


def cmd_identify(a: argparse.Namespace) -> dict:
    rec = _load(a.record)
    res = identify(rec, baseline_params(), with_simplex=not a.no_simplex)
    print(f"{len(res['points']['x'])} equilibrium points from {a.record}")
    print(f"{'method':<16}{'quantity':<8}{'this record':>14}{'paper':>14}")
    for method in ("two_point", "least_squares", "simplex"):
        if method not in res:
            continue
        for q, v in res[method].items():
            if q in PAPER[method]:
                print(f"{method:<16}{q:<8}{v:>14.5g}{PAPER[method][q]:>14.5g}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
        print(f"wrote {a.json}")
    return res


def cmd_synth(a: argparse.Namespace) -> dict:
    effects: dict[str, dict[str, float]] = {}
    for spec in a.effect or []:
        name, values = parse_effect_spec(spec)
        effects.setdefault(name, {}).update(values)
    params = {}
    for spec in a.param or []:
        if "=" not in spec:
            raise CliError(f"--param {spec!r}: expected NAME=VALUE")
        k, v = spec.split("=", 1)
        params[k.strip()] = _finite(v)
    if a.period is not None and a.reference not in ("square", "sine"):
        raise CliError(f"--period applies to a square or sine reference, not {a.reference}")
    if a.setting and a.emulator != "ivp":
        raise CliError(f"--setting {a.setting[0]!r}: settings belong to the independent emulator (--emulator ivp)")
    try:
        settings = emulator_ivp.parse_settings(a.setting or [])
    except ValueError as e:
        raise CliError(str(e)) from None
    kw, write = {}, synth_record
    if a.emulator == "ivp":
        kw, write = {"settings": settings}, emulator_ivp.synth_record   # the independent emulator, same arguments
    _progress(f"synthesising {a.duration} s ({a.reference}) with effects {effects or 'none'} "
              f"({'the independent emulator' if a.emulator == 'ivp' else 'the rig emulator'})")
    path = write(Path(a.out), effects=effects, reference=a.reference, duration=a.duration, seed=a.seed,
                        noise=not a.no_noise, params=params or None, period=a.period, **kw)
    print(f"wrote {path}")
    return {"record": str(path)}


# ----------------------------------------------------------------------------- demo

def cmd_demo(a: argparse.Namespace) -> DiagnosisResult:
    out = Path(a.out)
    fmu = ensure_fmu(None)
    _progress(f"FMU: {fmu}")
    # each step through the real parser, so that the demo gets every option's default from one place
    parse = build_parser().parse_args
    # Two parameter sets, on purpose (each plot's title names its own): the step runs the FMU with its
    # defaults (section3); the linearisation takes the set that reproduces the paper's Eq. 18/19 (eq18).
    # The diagnosis starts from 'baseline' (section3 with T_a = 0) and calibrates it on the record.
    _progress(f"closed-loop step: {set_label('section3')}")
    cmd_step(parse(["step", "--out", str(out / "step"), "--fmu", str(fmu)]))
    _progress(f"linearisation (to compare with the paper's Eq. 18/19): {set_label('eq18')}")
    cmd_linearize(parse(["linearize", "--params", "eq18", "--current", "0.5612",
                         "--json", str(out / "linearize.json"), "--plots", str(out / "linearize")]))
    rec_path = out / "record_undeclared_effect.csv"
    cmd_synth(parse(["synth", "--out", str(rec_path), "--effect", "delay:T_d=0.0025", "--reference", "steps",
                     "--duration", "12", "--seed", str(a.seed)]))
    d = cmd_diagnose(parse(["diagnose", str(rec_path), "--out", str(out / "diagnosis"), "--fmu", str(fmu)]))
    truth = json.loads(Path(str(rec_path) + ".truth.json").read_text())
    print(_truth_table(truth, d))
    print(f"demo done: see {out}/step, {out}/linearize, {out}/diagnosis/report.html (and report.md)")
    return d


def _truth_table(truth: dict, d: DiagnosisResult) -> str:
    """The planted effects of a synthetic record beside what the diagnosis estimated."""
    units = {n: row[3] for n, row in param_table().items()}
    rows = [f"{'effect':<22}{'parameter':<11}{'planted':>12}{'estimated':>12}{'± 1 sigma':>12}  unit"]
    for name, values in truth["effects"].items():
        found = name in d.selected
        for k, v in values.items():
            p = d.parameters.get(k) if found else None
            est, sd = (p.value, p.sigma) if p is not None else (None, None)
            rows.append(f"{name:<22}{k:<11}{v:>12.4g}{'not found' if est is None else f'{est:.4g}':>12}"
                        f"{'' if sd is None else f'{sd:.2g}':>12}  {units.get(k, '')}")
    extra = [e for e in d.selected if e not in truth["effects"]]
    if extra:
        rows.append(f"selected but not planted: {', '.join(extra)}")
    return "planted truth (from the .truth.json sidecar) against the diagnosis:\n" + "\n".join(rows)


# ----------------------------------------------------------------------------- main

class _Parser(argparse.ArgumentParser):
    """argparse with its errors in one line (no usage dump), like every other failure here."""

    #: Builds the epilog (the effect catalogue with its parameters' units) when help is shown.
    lazy_epilog = None

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{self.prog}: error: {message} (see {self.prog.split()[0]} --help)", file=sys.stderr)
        raise SystemExit(2)

    def format_help(self) -> str:
        if self.lazy_epilog is not None:
            self.epilog, self.lazy_epilog = self.lazy_epilog(), None
        return super().format_help()


EXAMPLES = """examples:
  maglev-cosim step --out runs/step                      closed-loop step of 0.05 MU at 3.2 mm
  maglev-cosim step --reference sine --amplitude 0.03 --position 3.5 --out runs/sine
  maglev-cosim linearize --params eq18 --current 0.5612 --plots runs/lin --json runs/lin.json
  maglev-cosim synth --out rec.csv --effect delay:T_d=0.0025 --seed 3
  maglev-cosim diagnose rec.csv --out runs/diag
  python -m maglev_cosim --version
"""


def _catalogue_help() -> str:
    lines = ["effect catalogue (name: FMU parameters [unit], what it models; * = opt-in with --effects):"]
    table = param_table()
    for e in CATALOGUE.values():
        pars = ", ".join(f"{n} [{table[n][3]}]" for n in e.params)
        star = "" if e.name in DEFAULT_EFFECTS else " *"
        lines.append(f"  {e.name}{star}: {pars}\n      {e.description}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    ap = _Parser(prog="maglev-cosim", formatter_class=fmt,
                 description="The Humusoft CE152 magnetic levitation rig as an FMI co-simulation FMU, and a "
                             "toolkit that drives it in closed loop and reconciles it with measured records. "
                             "Positions are in mm (or add a unit: 3.2mm, 0.0032m), converter values in MU.")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    ap.lazy_epilog = lambda: EXAMPLES + "\n" + _catalogue_help()
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")
    fmu_help = "FMU to use (default: the installed maglev.fmu, or $MAGLEV_FMU)"

    s = sub.add_parser("step", formatter_class=fmt, epilog=EXAMPLES,
                       help="closed-loop step, square or sine on the FMU, checked against the Python reference",
                       description="The paper's discrete PID (Eq. 24/25) drives the FMU through fmpy from a settled "
                                   "start; the same run on the independent pure-Python plant is the check.")
    s.add_argument("--amplitude", type=_finite, default=0.05, metavar="MU",
                   help="reference change [MU] (default 0.05 MU, about 0.4 mm); the reference must stay within "
                        "the readings of the travel")
    s.add_argument("--reference", choices=["step", "square", "sine"], default="step",
                   help="step at 0.1 s; square and sine waves of period 3 s (Sec. 5)")
    s.add_argument("--duration", type=_positive, default=None, metavar="S",
                   help="[s] (default 2 s for a step, 6 s, two periods, for square and sine)")
    s.add_argument("--params", default="section3", choices=["section3", "eq18", "baseline"],
                   help="parameter set (default section3, the FMU's defaults)")
    s.add_argument("--position", type=_length, default=0.0032, metavar="X",
                   help="operating point, between the stops (default 3.2 mm)")
    s.add_argument("--fmu", default=None, help=fmu_help)
    s.add_argument("--out", required=True, help="output folder for step.csv, step.png, step.json")
    s.set_defaults(func=cmd_step)

    s = sub.add_parser("linearize", formatter_class=fmt, help="Jacobian linearisation (Eq. 16-19) and the "
                       "closed loop with the PID; root locus and Bode plots on request",
                       description="A, B, C, D, poles, zeros and H(s) at an operating point (Eq. 16-19), and the "
                                   "discrete closed loop with the paper's PID. Nothing is written unless --json "
                                   "or --plots is given.")
    s.add_argument("--position", type=_length, default=0.0032, metavar="X",
                   help="operating point between the stops (default 3.2 mm, the paper's Section 4)")
    s.add_argument("--current", type=_current, default=None, metavar="I",
                   help="operating current (default: the equilibrium current; the paper uses 0.5612 A)")
    s.add_argument("--params", default="eq18", choices=["section3", "eq18", "baseline"],
                   help="parameter set (default eq18, the reading of the paper's Eq. 18)")
    s.add_argument("--json", default=None, metavar="FILE", help="write A, B, C, D, poles, zeros, H(s) and the "
                   "closed-loop figures to this JSON file")
    s.add_argument("--plots", default=None, metavar="DIR", help="write root_locus.png and closed_loop_bode.png here")
    s.set_defaults(func=cmd_linearize)

    s = sub.add_parser("bench", help="tables of figures: fmpy loop, cffi fast path, pure-Python reference, "
                       "diagnosis time")
    s.add_argument("--fmu", default=None, help=fmu_help)
    s.add_argument("--duration", type=_positive, default=10.0, metavar="S", help="closed-loop length [s] (default 10)")
    s.add_argument("--no-diagnose", action="store_true", help="skip timing a 12 s diagnosis")
    s.add_argument("--json", default=None, metavar="FILE", help="also write the figures to this JSON file")
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("diagnose", formatter_class=fmt,
                       help="calibrate the model on a record, find the effect it lacks, report before/after",
                       description="Replays the record in closed loop, calibrates k_c, x_0, k_FV, u_0, tries every "
                                   "effect of the catalogue on held-out blocks, and writes report.md, "
                                   "diagnosis.json and a calibrated FMU.")
    s.add_argument("record", help="record file (docs/record-format.md)")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--fmu", default=None, help=fmu_help)
    s.add_argument("--effects", default=None, metavar="A,B", help="comma-separated subset of the catalogue below")
    s.add_argument("--workers", type=int, default=None, help="processes for candidate fits (default 2)")
    s.add_argument("--accept-implausible", action="store_true",
                   help="diagnose a record that looks physically implausible (constant or saturated signals, "
                        "the ball on a stop for most of it) with warnings in the report, instead of refusing it")
    s.add_argument("--rig", default=None, help="the rig of a real record: a shipped rig (ce152, inteco-mls2em, "
                   "levitador) or a rig file (docs/rigs.md); a real rig's record (an Inteco .mat, a levitador "
                   "text, a text record declaring its columns: docs/bringing-your-rig.md) needs it")
    s.add_argument("--controller", default=None, help="the record's controller, declared in a controller file "
                   "(docs/controllers.md) or shipped (levitador-cascade, inteco-lqi): checked against the recorded "
                   "actuator signal and replayed in closed loop; without it the controller is treated as unknown")
    s.add_argument("--resample", action="store_true",
                   help="interpolate a real record with non-uniform time onto a uniform grid instead of refusing it")
    s.lazy_epilog = _catalogue_help
    s.set_defaults(func=cmd_diagnose)

    s = sub.add_parser("fmu", help="write the plant FMU for a rig: the rig's parameters as start values, "
                       "the rig file in resources/")
    s.add_argument("--rig", required=True, help="shipped rig name or rig file (docs/rigs.md)")
    s.add_argument("--out", required=True, help="the FMU file to write (.fmu)")
    s.add_argument("--calibration", default=None, metavar="JSON",
                   help="start values from a calibrate or diagnose --rig JSON ('parameters') over the rig's")
    s.add_argument("--fmu", default=None, help=fmu_help)
    s.set_defaults(func=cmd_fmu)

    s = sub.add_parser("calibrate", help="one parameter set on several records of one rig: per-record fit, "
                       "parameter spread, validation on records not used")
    s.add_argument("records", nargs="+", help="CE152 records (docs/record-format.md), or real records with --rig "
                   "(Inteco .mat, levitador text, a text record declaring its columns: docs/bringing-your-rig.md)")
    s.add_argument("--rig", default=None, help="shipped rig name or rig file of real records (docs/rigs.md); "
                   "none for CE152 records")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--validate", action="append", metavar="FILE", help="a record to judge the calibration on, "
                   "not used to fit it (repeatable)")
    s.add_argument("--controller", default=None, help="the record's controller, declared in a controller file "
                   "(docs/controllers.md) or shipped (levitador-cascade, inteco-lqi): checked against the recorded "
                   "actuator signal and replayed in closed loop; without it the controller is treated as unknown")
    s.add_argument("--resample", action="store_true", help="interpolate non-uniform time onto a uniform grid")
    s.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("identify", help="the paper's identification methods on a record (Sec. 3.4)")
    s.add_argument("record", help="record file (docs/record-format.md)")
    s.add_argument("--json", default=None, metavar="FILE", help="write the results to this JSON file")
    s.add_argument("--no-simplex", action="store_true", help="skip the Nelder-Mead fit of k_FV (Sec. 3.4.3)")
    s.set_defaults(func=cmd_identify)

    s = sub.add_parser("synth", formatter_class=fmt,
                       help="write a synthetic record from the rig emulator (truth in a .truth.json sidecar)")
    s.add_argument("--out", required=True, help="record file to write")
    s.add_argument("--effect", action="append", metavar="NAME:PARAM=VALUE",
                   help="an effect to plant, e.g. delay:T_d=0.0025 (repeatable; the catalogue below, plus "
                        "slew_rate:di_max=... [A/s], an effect the catalogue lacks)")
    s.add_argument("--param", action="append", metavar="NAME=VALUE", help="plant parameter override in SI units "
                   "(repeatable)")
    s.add_argument("--reference", choices=["square", "sine", "steps", "chirp"], default="steps",
                   help="reference: random staircase (default, most informative), square, sine or chirp")
    s.add_argument("--period", type=_positive, metavar="S", help="[s] period of a square or sine reference "
                   "(default 3 and 4)")
    s.add_argument("--duration", type=_positive, default=12.0, metavar="S", help="[s] (default 12)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the noise and the staircase (default 0)")
    s.add_argument("--no-noise", action="store_true", help="no sensor noise, random force or quantisation")
    s.add_argument("--emulator", choices=["rig", "ivp"], default="rig",
                   help="rig: maglev_cosim.records.emulator (default); ivp: the independent emulator written from the paper "
                        "(maglev_cosim.records.emulator_ivp: solve_ivp, coloured sensor noise, the PID's output 0.3 of a "
                        "sample late; effects " + ", ".join(emulator_ivp.EFFECTS) + ")")
    s.add_argument("--setting", action="append", metavar="NAME=VALUE",
                   help="with --emulator ivp: pid_offset (fraction of the sample, default 0.3), f_y (sensor noise "
                        "corner [Hz], default 100, inf: white), method, rtol, pid_derivative (error, the default, or "
                        "measurement: the PID's derivative of the reading alone), pid_tf (its derivative filter [s]); "
                        "the record declares the PID's gains alone")
    s.lazy_epilog = _catalogue_help
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("demo", help="the main job: step, linearise, synthesise and diagnose a record")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--seed", type=int, default=7, help="seed of the synthetic record (default 7)")
    s.set_defaults(func=cmd_demo)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    try:
        a.func(a)
    except KeyboardInterrupt:
        print("maglev-cosim: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one line, no traceback

        kind = "" if isinstance(exc, (CliError, FmuError, RecordError, WrongRig, ValueError, FileNotFoundError)) \
            else f"{type(exc).__name__}: "
        msg = " ".join(str(exc).split())
        print(f"maglev-cosim: error: {kind}{msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
