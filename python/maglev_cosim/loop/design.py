"""The paper's controller design checked with python-control (Section 4, Fig. 16–19).

The linear plant of Eq. 19 is discretised with a zero-order hold at ``T_s`` (the D/A holds the
output), closed with the discrete PID of Eq. 24/25 in a unity feedback loop, and analysed:
closed-loop poles, ``step_info``, bandwidth, root locus of the continuous design (Fig. 16/17),
closed-loop Bode magnitude (Fig. 18).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# Imported inside functions, on purpose: matplotlib (heavy, only the plots) and python-control (which
# loads matplotlib.pyplot: half a second that a diagnosis, which needs neither, need not pay).
from ..plant.linear import linearize
from ..plant.params import PlantParams, set_label
from .pid import PID, pid_continuous_tf, pid_tf

if TYPE_CHECKING:
    import control


def discrete_plant(p: PlantParams, x_op: float, ts: float, i: float | None = None) -> control.TransferFunction:
    """Eq. 19 at ``x_op`` [m], ZOH-discretised at ``ts`` [s]."""
    import control

    return control.ss2tf(control.sample_system(linearize(p, x_op, i), ts, method="zoh"))


def discrete_closed_loop(p: PlantParams, x_op: float = 0.0032, cfg: PID | None = None,
                         i: float | None = None) -> control.TransferFunction:
    """Reference-to-position closed loop ``C(z)G(z)/(1 + C(z)G(z))`` [MU/MU]."""
    import control

    cfg = cfg or PID()
    return control.feedback(pid_tf(cfg) * discrete_plant(p, x_op, cfg.ts, i), 1)


def bandwidth_hz(sys: control.TransferFunction, *, db: float = -3.0) -> float:
    """First frequency [Hz] above which |T| stays below its DC gain by ``db`` dB (frequency grid up
    to Nyquist for a discrete system)."""
    fmax = 0.5 / sys.dt if sys.dt else 1e4
    f = np.logspace(-2, np.log10(fmax * 0.999), 4000)
    mag = np.abs(sys(np.exp(2j * np.pi * f * sys.dt)) if sys.dt else sys(2j * np.pi * f)).ravel()
    dc = abs(complex(sys.dcgain()))
    below = mag < dc * 10 ** (db / 20)
    # the last crossing from above to below: the loop is peaky before it rolls off
    idx = np.nonzero(~below)[0]
    if len(idx) == 0:
        return float(f[0])
    k = idx[-1]
    return float(f[min(k + 1, len(f) - 1)])


def closed_loop_report(p: PlantParams, x_op: float = 0.0032, cfg: PID | None = None,
                       i: float | None = None) -> dict:
    """Closed-loop poles, stability, step_info and bandwidth of the linear discrete loop, with
    the paper's statements beside them (stable loop, bandwidth about 50 Hz, PID zeros −200, −1.5)."""
    import control

    cfg = cfg or PID()
    T = discrete_closed_loop(p, x_op, cfg, i)
    poles = np.asarray(T.poles())
    info = control.step_info(T)
    zeros_c = np.sort(np.real(np.roots([cfg.kd, cfg.kp, cfg.ki])))
    bw = bandwidth_hz(T)
    return {
        "operating_point": x_op,
        "closed_loop_poles": poles,
        "max_pole_magnitude": float(np.max(np.abs(poles))),
        "stable": bool(np.all(np.abs(poles) < 1.0)),
        "step_info": {k: float(v) for k, v in info.items()},
        "bandwidth_hz": bw,
        "pid_zeros": zeros_c.tolist(),
        "paper": {"stable": True, "bandwidth_hz": 50.0, "pid_zeros": [-200.0, -1.5], "ts": 1e-3},
    }


def root_locus_branches(p: PlantParams, x_op: float, cfg: PID, gains: np.ndarray) -> np.ndarray:
    """Closed-loop poles of ``1 + K·C0(s)·H(s)`` for each ``K``, where ``C0 = C/K_p`` is the PID with
    its gain normalised (zeros fixed at the design's, Eq. 21)."""
    import control

    L0 = pid_continuous_tf(1.0, cfg.ki / cfg.kp, cfg.kd / cfg.kp) * control.ss2tf(linearize(p, x_op))
    num = np.asarray(L0.num[0][0], float)
    den = np.asarray(L0.den[0][0], float)
    n = max(len(num), len(den))
    num = np.pad(num, (n - len(num), 0))
    den = np.pad(den, (n - len(den), 0))
    return np.array([np.sort_complex(np.roots(den + K * num)) for K in gains])


