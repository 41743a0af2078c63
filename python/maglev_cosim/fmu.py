"""Finding and driving the plant FMU (the installed ``maglev_cosim/_data/maglev.fmu``) through fmpy.

:class:`FmuPlant` is a thin, fast wrapper over fmpy's ``FMU2Slave``: value references are
looked up once from ``modelDescription.xml``, and ``fmi2SetReal``/``fmi2GetReal`` are called
with preallocated ctypes arrays, so a closed loop at 1 kHz costs a few microseconds a step.
"""

from __future__ import annotations

import atexit
import ctypes
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

from ._resources import ResourceError, fmu_path

#: Output variables read after every step, in this order.
OUTPUTS: tuple[str, ...] = ("y", "x", "v", "i")


class FmuError(RuntimeError):
    """The FMU is missing or an FMI call failed."""


def default_fmu_path() -> Path:
    """``$MAGLEV_FMU`` if set, else the installed FMU (see :func:`maglev_cosim.fmu_path`)."""
    try:
        return fmu_path()
    except ResourceError as exc:
        raise FmuError(str(exc)) from None


def ensure_fmu(path: str | Path | None = None) -> Path:
    """The FMU to use: ``path`` if given, else the default; raises :class:`FmuError` when missing."""
    if path is None:
        return default_fmu_path()
    p = Path(path)
    if not p.is_file():
        raise FmuError(f"FMU not found: {p}")
    return p


_unzip_cache: dict[tuple[str, float], str] = {}


def _unzipped(fmu: Path) -> str:
    """The FMU extracted once per process (and removed when the process ends)."""
    key = (str(fmu.resolve()), fmu.stat().st_mtime)
    if key not in _unzip_cache:
        tmp = tempfile.mkdtemp(prefix="maglev_fmu_")
        atexit.register(shutil.rmtree, tmp, True)
        _unzip_cache[key] = extract(str(fmu), unzipdir=tmp)
    return _unzip_cache[key]


class FmuPlant:
    """One instance of the plant FMU, set up and initialised, ready to step.

    Parameters
    ----------
    start_values:
        FMU parameter and input start values by name (SI units as in ``modelDescription.xml``;
        ``u`` in MU).
    fmu:
        Path of the ``.fmu`` (default: :func:`ensure_fmu`).
    start_time:
        Simulation start time [s].
    logger:
        Called with each message the FMU logs, as ``logger(status: int, message: str)``.

    Raises
    ------
    FmuError
        When an FMI call fails: a bad or non-physical value, a step the FMU refuses. The message is
        the one line the FMU logged, naming the variable (for example ``fmi2SetReal: variable k_c:
        must be in [1e-12, 1] N.m2/A2, got -1``).
    """

    def __init__(self, start_values: Mapping[str, float] | None = None, *, fmu: str | Path | None = None,
                 start_time: float = 0.0, instance_name: str = "maglev",
                 logger: Callable[[int, str], None] | None = None) -> None:
        path = ensure_fmu(fmu)
        unzipdir = _unzipped(path)
        self.model_description = read_model_description(unzipdir)
        self.vr: dict[str, int] = {v.name: v.valueReference for v in self.model_description.modelVariables}
        self._fmu = FMU2Slave(guid=self.model_description.guid, unzipDirectory=unzipdir,
                              modelIdentifier=self.model_description.coSimulation.modelIdentifier,
                              instanceName=instance_name)
        self._last_error = ""

        def _log(env, name, status, category, message):
            text = message.decode(errors="replace")
            if status >= 2:  # discard, error, fatal: the reason a call is about to fail
                self._last_error = text
            if logger is not None:
                logger(int(status), text)

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(_log)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = callbacks  # keeps the ctypes callbacks alive
        self._fmu.instantiate(callbacks=callbacks)
        try:
            if start_values:
                self.set(dict(start_values))
            self._fmu.setupExperiment(startTime=start_time)
            self._fmu.enterInitializationMode()
            self._fmu.exitInitializationMode()
        except (FMICallException, FmuError) as exc:
            self._fmu.freeInstance()
            self._fmu = None
            raise FmuError(f"FMU initialisation failed: {self._failure(exc)}") from None
        self.time = float(start_time)
        self._c = self._fmu.component
        self._set = self._fmu.fmi2SetReal
        self._get = self._fmu.fmi2GetReal
        self._step = self._fmu.fmi2DoStep
        self._u_vr = (ctypes.c_uint * 1)(self.vr["u"])
        self._u_val = (ctypes.c_double * 1)()
        self._out_vr = (ctypes.c_uint * len(OUTPUTS))(*[self.vr[n] for n in OUTPUTS])
        self._out_val = (ctypes.c_double * len(OUTPUTS))()

    def _failure(self, exc: Exception) -> str:
        """The FMU's own message for a failed call (one line), else the exception's."""
        msg, self._last_error = self._last_error, ""
        return " ".join((msg or str(exc)).split())

    def set(self, values: Mapping[str, float]) -> None:
        """Sets variables by name (before or after initialisation, as FMI allows)."""
        unknown = [n for n in values if n not in self.vr]
        if unknown:
            raise FmuError(f"unknown FMU variable(s): {', '.join(unknown)}")
        try:
            self._fmu.setReal([self.vr[n] for n in values], [float(v) for v in values.values()])
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def get(self, names: Sequence[str]) -> list[float]:
        """Values of variables by name."""
        try:
            return list(self._fmu.getReal([self.vr[n] for n in names]))
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def set_input(self, u: float) -> None:
        """Sets the D/A input ``u`` [MU], held until the next call."""
        self._u_val[0] = u
        try:
            self._set(self._c, self._u_vr, 1, self._u_val)
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def outputs(self) -> tuple[float, float, float, float]:
        """``(y [MU], x [m], v [m/s], i [A])`` now."""
        try:
            self._get(self._c, self._out_vr, len(OUTPUTS), self._out_val)
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None
        o = self._out_val
        return o[0], o[1], o[2], o[3]

    def step(self, h: float) -> None:
        """Advances the FMU by ``h`` [s] from its current time (unchanged if the FMU refuses)."""
        try:
            self._step(self._c, self.time, h, 1)
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None
        self.time += h

    def get_state(self):
        """An FMU state snapshot (``fmi2GetFMUstate``)."""
        return self._fmu.getFMUstate()

    def set_state(self, state, time: float) -> None:
        """Restores a snapshot taken at ``time`` [s]."""
        self._fmu.setFMUstate(state)
        self.time = time

    def free_state(self, state) -> None:
        self._fmu.freeFMUstate(state)

    def close(self) -> None:
        """Terminates and frees the instance."""
        if self._fmu is not None:
            try:
                self._fmu.terminate()
            except Exception:  # noqa: BLE001 - an instance in the error state cannot terminate; free it anyway
                pass
            finally:
                self._fmu.freeInstance()
                self._fmu = None

    def __enter__(self) -> FmuPlant:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
