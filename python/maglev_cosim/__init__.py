"""maglev-cosim: the Humusoft CE152 magnetic levitation rig as an FMI 2.0 co-simulation FMU.

Units follow the paper: positions in m, velocities in m/s, currents in A, voltages in V,
converter values in machine units (MU, ±1 full range), times in s.

The public API is importable from here; each name loads its module on first use, so that
``import maglev_cosim`` stays cheap. :func:`fmu_path` is the installed plant FMU (or
``$MAGLEV_FMU`` when set).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module that defines it
_API = {
    "PlantParams": "plant.params", "get_params": "plant.params", "as_params": "plant.params",
    "PID": "loop.pid",
    "simulate": "loop.simulate", "LoopResponse": "loop.simulate", "reference_signal": "loop.simulate",
    "linearize": "plant.linear", "transfer_function": "plant.linear", "operating_point": "plant.linear",
    "discrete_closed_loop": "loop.design", "closed_loop_report": "loop.design",
    "FmuPlant": "loop.fmu", "FmuError": "loop.fmu",
    "Record": "records.record", "RecordError": "records.record", "read_record": "records.record",
    "write_record": "records.record", "load": "records.load", "Recording": "records.load",
    "diagnose": "diagnosis", "DiagnosisResult": "diagnosis", "CATALOGUE": "diagnosis",
    "nrmse_fit": "diagnosis.metrics", "resid": "diagnosis.metrics",
    "fmu_path": "_resources",
}

__all__ = sorted(_API) + ["__version__"]

if TYPE_CHECKING:
    from .loop.design import closed_loop_report, discrete_closed_loop
    from .diagnosis import CATALOGUE, DiagnosisResult, diagnose
    from .records.load import Recording, load
    from .loop.fmu import FmuError, FmuPlant
    from .plant.linear import linearize, operating_point, transfer_function
    from .loop.simulate import LoopResponse, reference_signal, simulate
    from .diagnosis.metrics import nrmse_fit, resid
    from .plant.params import PlantParams, as_params, get_params
    from ._resources import fmu_path
    from .loop.pid import PID
    from .records.record import Record, RecordError, read_record, write_record


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'maglev_cosim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return __all__