def plot_root_locus(p: PlantParams, x_op: float, cfg: PID, path: str | Path, *, params_label: str | None = None) -> Path:
    """Root locus of the continuous design (Fig. 16/17) with the chosen gain K = K_p marked: the
    whole locus, and beside it a zoom on the cluster at the origin (the integrator's pole, the PID's
    slow zero and the slow closed-loop pole, a few 1/s apart where the whole plot spans hundreds).
    The title names the parameter set (``params_label``, default :func:`~.params.set_label`)."""
    import control

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    gains = np.logspace(-3, 2, 600)
    br = root_locus_branches(p, x_op, cfg, gains)
    chosen = root_locus_branches(p, x_op, cfg, np.array([cfg.kp]))[0]
    ol = np.append(np.asarray(control.ss2tf(linearize(p, x_op)).poles()), 0.0)   # plant and integrator
    z = np.roots([cfg.kd, cfg.kp, cfg.ki])
    # the zoom: around the poles and zeros within 10 1/s of the origin, with a margin
    near = np.concatenate([ol, z, chosen])
    near = near[np.abs(near) < 10.0]
    half = max(1.0, 1.5 * float(np.max(np.abs(near.real - near.real.mean())))) if len(near) else 5.0
    cx = float(near.real.mean()) if len(near) else 0.0
    zoom = (cx - half, cx + half, -half, half)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={"width_ratios": [1.35, 1]})
    for ax in axes:
        for k in range(br.shape[1]):
            ax.plot(br[:, k].real, br[:, k].imag, ".", ms=1.5, color="tab:blue")
        ax.plot(ol.real, ol.imag, "x", color="k", ms=9, label="open-loop poles (Eq. 19 and the integrator)")
        ax.plot(z.real, z.imag, "o", mfc="none", color="k", ms=8, label="PID zeros (Eq. 21)")
        ax.plot(chosen.real, chosen.imag, "s", color="tab:red", ms=7, label=f"closed loop, K = {cfg.kp}")
        ax.axvline(0, color="0.7", lw=0.8)
        ax.axhline(0, color="0.85", lw=0.6)
        ax.set_xlabel("Re s [1/s]")
        ax.set_ylabel("Im s [1/s]")
    full, zax = axes
    full.set_xlim(-450, 150)
    full.set_ylim(-300, 300)
    full.add_patch(Rectangle((zoom[0], zoom[2]), zoom[1] - zoom[0], zoom[3] - zoom[2], fill=False,
                             ec="tab:orange", lw=1.2))
    full.annotate("zoomed at right", xy=(zoom[1], zoom[3]), xytext=(30, 60), textcoords="offset points",
                  color="tab:orange", fontsize=8, arrowprops={"arrowstyle": "-", "color": "tab:orange"})
    full.set_title("whole locus", fontsize=10)
    full.legend(fontsize=8, loc="lower left")
    zax.set_xlim(zoom[0], zoom[1])
    zax.set_ylim(zoom[2], zoom[3])
    for s in zax.spines.values():
        s.set_edgecolor("tab:orange")
    for v in near:
        if v.imag >= 0:
            zax.annotate(f"{v.real:.2f}", xy=(v.real, v.imag), xytext=(0, 10), textcoords="offset points",
                         ha="center", fontsize=8)
    zax.set_title("zoom on the origin: integrator pole,\nslow PID zero, slow closed-loop pole", fontsize=10)
    label = params_label or set_label(p)
    fig.suptitle(f"Root locus of the PID design at x = {x_op * 1e3:.1f} mm (Fig. 16/17), {label}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_closed_loop_bode(p: PlantParams, x_op: float, cfg: PID, path: str | Path, *,
                          params_label: str | None = None) -> Path:
    """Bode plot of the discrete closed loop, reference to position: magnitude with the −3 dB
    bandwidth marked (Fig. 18) and phase, up to the Nyquist frequency. The title names the
    parameter set (``params_label``, default :func:`~.params.set_label`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = discrete_closed_loop(p, x_op, cfg)
    f = np.logspace(-1, np.log10(0.5 / cfg.ts * 0.999), 2000)
    resp = np.asarray(T(np.exp(2j * np.pi * f * cfg.ts))).ravel()
    bw = bandwidth_hz(T)
    fig, ax = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    ax[0].semilogx(f, 20 * np.log10(np.abs(resp)), color="tab:blue")
    ax[0].axhline(-3, color="0.6", ls="--", lw=0.8)
    ax[0].axvline(bw, color="tab:red", ls=":", label=f"bandwidth {bw:.1f} Hz (paper: about 50 Hz)")
    ax[0].set_ylabel("|T| [dB]")
    ax[0].set_title(f"Closed loop, reference to position (Fig. 18), x = {x_op * 1e3:.1f} mm\n"
                    f"{params_label or set_label(p)}", fontsize=10)
    ax[0].legend(fontsize=8)
    ax[1].semilogx(f, np.degrees(np.unwrap(np.angle(resp))), color="tab:blue")
    ax[1].axvline(bw, color="tab:red", ls=":")
    ax[1].set_ylabel("phase [deg]")
    ax[1].set_xlabel("frequency [Hz]")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)

