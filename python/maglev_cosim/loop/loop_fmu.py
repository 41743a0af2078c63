"""The closed loop in any FMI tool, without Python: plant FMU + controller FMU + step reference.

Two ready files, both made from the same settings (:func:`loop_settings`, the start of
:func:`maglev_cosim.loop.simulate.simulate`: the plant settled at rest at ``x_op`` and the PID's integrator
holding the equilibrium input), so that they run what ``loop.simulate`` runs:

- ``maglev_loop.ssp``: SSP 1.0, ``SystemStructure.ssd`` with the components ``plant``
  (``resources/maglev.fmu``) and ``pid`` (``resources/maglev_pid.fmu``), the connections
  ``plant.y -> pid.y`` and ``pid.u -> plant.u``, and every start value as a parameter binding;
- ``maglev_loop.fmu``: the same loop as one co-simulation FMU, a container made by
  fmu-manipulation-toolbox (``fmucontainer``) that runs the two FMUs in its own C runtime,
  sequentially, controller first, at the communication step ``ts``.

Order of evaluation. The controller FMU samples its input ``y`` in ``fmi2DoStep`` and holds
``u[k]`` from then on (``c/maglev_pid_fmu.c``). A master that, at each communication point
``t_k``, steps the controller on the plant's current reading and then the plant on the
controller's new output (Gauss-Seidel, controller first, step ``ts``: the container's sequential
mode) applies ``u[k] = PID(w[k] - y[k])`` over ``[t_k, t_k + ts]``, as ``loop.simulate`` does. A
master that steps both on the values of the previous point (Jacobi) adds one sample of delay.

``python -m maglev_cosim.loop.loop_fmu BUILD_DIR`` writes both into ``BUILD_DIR`` from the
``maglev.fmu`` and ``maglev_pid.fmu`` there (``scripts/setup.sh`` runs it).
"""

from __future__ import annotations

import json
import logging
import shutil
import sys
import tempfile
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

# Imported inside a function, on purpose: fmu_manipulation_toolbox (optional: the `test` extra).
from ..plant import formulas
from ..plant.params import PlantParams, as_params
from .pid import ANTI_WINDUP, PID
from .simulate import X_OP, settled_start

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
#: The loop's default experiment: the paper's step of 0.05 MU (Section 5) at 0.1 s, 1 s long.
AMPLITUDE, T_STEP, STOP = 0.05, 0.1, 1.0


def loop_settings(params: PlantParams | str | None = "section3", pid: PID | None = None, *, x_op: float = X_OP,
                  amplitude: float = AMPLITUDE, t_step: float = T_STEP) -> dict[str, dict[str, float]]:
    """Start values of the two FMUs: ``{"plant": {...}, "pid": {...}}``. The plant at rest at
    ``x_op`` [m] with the input that holds it there, the PID settled on that input, and the step
    reference from the reading at ``x_op`` to ``amplitude`` [MU] above at ``t_step`` [s]."""
    p = as_params(params)
    pid = pid or PID()
    start, u_hold = settled_start(p, x_op)
    base = formulas.point(start, x_op).y
    c = pid.c_settings()
    return {
        "plant": {**start.to_start_values(), "u": float(u_hold)},
        "pid": {"ts": c["ts"], "kp": c["kp"], "ki": c["ki"], "kd": c["kd"], "tf": c["tf"], "u_min": c["u_min"],
                "u_max": c["u_max"], "anti_windup": float(ANTI_WINDUP.index(pid.anti_windup)), "i_lo": c["i_lo"],
                "i_hi": c["i_hi"], "backoff": c["backoff"], "u_hold": float(u_hold), "w0": float(base),
                "w1": float(base + amplitude), "t_step": float(t_step)},
    }


def _num(x: float) -> str:
    return repr(float(x))


