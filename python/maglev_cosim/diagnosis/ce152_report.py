"""The CE152 path's figures, report and calibrated FMU: ``report.md`` with PNG plots, ``report.html``
and ``maglev_calibrated.fmu`` (the FMU with the final parameters as start values, its own GUID and
model name, the report as its documentation and ``resources/calibration.json``)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import zipfile
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

# Imported inside functions, on purpose: matplotlib (heavy, only the plots) and lxml (fmpy's dependency).
from .._html import write_html
from ..plant.calibrated_fmu import calibrated_fmu, issued_guid
from ..plant.fast import param_table
from ..plant.params import set_label
from ..records.record import Record
from .acceptance import CRITERION
from .effects import CATALOGUE
from .locate import LOCATIONS, best_per_location
from .metrics import nrmse_fit, psd, resid
from .pipeline import Diagnosis
from .replay import baseline_params
from .result import Json


def _sha256(path: str | Path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _calibration_date() -> str:
    """Today (UTC), or the day of ``$SOURCE_DATE_EPOCH`` when set (reproducible builds)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    now = datetime.fromtimestamp(int(epoch), timezone.utc) if epoch else datetime.now(timezone.utc)
    return now.strftime("%Y-%m-%d")


def calibration_data(rec: Record, d: Diagnosis) -> Json:
    """``resources/calibration.json`` of a calibrated FMU: the source record and its hash, the date,
    the effects found, every parameter that differs from the C defaults with its ±1 standard error
    where the diagnosis estimated one, and the fit figures before and after."""
    table = param_table()
    params = {}
    for name, value in d.parameters.items():
        sigma = d.uncertainties.get(name)
        params[name] = {"value": float(value), "unit": table[name][3] if name in table else None,
                        **({"sigma": float(sigma)} if sigma is not None and math.isfinite(sigma) else {})}
    fits = {k: {"y": nrmse_fit(rec.y, d.sims[k]["y"]), "u": nrmse_fit(rec.u, d.sims[k]["u"])}
            for k in ("before", "after") if k in d.sims}
    return {
        "format": "maglev-cosim calibration 1",
        "record": {"file": Path(rec.path).name, "sha256": _sha256(rec.path), "samples": rec.n, "ts_s": rec.ts},
        "date": _calibration_date(),
        "effects": list(d.selected),
        "verdict": d.verdict.verdict if d.verdict is not None else None,
        "parameters": params,
        "fit": {"free_run_nrmse_percent": fits, "rms": {"before": d.before, "after": d.after},
                **({"verdict_fit": d.verdict.fit, "verdict_fit_before": d.verdict.fit_before}
                   if d.verdict is not None else {})},
    }


def _describe(cal: dict) -> str:
    effects = []
    for e in cal["effects"]:
        parts = []
        for p in CATALOGUE[e].params:
            q = cal["parameters"][p]
            parts.append(f"{p} = {q['value']:.4g}" + (f" ± {q['sigma']:.2g}" if "sigma" in q else "")
                         + (f" {q['unit']}" if q["unit"] else ""))
        effects.append(f"{e} ({', '.join(parts)})")
    sha = cal["record"]["sha256"]
    return (f"CE152 plant calibrated on record {cal['record']['file']}"
            + (f" (sha256 {sha[:16]}...)" if sha else "") + f" on {cal['date']}; effects found: "
            + ("; ".join(effects) if effects else "none") + " (maglev-cosim diagnose; resources/calibration.json)")


def write_calibrated_fmu(rec: Record, d: Diagnosis, fmu: Path, out: Path, report_dir: Path) -> Path:
    """The diagnosis's calibrated FMU, with its provenance: ``resources/calibration.json``
    (:func:`calibration_data`), and the report as ``documentation/`` (``index.html``, the
    self-contained page, plus ``report.md``, the plots and ``diagnosis.json``)."""
    cal = calibration_data(rec, d)
    docs = {"index.html": (report_dir / "report.html").read_bytes()}
    for f in sorted(report_dir.iterdir()):
        if f.suffix in (".md", ".png", ".json") and f.is_file():
            docs[f.name] = f.read_bytes()
    with zipfile.ZipFile(fmu) as z:
        base = z.read("modelDescription.xml")
    from lxml import etree

    cal["guid"] = issued_guid(etree.fromstring(base).get("guid"), d.parameters, cal["record"]["sha256"])
    cal["model_name"] = f"CE152 magnetic levitation, calibrated on {cal['record']['file']}"
    return calibrated_fmu(fmu, out, d.parameters, description=_describe(cal), model_name=cal["model_name"],
                          resources={"calibration.json": (json.dumps(cal, indent=2) + "\n").encode()},
                          documentation=docs, source_sha256=cal["record"]["sha256"])


