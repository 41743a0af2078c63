"""Writing what the diagnosis found: ``diagnosis.json``, ``report.md`` with PNG plots, and
``maglev_calibrated.fmu`` (the FMU with the final parameters as start values)."""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .diagnose import CATALOGUE, CRITERION, Diagnosis, spectrum
from .record import Record


def calibrated_fmu(source: Path, out: Path, parameters: Mapping[str, float]) -> Path:
    """A copy of the FMU ``source`` whose parameter start values are ``parameters``."""
    from lxml import etree

    with zipfile.ZipFile(source) as zin:
        root = etree.fromstring(zin.read("modelDescription.xml"))
        for sv in root.iter("ScalarVariable"):
            name = sv.get("name")
            if name in parameters and sv.get("causality") == "parameter":
                real = sv.find("Real")
                real.set("start", repr(float(parameters[name])))
        xml = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
            for item in zin.infolist():
                data = xml if item.filename == "modelDescription.xml" else zin.read(item.filename)
                zout.writestr(item, data)
    return out


def _plots(rec: Record, d: Diagnosis, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    before, after = d.sims["before"], d.sims["after"]

    fig, ax = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    ax[0].plot(rec.t, rec.w, color="0.6", lw=1, label="reference w")
    ax[0].plot(rec.t, rec.y, color="k", lw=0.8, label="measured y")
    ax[0].plot(rec.t, before["y"], color="tab:red", lw=0.9, label="simulated, before")
    ax[0].plot(rec.t, after["y"], color="tab:blue", lw=0.9, ls="--", label="simulated, after")
    ax[0].set_ylabel("y [MU]")
    ax[0].legend(loc="upper right", fontsize=8, ncol=4)
    ax[1].plot(rec.t, rec.u, color="k", lw=0.6, label="measured u")
    ax[1].plot(rec.t, before["u"], color="tab:red", lw=0.8, label="simulated, before")
    ax[1].plot(rec.t, after["u"], color="tab:blue", lw=0.8, ls="--", label="simulated, after")
    ax[1].set_ylabel("u [MU]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(loc="upper right", fontsize=8, ncol=3)
    fig.suptitle("Measured versus simulated closed loop")
    fig.tight_layout()
    fig.savefig(out / "measured_vs_simulated.png", dpi=110)
    plt.close(fig)
    files.append("measured_vs_simulated.png")

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
        ax[k].set_ylabel(f"{sig} [MU]")
        ax[k].legend(loc="upper right", fontsize=8, ncol=4)
    ax[1].set_xlabel("t [s]")
    fig.suptitle("Zoom where the calibrated baseline misses most")
    fig.tight_layout()
    fig.savefig(out / "zoom.png", dpi=110)
    plt.close(fig)
    files.append("zoom.png")

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        ax[k].plot(rec.t, meas - before[sig], color="tab:red", lw=0.6, label="before")
        ax[k].plot(rec.t, meas - after[sig], color="tab:blue", lw=0.6, label="after")
        ax[k].set_ylabel(f"{sig} measured - simulated [MU]")
        ax[k].legend(loc="upper right", fontsize=8)
    ax[1].set_xlabel("t [s]")
    fig.suptitle("Residual before and after")
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=110)
    plt.close(fig)
    files.append("residual.png")

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (sig, meas) in enumerate((("y", rec.y), ("u", rec.u))):
        for sim, color, label in ((before, "tab:red", "before"), (after, "tab:blue", "after")):
            f, a = spectrum(meas - sim[sig], rec.ts)
            ax[k].semilogy(f[1:], a[1:] + 1e-12, color=color, lw=0.7, label=label)
        ax[k].set_ylabel(f"|{sig} residual| [MU]")
        ax[k].legend(loc="upper right", fontsize=8)
    ax[1].set_xlabel("frequency [Hz]")
    ax[1].set_xlim(0, 0.5 / rec.ts)
    fig.suptitle("Amplitude spectrum of the residual")
    fig.tight_layout()
    fig.savefig(out / "spectrum.png", dpi=110)
    plt.close(fig)
    files.append("spectrum.png")
    return files


def _fmt(v: float) -> str:
    return f"{v:.4g}" if isinstance(v, float) and math.isfinite(v) else str(v)


def write_report(rec: Record, d: Diagnosis, out: Path, *, fmu: Path | None = None) -> dict[str, Path]:
    """Writes ``diagnosis.json``, ``report.md``, the plots and (given the FMU) ``maglev_calibrated.fmu``."""
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    data = d.to_json()
    (out / "diagnosis.json").write_text(json.dumps(data, indent=2, default=float))
    written["json"] = out / "diagnosis.json"
    pngs = _plots(rec, d, out)
    if fmu is not None:
        written["fmu"] = calibrated_fmu(fmu, out / "maglev_calibrated.fmu", d.parameters)

    lines = [f"# Diagnosis of `{rec.path}`", ""]
    lines += [f"Record: {rec.n} samples at ts = {rec.ts} s ({rec.duration:.2f} s); PID kp = {rec.kp}, "
              f"ki = {rec.ki}, kd = {rec.kd}, output limits [{rec.u_min}, {rec.u_max}] MU.", ""]
    lines += ["## Result", ""]
    if d.selected:
        lines.append("Effects the baseline lacks, in the order they were found: "
                     + ", ".join(f"**{e}** ({CATALOGUE[e].description})" for e in d.selected) + ".")
    else:
        lines.append("**No effect selected**: after calibration no effect of the catalogue explains the "
                     "residual better than noise does.")
    lines += ["", "| | rms_y [MU] | rms_u [MU] |", "|---|---|---|",
              f"| before (calibrated baseline) | {d.before['rms_y']:.6f} | {d.before['rms_u']:.6f} |",
              f"| after (final model) | {d.after['rms_y']:.6f} | {d.after['rms_u']:.6f} |",
              f"| noise floor estimate | {d.noise['sigma_y']:.6f} | {d.noise['rms_u_from_sensor_noise']:.6f} |", ""]
    lines += ["RMS over the whole record of measured minus simulated. The noise floor is estimated from the "
              "record itself (white part of the reading from its second differences, and the PID's response "
              "to it); random forces on the ball add to what noise leaves in y.", ""]
    if d.unexplained.get("note"):
        lines += [f"Note: {d.unexplained['note']}.", ""]
    if d.selected:
        lines += ["### Estimated effect parameters (±1 standard error)", "", "| parameter | value | ± |", "|---|---|---|"]
        for e in d.selected:
            for p in CATALOGUE[e].params:
                lines.append(f"| {p} | {_fmt(d.parameters[p])} | {_fmt(d.uncertainties.get(p, float('nan')))} |")
        lines.append("")
    lines += ["### Calibrated baseline parameters", "", "| parameter | value | ± | Section 3 |", "|---|---|---|---|"]
    from .replay import baseline_params

    paper = baseline_params()
    for name in ("k_c", "x_0", "k_FV", "u_0"):
        lines.append(f"| {name} | {_fmt(d.parameters[name])} | {_fmt(d.uncertainties.get(name, float('nan')))} "
                     f"| {_fmt(paper[name])} |")
    lines += ["", "The A/D offset y_MU0 is not calibrated: in a regulated loop it shifts the picture exactly "
              "as x_0 does.", ""]
    lines += ["## Candidates", "", "| round | effect | parameters | rms_y | rms_u | held-out change | LR stat | "
              "threshold | accepted |", "|---|---|---|---|---|---|---|---|---|"]
    for c in d.candidates:
        par = ", ".join(f"{k} = {_fmt(v)}" for k, v in c["parameters"].items())
        lines.append(f"| {c['round']} | {c['effect']} | {par} | {c['rms_y']:.6f} | {c['rms_u']:.6f} | "
                     f"{-100 * c['held_out_gain']:+.1f} % | {c['lr_statistic']:.1f} | {c['threshold']:.1f} | "
                     f"{'**yes**' if c.get('selected') else ('yes' if c['accepted'] else 'no')} |")
    lines += ["", f"**Criterion.** {CRITERION}", ""]
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
    if "fmu" in written:
        lines += ["## Calibrated FMU", "",
                  "`maglev_calibrated.fmu` is the plant FMU with the final parameters as start values: drop it "
                  "into any FMI 2.0 tool.", ""]
    lines += [f"Diagnosis took {d.elapsed:.1f} s. Machine-readable: `diagnosis.json`.", ""]
    (out / "report.md").write_text("\n".join(lines))
    written["report"] = out / "report.md"
    return written
