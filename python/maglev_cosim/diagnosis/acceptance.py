"""When an effect is accepted: a likelihood-ratio test on held-out blocks, corrected for the
residual's autocorrelation, and a smallest worthwhile reduction."""

from __future__ import annotations

import math

import numpy as np

from .metrics import chi2_quantile

BLOCK = 0.8                  # [s] alternating fit / held-out blocks
ALPHA = 1e-3                 # false-acceptance probability of the likelihood-ratio test
MIN_GAIN = 0.03              # smallest held-out cost reduction worth an effect (3 %)


def fit_blocks(t: np.ndarray) -> np.ndarray:
    """Which samples (times ``t`` [s]) lie in the fit blocks: the even ``BLOCK``-long blocks from
    t = 0; the odd ones are held out."""
    return (np.floor(np.asarray(t) / BLOCK).astype(int) % 2) == 0


def accept(cost_before: float, cost_after: float, n_eff: float, n_params: int) -> tuple[bool, dict]:
    """The acceptance criterion, applied to the held-out blocks.

    An effect with ``p`` parameters is accepted when (1) the likelihood-ratio statistic
    ``N_eff·ln(J_before/J_after)`` exceeds the χ²(p) quantile at 1 − α (α = 0.001), where
    ``N_eff`` is the held-out residual's effective number of independent samples (corrected for
    autocorrelation, :func:`effective_samples`), so a reduction that noise explains is rejected
    with probability 0.999; and (2) the held-out cost falls by at least 3 %.
    """
    gain = 1.0 - cost_after / cost_before if cost_before > 0 else 0.0
    ratio = cost_before / cost_after if cost_after > 0 else math.inf
    # a cost after that is infinite (a replay that diverged) or not a number is a rejection, not a
    # math domain error
    stat = n_eff * math.log(ratio) if ratio > 0 else -math.inf
    threshold = float(chi2_quantile(1 - ALPHA, n_params))
    ok = bool(stat > threshold and gain >= MIN_GAIN)
    return ok, {"lr_statistic": float(stat), "threshold": threshold, "held_out_gain": float(gain),
                "n_eff": float(n_eff)}


def accept_nll(nll_before: float, nll_after: float, n_eff: float, n_params: int) -> tuple[bool, dict]:
    """:func:`accept` on two models' held-out mean negative log-likelihoods per sample (a filter's
    ``log s + e²/s``: the costs ``exp(NLL)``), taken as their difference: a filter that a record's
    model fits badly reaches a mean NLL of hundreds, whose exp alone overflows (on the project
    emulator's current limit of seed 5401, benchmark seeds 5400, a cost ratio of 0 ended the
    diagnosis in a math domain error). An NLL that is not finite is not accepted."""
    if not (math.isfinite(nll_before) and math.isfinite(nll_after)):
        return False, {"lr_statistic": -math.inf, "threshold": float(chi2_quantile(1 - ALPHA, n_params)),
                       "held_out_gain": -math.inf, "n_eff": float(n_eff)}
    # exp(700) is finite: a difference beyond it is a rejection in any case
    return accept(1.0, math.exp(min(nll_after - nll_before, 700.0)), n_eff, n_params)


CRITERION = (f"An effect is accepted when, on the held-out blocks (alternating {BLOCK} s blocks not used "
             f"for fitting), the likelihood-ratio statistic N_eff*ln(J_before/J_after) exceeds the "
             f"chi-square quantile with p degrees of freedom at 1 - {ALPHA} (p = the effect's parameter "
             f"count; N_eff = held-out samples corrected for the residual's autocorrelation), and the "
             f"held-out cost J (mean squared residual of y and u, each divided by the calibrated "
             f"baseline's RMS) falls by at least {MIN_GAIN:.0%}. Among accepted effects the one with the "
             f"largest held-out reduction is added, and the search repeats on the new residual.")