def ssd_text(settings: dict[str, dict[str, float]], *, step: float, stop: float = STOP) -> str:
    """``SystemStructure.ssd`` of the loop (SSP 1.0)."""
    def connector(name: str, kind: str) -> str:
        return f'          <ssd:Connector name="{name}" kind="{kind}"><ssc:Real/></ssd:Connector>'

    def bindings(values: dict[str, float]) -> list[str]:
        out = ['        <ssd:ParameterBindings>', '          <ssd:ParameterBinding>',
               '            <ssd:ParameterValues>', f'              <ssv:ParameterSet version="1.0" name="start" '
               f'xmlns:ssv="{SSV_NS}">', '                <ssv:Parameters>']
        for name, value in values.items():
            out.append(f'                  <ssv:Parameter name={quoteattr(name)}><ssv:Real value="{_num(value)}"/>'
                       '</ssv:Parameter>')
        return out + ['                </ssv:Parameters>', '              </ssv:ParameterSet>',
                      '            </ssd:ParameterValues>', '          </ssd:ParameterBinding>',
                      '        </ssd:ParameterBindings>']

    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<ssd:SystemStructureDescription xmlns:ssd="{SSD_NS}" xmlns:ssc="{SSC_NS}" version="1.0" '
             'name="maglev_loop" generationTool="maglev-cosim">',
             '  <ssd:System name="loop" description="CE152 closed loop: plant, discrete PID (Eq. 24/25) with a step '
             'reference; step the PID before the plant at each communication point of ts">',
             '    <ssd:Connectors>',
             connector("w_in", "input").replace("          ", "      "),
             connector("y", "output").replace("          ", "      "),
             connector("u", "output").replace("          ", "      "),
             '    </ssd:Connectors>',
             '    <ssd:Elements>',
             '      <ssd:Component name="pid" source="resources/maglev_pid.fmu" type="application/x-fmu-sharedlibrary">',
             '        <ssd:Connectors>', connector("y", "input"), connector("w_in", "input"), connector("u", "output"),
             connector("w", "output"), '        </ssd:Connectors>', *bindings(settings["pid"]),
             '      </ssd:Component>',
             '      <ssd:Component name="plant" source="resources/maglev.fmu" type="application/x-fmu-sharedlibrary">',
             '        <ssd:Connectors>', connector("u", "input"), connector("y", "output"), connector("x", "output"),
             connector("v", "output"), connector("i", "output"), '        </ssd:Connectors>',
             *bindings(settings["plant"]),
             '      </ssd:Component>',
             '    </ssd:Elements>',
             '    <ssd:Connections>',
             '      <ssd:Connection startElement="plant" startConnector="y" endElement="pid" endConnector="y"/>',
             '      <ssd:Connection startElement="pid" startConnector="u" endElement="plant" endConnector="u"/>',
             '      <ssd:Connection startElement="plant" startConnector="y" endConnector="y"/>',
             '      <ssd:Connection startElement="pid" startConnector="u" endConnector="u"/>',
             '      <ssd:Connection startConnector="w_in" endElement="pid" endConnector="w_in"/>',
             '    </ssd:Connections>',
             '  </ssd:System>',
             f'  <ssd:DefaultExperiment startTime="0.0" stopTime="{_num(stop)}"/>',
             '</ssd:SystemStructureDescription>', '']
    del step  # the SSD has no step size; docs/fmu.md and the container state ts
    return "\n".join(lines)


def write_ssp(out: str | Path, plant_fmu: str | Path, pid_fmu: str | Path,
              settings: dict[str, dict[str, float]] | None = None) -> Path:
    """``maglev_loop.ssp``: the SSD and both FMUs in ``resources/``."""
    settings = settings or loop_settings()
    out = Path(out)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", ssd_text(settings, step=settings["pid"]["ts"]))
        z.write(plant_fmu, "resources/maglev.fmu")
        z.write(pid_fmu, "resources/maglev_pid.fmu")
    return out


