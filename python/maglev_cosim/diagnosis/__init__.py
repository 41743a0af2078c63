"""Closing the loop with measured data: replay, calibrate, find the residual, trace it to the
effect the model lacks, add it, and report the error before and after.

- :mod:`.effects`: the catalogue; each effect owns its fit coordinates, starts and transforms;
- :mod:`.problem`: the fit problem and least squares over parameterizations;
- :mod:`.residual`: describing a residual, and the noise floor of a record;
- :mod:`.acceptance`: the held-out likelihood-ratio test;
- :mod:`.verdict`: free-run and k-step prediction fits, the innovations' predictable share, the verdict;
- :mod:`.engine`: :func:`diagnose`, the one entry point for every record (CE152 or a real rig's);
- :mod:`.result`: :class:`DiagnosisResult`, what it returns, typed, with ``to_json`` (``diagnosis.json``);
- :mod:`.pipeline`: a CE152 record's stages (closed-loop replay with its declared controller);
- :mod:`.ce152_report`: a CE152 record's figures, report and calibrated FMU;
- :mod:`.replay`: a record replayed through the model (the loop the record ran, its noise);
- :mod:`.metrics`: fit figures (NRMSE, residuals, spectra);
- :mod:`.identify`: the paper's static identification (Eq. 14, the simplex fit);
- :mod:`.real_rig`: a real rig's stages: prediction from the measured actuator signal, calibration,
  validation, the black-box comparison, its report;
- :mod:`.blackbox`, :mod:`.locate`: the black-box benchmark models; where in the loop a residual comes from.
"""

from .acceptance import CRITERION, accept
from .effects import BASELINE, CATALOGUE, Effect
from .engine import diagnose
from .pipeline import Diagnosis
from .result import DiagnosisResult

__all__ = ["BASELINE", "CATALOGUE", "CRITERION", "Diagnosis", "DiagnosisResult", "Effect", "accept", "diagnose"]
