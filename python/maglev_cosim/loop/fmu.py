"""Finding and driving the plant FMU (the installed ``maglev_cosim/_data/maglev.fmu``, or the FMI 3.0
``maglev3.fmu``) through fmpy.

:class:`FmuPlant` is a thin, fast wrapper over fmpy's ``FMU2Slave`` or ``FMU3Slave`` (chosen by the
FMU's ``fmiVersion``): value references are looked up once from ``modelDescription.xml``, and the
setter, getter and step are called with preallocated ctypes arrays, so a closed loop at 1 kHz costs
a few microseconds a step.
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
from fmpy.fmi3 import FMU3Slave

from .._resources import ResourceError, fmu_path

#: Output variables read after every step, in this order.
OUTPUTS: tuple[str, ...] = ("y", "x", "v", "i")


class FmuError(RuntimeError):
    """The FMU is missing or an FMI call failed."""


def default_fmu_path(fmi_version: int = 2) -> Path:
    """``$MAGLEV_FMU`` if set, else the installed FMU (see :func:`maglev_cosim.fmu_path`)."""
    try:
        return fmu_path(fmi_version)
    except ResourceError as exc:
        raise FmuError(str(exc)) from None


def ensure_fmu(path: str | Path | None = None, fmi_version: int = 2) -> Path:
    """The FMU to use: ``path`` if given, else the default one of that FMI version; raises
    :class:`FmuError` when missing."""
    if path is None:
        return default_fmu_path(fmi_version)
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
        Path of the ``.fmu`` (default: :func:`ensure_fmu`), FMI 2.0 or 3.0.
    start_time:
        Simulation start time [s].
    logger:
        Called with each message the FMU logs, as ``logger(status: int, message: str)``.

    Raises
    ------
    FmuError
        When an FMI call fails: a bad or non-physical value, a step the FMU refuses. The message is
        the one line the FMU logged, naming the variable (for example ``fmi2SetReal: variable k_c:
        must be in [0, 1] N.m2/A2, got -1``).
    """

    def __init__(self, start_values: Mapping[str, float] | None = None, *, fmu: str | Path | None = None,
                 start_time: float = 0.0, instance_name: str = "maglev",
                 logger: Callable[[int, str], None] | None = None) -> None:
        path = ensure_fmu(fmu)
        unzipdir = _unzipped(path)
        self.model_description = md = read_model_description(unzipdir)
        self.fmi_version = int(md.fmiVersion.split(".")[0])
        self.vr: dict[str, int] = {v.name: v.valueReference for v in md.modelVariables}
        self._last_error = ""

        def _text(status, message):
            text = message.decode(errors="replace")
            if status >= 2:  # discard, error, fatal: the reason a call is about to fail
                self._last_error = text
            if logger is not None:
                logger(int(status), text)

        kw = dict(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=instance_name)
        if self.fmi_version == 3:
            self._fmu = FMU3Slave(**kw)
            self._fmu.instantiate(logMessage=lambda env, status, category, message: _text(status, message))
        else:
            self._fmu = FMU2Slave(**kw)
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, message: _text(status, message))
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            self._callbacks = callbacks  # keeps the ctypes callbacks alive
            self._fmu.instantiate(callbacks=callbacks)
        try:
            if start_values:
                self.set(dict(start_values))
            if self.fmi_version == 3:
                self._fmu.enterInitializationMode(startTime=start_time)
            else:
                self._fmu.setupExperiment(startTime=start_time)
                self._fmu.enterInitializationMode()
            self._fmu.exitInitializationMode()
        except (FMICallException, FmuError) as exc:
            self._fmu.freeInstance()
            self._fmu = None
            raise FmuError(f"FMU initialisation failed: {self._failure(exc)}") from None
        self.time = float(start_time)
        self._c = self._fmu.component
        self._u_vr = (ctypes.c_uint * 1)(self.vr["u"])
        self._u_val = (ctypes.c_double * 1)()
        self._out_vr = (ctypes.c_uint * len(OUTPUTS))(*[self.vr[n] for n in OUTPUTS])
        self._out_val = (ctypes.c_double * len(OUTPUTS))()
        n = len(OUTPUTS)
        if self.fmi_version == 3:
            f = self._fmu
            flags = [ctypes.c_bool() for _ in range(3)]
            last = ctypes.c_double()
            out_args = (*[ctypes.byref(b) for b in flags], ctypes.byref(last))
            self._keep = (flags, last)
            self._set_u = lambda: f.fmi3SetFloat64(self._c, self._u_vr, 1, self._u_val, 1)
            self._get_out = lambda: f.fmi3GetFloat64(self._c, self._out_vr, n, self._out_val, n)
            self._do_step = lambda t, h: f.fmi3DoStep(self._c, t, h, True, *out_args)
            self._getter = f.getFloat64
        else:
            f = self._fmu
            self._set_u = lambda: f.fmi2SetReal(self._c, self._u_vr, 1, self._u_val)
            self._get_out = lambda: f.fmi2GetReal(self._c, self._out_vr, n, self._out_val)
            self._do_step = lambda t, h: f.fmi2DoStep(self._c, t, h, 1)
            self._getter = f.getReal

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
            setter = self._fmu.setFloat64 if self.fmi_version == 3 else self._fmu.setReal
            setter([self.vr[n] for n in values], [float(v) for v in values.values()])
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def get(self, names: Sequence[str]) -> list[float]:
        """Values of variables by name."""
        try:
            return list(self._getter([self.vr[n] for n in names]))
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def set_input(self, u: float) -> None:
        """Sets the D/A input ``u`` [MU], held until the next call."""
        self._u_val[0] = u
        try:
            self._set_u()
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None

    def outputs(self) -> tuple[float, float, float, float]:
        """``(y [MU], x [m], v [m/s], i [A])`` now."""
        try:
            self._get_out()
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None
        o = self._out_val
        return o[0], o[1], o[2], o[3]

    def step(self, h: float) -> None:
        """Advances the FMU by ``h`` [s] from its current time (unchanged if the FMU refuses)."""
        try:
            self._do_step(self.time, h)
        except FMICallException as exc:
            raise FmuError(self._failure(exc)) from None
        self.time += h

    def get_state(self):
        """An FMU state snapshot (``fmi2GetFMUstate`` / ``fmi3GetFMUState``)."""
        return self._fmu.getFMUState() if self.fmi_version == 3 else self._fmu.getFMUstate()

    def set_state(self, state, time: float) -> None:
        """Restores a snapshot taken at ``time`` [s]."""
        if self.fmi_version == 3:
            self._fmu.setFMUState(state)
        else:
            self._fmu.setFMUstate(state)
        self.time = time

    def free_state(self, state) -> None:
        if self.fmi_version == 3:
            self._fmu.freeFMUState(state)
        else:
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