def container_description(settings: dict[str, dict[str, float]]) -> dict:
    """fmu-manipulation-toolbox's JSON description of the container: the FMUs in the order they
    step (controller first), sequential, at the step ``ts``, with the start values of both."""
    start = [[fmu, name, _num(v)] for fmu, key in (("maglev_pid.fmu", "pid"), ("maglev.fmu", "plant"))
             for name, v in settings[key].items()]
    return {
        "name": "maglev_loop.fmu", "step_size": settings["pid"]["ts"], "sequential": True, "mt": False,
        "auto_link": False, "auto_input": False, "auto_output": False, "auto_parameter": False,
        "fmu": ["maglev_pid.fmu", "maglev.fmu"],
        "link": [["maglev.fmu", "y", "maglev_pid.fmu", "y"], ["maglev_pid.fmu", "u", "maglev.fmu", "u"]],
        # every port of the two FMUs is linked or exposed: the PID's extra reference w_in (added to
        # its step reference, 0 unless a master sets it) is the container's input, the plant's
        # outputs and the force F its outputs
        "input": [["w_in", "maglev_pid.fmu", "w_in"]],
        "output": [["maglev.fmu", n, n] for n in ("y", "x", "v", "i", "F")]
                  + [["maglev_pid.fmu", "u", "u"], ["maglev_pid.fmu", "w", "w"]],
        "start": start,
    }


def _expected_loop_warning(record: logging.LogRecord) -> bool:
    """Drops fmu-manipulation-toolbox's warning "Loop of links through the embedded FMU
    'maglev_pid.fmu': it is initialized without the values its inputs get from the loop". The loop
    is the feedback loop itself (plant.y -> pid.y, pid.u -> plant.u), so the toolbox initializes the
    PID first, before the plant's reading exists. That is harmless: the PID's output at
    initialization is its settled start ``u_hold``, and it reads ``y`` first in its first
    ``fmi2DoStep``, after the container has passed it the plant's reading (the container run
    matches ``loop.simulate`` to 1e-15 MU, ``tests/test_loopfmu.py``). Any other message passes."""
    return not record.getMessage().startswith("Loop of links through the embedded FMU 'maglev_pid.fmu'")


class ContainerUnavailable(RuntimeError):
    """fmu-manipulation-toolbox is not installed (it is in the package's ``test`` extra)."""


def write_container(out: str | Path, plant_fmu: str | Path, pid_fmu: str | Path,
                    settings: dict[str, dict[str, float]] | None = None) -> Path:
    """``maglev_loop.fmu``: the loop as a container FMU made by fmu-manipulation-toolbox."""
    try:
        from fmu_manipulation_toolbox.assembly import Assembly
    except ImportError as e:
        raise ContainerUnavailable(f"fmu-manipulation-toolbox is not installed ({e}): pip install "
                                   "'maglev-cosim[test]' or fmu-manipulation-toolbox") from None
    settings = settings or loop_settings()
    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copy(plant_fmu, tmp / "maglev.fmu")
        shutil.copy(pid_fmu, tmp / "maglev_pid.fmu")
        (tmp / "maglev_loop.json").write_text(json.dumps(container_description(settings), indent=1))
        assembly = Assembly("maglev_loop.json", fmu_directory=tmp)
        toolbox_log = logging.getLogger("fmu_manipulation_toolbox")
        toolbox_log.addFilter(_expected_loop_warning)
        try:
            assembly.make_fmu()
        finally:
            toolbox_log.removeFilter(_expected_loop_warning)
        shutil.copy(tmp / "maglev_loop.fmu", out)
    return out


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m maglev_cosim.loop.loop_fmu BUILD_DIR\n"
              "writes BUILD_DIR/maglev_loop.ssp and BUILD_DIR/maglev_loop.fmu from BUILD_DIR/maglev.fmu and "
              "BUILD_DIR/maglev_pid.fmu", file=sys.stderr)
        return 2
    build = Path(args[0])
    plant, pid = build / "maglev.fmu", build / "maglev_pid.fmu"
    settings = loop_settings()
    print(f"wrote {write_ssp(build / 'maglev_loop.ssp', plant, pid, settings)}")
    try:
        print(f"wrote {write_container(build / 'maglev_loop.fmu', plant, pid, settings)}")
    except ContainerUnavailable as e:
        print(f"maglev_loop.fmu not written: {e}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