def _save(plt, fig, path: Path, title: str) -> str:
    """Every figure of the report the same way: its title (what it shows and the model), laid out,
    written to ``path`` at 110 dpi and closed; returns the file's name."""
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _plots(rec: Record, d: Diagnosis, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    before, after = d.sims["before"], d.sims["after"]
    # the model each plot shows: the 'baseline' set (section3 with T_a = 0) calibrated on this record,
    # "after" with the effects found
    model = (f"model: {set_label('baseline')}, calibrated on the record; after: + "
             f"{', '.join(d.selected) or 'no effect'}")

    fig, ax = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    ax[0].plot(rec.t, rec.w, color="0.6", lw=1, label="reference w")
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        ax[k].plot(rec.t, meas, color="k", lw=0.7, label=f"measured {sig}")
        for sim, color, ls, label in ((before, "tab:red", "-", "before"), (after, "tab:blue", "--", "after")):
            ax[k].plot(rec.t, sim[sig], color=color, lw=0.85, ls=ls,
                       label=f"simulated, {label}: fit {nrmse_fit(meas, sim[sig]):.1f} %")
        ax[k].set_ylabel(f"{sig} [MU]")
        ax[k].legend(loc="upper right", fontsize=8, ncol=4)
    ax[1].set_xlabel("t [s]")
    files.append(_save(plt, fig, out / "measured_vs_simulated.png",
                       "Measured versus simulated closed loop (free run; fit = 100·(1 − ‖y − ŷ‖/‖y − mean y‖), "
                       "as MATLAB's compare)\n" + model))

    # zoom on the 0.6 s where the calibrated baseline misses most
    err = np.convolve((rec.u - before["u"]) ** 2, np.ones(300), mode="same")
    c = int(np.argmax(err))
    a, b = max(0, c - 200), min(rec.n, c + 400)
    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        if sig == "y":
            ax[k].plot(rec.t[a:b], rec.w[a:b], color="0.6", lw=1, label="reference w")
        ax[k].plot(rec.t[a:b], meas[a:b], color="k", lw=1, label=f"measured {sig}")
        ax[k].plot(rec.t[a:b], before[sig][a:b], color="tab:red", lw=1, label="simulated, before")
        ax[k].plot(rec.t[a:b], after[sig][a:b], color="tab:blue", lw=1, ls="--", label="simulated, after")
        if d.verdict is not None:
            pred = d.verdict.after.sims[f"{sig}_pred"]
            h = d.verdict.fit["prediction"]["horizon_s"]
            ax[k].plot(rec.t[a:b], pred[a:b], color="tab:green", lw=0.9, ls=":",
                       label=f"predicted {h * 1e3:.0f} ms ahead, after")
        ax[k].set_ylabel(f"{sig} [MU]")
        ax[k].legend(loc="upper right", fontsize=8, ncol=4)
    ax[1].set_xlabel("t [s]")
    files.append(_save(plt, fig, out / "zoom.png", "Zoom where the calibrated baseline misses most" + "\n" + model))

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        ax[k].plot(rec.t, meas - before[sig], color="tab:red", lw=0.6, label="before")
        ax[k].plot(rec.t, meas - after[sig], color="tab:blue", lw=0.6, label="after")
        ax[k].set_ylabel(f"{sig} measured - simulated [MU]")
        ax[k].legend(loc="upper right", fontsize=8)
    ax[1].set_xlabel("t [s]")
    files.append(_save(plt, fig, out / "residual.png", "Residual before and after" + "\n" + model))

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        for sim, color, label in ((before, "tab:red", "before"), (after, "tab:blue", "after")):
            f, p = psd(meas - sim[sig], rec.ts)
            ax[k].loglog(f[1:], p[1:], color=color, lw=0.8, label=label)
        ax[k].set_ylabel(f"{sig} residual PSD [MU²/Hz]")
        ax[k].legend(loc="upper right", fontsize=8)
        ax[k].grid(True, which="both", alpha=0.3)
    ax[1].set_xlabel("frequency [Hz]")
    files.append(_save(plt, fig, out / "spectrum.png",
                       "Power spectral density of the residual (Welch, 2 s Hann segments)" + "\n" + model))

    # MATLAB resid on what the verdict judges: the one-step innovations of the final model's Kalman
    # filter (their predictable share decides `unexplained`), against its past, the reference and
    # the input; the free-run residual is autocorrelated by nature (the loop filters the random force),
    # so a white-noise band says nothing of it: it is in residual.png and spectrum.png.
    fig, ax = plt.subplots(1, 3, figsize=(13, 4.4), sharex=True)
    max_lag = int(round(0.05 / rec.ts))
    if d.verdict is not None:
        innov = d.verdict.after.sims["innov"]
        ok = np.isfinite(innov)
        e = np.where(ok, innov, 0.0)
        r_w = resid(e, rec.w, max_lag=max_lag)
        r_u = resid(e, rec.u, max_lag=max_lag)
        panels = ((r_w.lags, r_w.auto, r_w.band, "autocorrelation", "innovations of y: autocorrelation"),
                  (r_w.lags, r_w.cross, r_w.band, "cross-correlation with w",
                   "innovations of y against the reference w"),
                  (r_u.lags, r_u.cross, r_u.band, "cross-correlation with u",
                   "innovations of y against the input u"))
        for a, (lags, vals, band, ylabel, title) in zip(ax, panels):
            a.vlines(lags * rec.ts * 1e3, 0, vals, color="tab:blue", lw=1)
            a.axhspan(-band, band, color="tab:orange", alpha=0.25,
                      label=f"{100 * r_w.confidence:.0f} % band of a white residual")
            a.axhline(0, color="0.5", lw=0.6)
            a.set_title(title, fontsize=9)
            a.set_ylabel(ylabel)
            a.set_xlabel("lag [ms]")
        ax[0].legend(fontsize=7, loc="upper right")
        share = d.verdict.predictable_share["after"]
        what = (f"one-step innovations of the final model's Kalman filter\n(the residual the verdict judges: "
                f"{100 * share:.1f} % predictable from their past and the input)")
    else:
        for a in ax:
            a.set_axis_off()
        what = "no verdict: no innovations"
    files.append(_save(plt, fig, out / "resid.png",
                       f"Residual analysis of the final model (as MATLAB's resid): {what}" + "\n" + model))
    if d.verdict is not None and d.verdict.corrections:
        files.append(_location_plot(d.verdict.corrections, out, plt, model))
    return files


_SIGNAL_AXIS = {"u": ("controller output u [MU]", 1.0), "x": ("ball position x [mm]", 1e3),
                "y": ("reading y [MU]", 1.0), "F": ("force F [N]", 1.0), "i": ("current i [A]", 1.0),
                "v": ("ball velocity v [mm/s]", 1e3)}


def _friction_text(shape: Mapping) -> str:
    """The mechanics' force of gap and velocity in two figures: its step against the motion at
    v = 0 (F_c of -F_c*tanh(v/v_s)) and its damping."""
    return f"F_c = {shape['coulomb_force_N'] * 1e3:.3g} mN, damping {shape['damping_N_s_per_m']:.3g} N.s/m"


def _location_plot(corrections, out: Path, plt, model: str = "") -> str:
    """The best generic correction at each location: the spline's curve over its signal, or the
    filter's frequency response; its held-out gain in the title."""
    best = best_per_location(corrections)
    # the mechanics' force of gap and velocity, drawn against the velocity: a friction shows as a
    # step at v = 0 (issue 22, item 3), whichever correction is the mechanics' best
    motion = next((c for c in corrections if c.location == "mechanics" and c.form == "state"), None)
    extra = motion is not None and best.get("mechanics") is not motion
    fig, ax = plt.subplots(1, 4 if extra else 3, figsize=(17 if extra else 13, 3.8))
    if extra:
        a = ax[3]
        a.plot(np.asarray(motion.shape["x"]) * 1e3, np.asarray(motion.shape["correction"]) * 1e3, color="tab:red")
        a.axvline(0.0, color="0.6", lw=0.8)
        a.set_xlabel(_SIGNAL_AXIS["v"][0])
        a.set_ylabel("force on the ball at the mean gap [mN]")
        a.set_title(f"mechanics: force of gap and velocity\nremoves {100 * motion.held_out_gain:.1f} %; "
                    + _friction_text(motion.shape), fontsize=9)
        a.grid(alpha=0.3)
    for a, loc in zip(ax, LOCATIONS):
        c = best.get(loc)
        if c is None:
            a.set_axis_off()
            continue
        sh = c.shape
        if sh["kind"] == "curve":
            label, k = _SIGNAL_AXIS[sh["signal"]]
            a.plot(np.asarray(sh["x"]) * k, sh["correction"], color="tab:red")
            a.set_xlabel(label)
            a.set_ylabel(f"correction [{c.unit}]")
        else:
            a.semilogx(sh["f_hz"], sh["phase_deg"], color="tab:red", label="phase [deg]")
            a.set_xlabel("frequency [Hz]")
            a.set_ylabel(f"phase of the filter on {sh['signal']} [deg]")
            b = a.twinx()
            b.semilogx(sh["f_hz"], sh["magnitude"], color="tab:blue")
            b.set_ylabel("gain", color="tab:blue")
        a.set_title(f"{loc}: {c.form} in {c.signal}, removes {100 * c.held_out_gain:.1f} %\nof the held-out "
                    "residual" + ("\n" + _friction_text(sh) if c is motion else ""), fontsize=9)
        if c is motion:
            a.axvline(0.0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
    return _save(plt, fig, out / "location.png", "Where the residual enters: the best generic correction at each "
                 "place in the loop" + ("\n" + model if model else ""))


def _fmt(v: float) -> str:
    return f"{v:.4g}" if isinstance(v, float) and math.isfinite(v) else str(v)


def _verdict_sentence(d: Diagnosis) -> str:
    v = d.verdict.verdict
    if v == "explained":
        return "The calibrated model with " + ", ".join(d.selected) + " explains the record."
    if v == "no effect":
        return "The calibrated baseline already explains the record: no effect of the catalogue is missing."
    if v == "explained in part":
        loc = (d.verdict.noise_floor or {}).get("location") or "undetermined"
        return ("The calibrated model with " + ", ".join(d.selected) + " explains part of the record; its disturbance "
                "estimate explains the rest, which it should not (see the warnings)"
                + ("." if loc == "undetermined" else f": what remains enters most likely at the {loc}."))
    if v == "calibration failed":
        return "The calibration ended on a bound of a parameter's range: the model does not fit this record."
    loc = v.split(":", 1)[1].strip()
    where = "no correction of the catalogue points to a place" if loc == "undetermined" else \
        f"the corrections at the {loc} explain most of what is left"
    return ("Something the catalogue lacks remains after " + (", ".join(d.selected) or "calibration")
            + f": {where}.")


def write_report(rec: Record, d: Diagnosis, out: Path, *, fmu_out: Path | None = None,
                 fmu_refused: bool = False, comparison=None) -> list[Path]:
    """Writes ``report.md``, the plots and ``report.html`` into ``out`` (``diagnosis.json`` and the
    calibrated FMU, :func:`write_calibrated_fmu`, are the engine's: ``fmu_out`` is where it goes,
    ``fmu_refused`` that none is written because the calibration failed; ``comparison``: the model /
    black box / naive table, :class:`~.compare.RecordComparison`); the files written."""
    out.mkdir(parents=True, exist_ok=True)
    pngs = _plots(rec, d, out)

    units = {n: row[3] for n, row in param_table().items()}
    lines = [f"# Diagnosis of `{rec.path}`", ""]
    if d.verdict is not None:
        v = d.verdict
        fr, pr, frb, prb = v.fit["free_run"], v.fit["prediction"], v.fit_before["free_run"], v.fit_before["prediction"]
        h = f"{pr['horizon_s'] * 1e3:.0f} ms"
        lines += [f"**Verdict: {v.verdict}.** " + _verdict_sentence(d), "",
                  "| fit [%] (NRMSE, as MATLAB's compare) | y free run | u free run | "
                  f"y {h} ahead | u {h} ahead |", "|---|---|---|---|---|",
                  f"| calibrated baseline | {frb['y']:.1f} | {frb['u']:.1f} | {prb['y']:.1f} | {prb['u']:.1f} |",
                  f"| final model | {fr['y']:.1f} | {fr['u']:.1f} | {pr['y']:.1f} | {pr['u']:.1f} |", ""]
        lines += [f"The fits minimised the {d.fit_mode} error. The k-step prediction is an extended Kalman filter "
                  "on the C plant that follows the measured past, with the record's own disturbances: a random "
                  f"force of {v.noise.q_force * 1e3:.3g} mN RMS (corner {v.noise.f_force:.3g} Hz) and a sensor "
                  f"noise of {v.noise.r_sensor:.3g} MU RMS" + (f" white and {v.noise.r_coloured:.3g} MU RMS coloured "
                  f"(corner {v.noise.f_sensor:.3g} Hz)" if v.noise.coloured else "") + ", estimated from the innovations. What the final model "
                  f"leaves in the innovations is {100 * v.predictable_share['after']:.1f} % predictable (baseline: "
                  f"{100 * v.predictable_share['before']:.1f} %)."]
        rule = v.noise_floor or {}
        fl, rs = rule.get("floor"), rule.get("reference_share")
        if fl and rs:
            lines[-1] += (f" Against the floor its own disturbance model implies (docs/diagnosis.md, the noise-floor "
                          f"rule): its {fl['horizon_s'] * 1e3:.0f} ms prediction error is {fl['ratio_y']:.2f} (y) and "
                          f"{fl['ratio_u']:.2f} (u) times what it leaves on records it simulates itself; the reference's "
                          f"past and the ball's motion predict {100 * rs['r2']:.2f} % of its innovations "
                          f"({100 * rs.get('own_records_r2', 0.0):.2f} % on its own records); its random force is "
                          f"{rule['force_growth']:.2f} times the calibrated baseline's.")
        lines.append("")
    if d.warnings:
        lines += ["**Warnings**:", ""] + [f"- {w}" for w in d.warnings] + [""]
    ctrl = (f"controller {type(rec.controller).__name__} declared by `{rec.controller_file}`"
            if rec.controller is not None else f"PID kp = {rec.kp}, ki = {rec.ki}, kd = {rec.kd}"
            + (f", derivative filter tf = {rec.tf * 1e3:.3g} ms" if rec.tf else "")
            + (", derivative of the reading alone" if rec.derivative == "measurement" else "")
            + (f", anti-windup {rec.anti_windup}" if rec.anti_windup != "none" else ""))
    lines += [f"Record: {rec.n} samples at ts = {rec.ts} s ({rec.duration:.2f} s); {ctrl}, "
              f"output limits [{rec.u_min}, {rec.u_max}] MU.", ""]
    lines += ["## Result", ""]
    if d.selected:
        lines.append("Effects the baseline lacks, in the order they were found: "
                     + ", ".join(f"**{e}** ({CATALOGUE[e].description})" for e in d.selected) + ".")
    else:
        lines.append("No effect of the catalogue was selected: none explains the held-out residual better than "
                     "noise does (whether that means the baseline suffices is the verdict above).")
    fits = {k: (nrmse_fit(rec.y, d.sims[k]["y"]), nrmse_fit(rec.u, d.sims[k]["u"])) for k in ("before", "after")}
    lines += ["", "| | rms_y [MU] | rms_u [MU] | fit y [%] | fit u [%] |", "|---|---|---|---|---|",
              f"| before (calibrated baseline) | {d.before['rms_y']:.6f} | {d.before['rms_u']:.6f} "
              f"| {fits['before'][0]:.1f} | {fits['before'][1]:.1f} |",
              f"| after (final model) | {d.after['rms_y']:.6f} | {d.after['rms_u']:.6f} "
              f"| {fits['after'][0]:.1f} | {fits['after'][1]:.1f} |",
              f"| noise floor estimate | {d.noise['sigma_y']:.6f} | {d.noise['rms_u_from_sensor_noise']:.6f} | | |", ""]
    lines += ["Fit: free-run NRMSE fit as MATLAB's compare defines it, 100·(1 − ‖y − ŷ‖/‖y − mean y‖). "
              "RMS over the whole record of measured minus simulated. The noise floor is estimated from the "
              "record itself (white part of the reading from its second differences, and the PID's response "
              "to it); random forces on the ball add to what noise leaves in y.", ""]
    if d.unexplained.get("note"):
        lines += [f"Note: {d.unexplained['note']}.", ""]
    if d.verdict is not None and d.verdict.corrections:
        lines += ["### Where the residual enters", "",
                  "A generic correction of the final model at each place in the loop (a cubic spline of the "
                  "local signal, or a low-order filter of it), fitted on the fit blocks and judged on the "
                  "held-out ones (`location.png` shows the best at each place):", "",
                  "| location | form | signal | held-out residual removed | on the fit blocks |", "|---|---|---|---|---|"]
        for c in d.verdict.corrections:
            lines.append(f"| {c.location} | {c.form} | {c.signal} | {100 * c.held_out_gain:.1f} % | "
                         f"{100 * c.fit_gain:.1f} % |")
        lines.append("")
    if comparison is not None:
        lines += ["### Prediction: the model against a black box", "",
                  "Skill against \"stays put\" of the reading predicted 5, 20 and 50 ms ahead (> 0: better; 1: "
                  "exact), on the blocks no fit saw and on the fit blocks. The model in closed loop runs the final "
                  "model with the record's controller from each sample on, driven by the reference alone; driven "
                  "by u, it takes the recorded actuator signal up to the predicted instant, as the black box (a "
                  "ridge regression per horizon on the last 30 ms of readings and on u and u² up to the "
                  "predicted instant, fitted on the fit blocks) does. That signal holds the controller's "
                  "reaction to what moved the ball meanwhile, which a direct regression reads and the physics "
                  "driven by it cannot (docs/diagnosis.md, \"Model against black box\").", "",
                  *comparison.table(), ""]
    if d.selected:
        lines += ["### Estimated effect parameters (±1 standard error)", "", "| parameter | value | ± | unit |",
                  "|---|---|---|---|"]
        for e in d.selected:
            for p in CATALOGUE[e].params:
                lines.append(f"| {p} | {_fmt(d.parameters[p])} | {_fmt(d.uncertainties.get(p, float('nan')))} "
                             f"| {units[p]} |")
        lines.append("")
    paper = baseline_params()
    # the calibrated baseline's values (the "before" model: diagnosis.json's calibrated_baseline),
    # then the final model's, refitted with the effects, with their standard errors
    lines += ["### Calibrated baseline parameters", "",
              "The `baseline` set calibrated on the record, before any effect (the \"before\" model; "
              "`calibrated_baseline` in diagnosis.json):", "",
              "| parameter | calibrated baseline | Section 3 | unit |", "|---|---|---|---|"]
    for name in ("k_c", "x_0", "k_FV", "u_0"):
        lines.append(f"| {name} | {_fmt(float(d.calibrated_baseline[name]))} | {_fmt(paper[name])} | {units[name]} |")
    lines += ["", "### Final model's calibrated parameters", "",
              "The same parameters of the final model (" + (", ".join(d.selected) or "no effect")
              + "), refitted on the whole record (`parameters` in diagnosis.json; ±1 standard error):", "",
              "| parameter | final model | ± | calibrated baseline | unit |", "|---|---|---|---|---|"]
    for name in ("k_c", "x_0", "k_FV", "u_0"):
        lines.append(f"| {name} | {_fmt(d.parameters[name])} | {_fmt(d.uncertainties.get(name, float('nan')))} "
                     f"| {_fmt(float(d.calibrated_baseline[name]))} | {units[name]} |")
    lines += ["", "The A/D offset y_MU0 is not calibrated: in a regulated loop it shifts the picture exactly "
              "as x_0 does.", ""]
    lines += ["## Candidates", "", "| round | effect | parameters | rms_y [MU] | rms_u [MU] | held-out cost change | LR stat | "
              "threshold | accepted |", "|---|---|---|---|---|---|---|---|---|"]
    for c in d.candidates:
        par = ", ".join(f"{k} = {_fmt(v)} {units[k]}" for k, v in c["parameters"].items())
        par += "".join(f" ({k} refitted beside it to {_fmt(v)} {units[k]})" for k, v in c.get("joint", {}).items())
        if c.get("stage") == "screen":
            par += " (screened: fit stopped early)"
        elif c.get("stage") == "gradient screen":
            par += " (one Gauss-Newton step: its gradient promised too little to fit)"
        lines.append(f"| {c['round']} | {c['effect']} | {par} | {c['rms_y']:.6f} | {c['rms_u']:.6f} | "
                     f"{-100 * c['held_out_gain']:+.1f} % | {c['lr_statistic']:.1f} | {c['threshold']:.1f} | "
                     f"{'**yes**' if c.get('selected') else ('yes' if c['accepted'] else 'no')} |")
    lines += ["", f"**Criterion.** {CRITERION}", "",
              "Every candidate is first screened: fitted with a few least-squares evaluations only. Those whose "
              "held-out likelihood ratio reaches half its threshold are fitted to convergence and judged again; "
              "the others are marked *screened*. From the second round on, an effect the baseline cannot absorb "
              "is screened by one Gauss-Newton step first, and fitted only where that step promises a quarter "
              "of its threshold or more.", ""]
    rb = d.residual_before
    lines += ["## Residual of the calibrated baseline", "",
              f"- RMS: y {rb['rms_y']:.6f} MU, u {rb['rms_u']:.6f} MU; mean: y {rb['mean_y']:+.6f}, u {rb['mean_u']:+.6f}",
              "- spectral peaks in u: " + (", ".join(f"{p['f']:.2f} Hz ({p['amplitude']:.2e} MU, ×{p['prominence']:.0f})"
                                                    for p in rb["peaks_u"][:3]) or "none"),
              f"- whiteness: {100 * rb['whiteness']['fraction_of_lags_outside_95pct_u']:.0f} % of the first 50 "
              f"autocorrelation lags of the u residual lie outside the 95 % band of white noise "
              f"(y: {100 * rb['whiteness']['fraction_of_lags_outside_95pct_y']:.0f} %)",
              "- correlation of the u residual with the reference "
              f"{rb['correlation']['u_error_vs_reference']:+.2f}, the input {rb['correlation']['u_error_vs_input']:+.2f}, "
              f"the operating point {rb['correlation']['u_error_vs_operating_point']:+.2f}",
              ]
    st = rb["around_steps"]
    if st["steps"] and st["rms_u_near_steps"] is not None and st["rms_u_elsewhere"] is not None:
        lines.append(f"- around the {st['steps']} reference steps (0.3 s after each) the u residual RMS is "
                     f"{st['rms_u_near_steps']:.5f} MU against {st['rms_u_elsewhere']:.5f} MU elsewhere")
    lines += ["", "## Plots", ""]
    for p in pngs:
        lines += [f"![{p}]({p})", ""]
    if fmu_refused:
        lines += ["## Calibrated FMU", "", "None written: the calibration failed, so its parameters are not a model "
                  "of the rig.", ""]
    if fmu_out is not None:
        lines += ["## Calibrated FMU", "",
                  "`maglev_calibrated.fmu` is the plant FMU with the final parameters as start values: drop it "
                  "into any FMI 2.0 tool. It is a model of its own (its own GUID and model name); it carries "
                  "this report as `documentation/index.html` and `resources/calibration.json` (parameters, "
                  "±σ, fit figures, the sha256 of the record).", ""]
    lines += [f"Diagnosis took {d.elapsed:.1f} s. Machine-readable: `diagnosis.json`.", ""]
    (out / "report.md").write_text("\n".join(lines))
    return [out / "report.md", write_html(out / "report.md", out / "report.html"), *(out / p for p in pngs)]
