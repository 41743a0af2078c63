"""docs/bringing-your-rig.md: its rig file is the example's file, its Python runs and prints what the
page says, and (slow tier) every shell command on the page runs as printed, with the figures the
page quotes."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "bringing-your-rig.md"
EXAMPLE = REPO / "examples" / "bring_your_rig"


def _blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", DOC.read_text(), re.S)


def _env() -> dict[str, str]:
    """``python`` and ``maglev-cosim`` of the interpreter running the tests first on the PATH."""
    return {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


def _run(command: str, cwd: Path) -> str:
    r = subprocess.run(command, shell=True, capture_output=True, text=True, cwd=cwd, env=_env(), timeout=600)
    assert r.returncode == 0, f"{command}\n{r.stderr}"
    return r.stdout


def test_the_pages_rig_file_is_the_examples_and_loads():
    from maglev_cosim.rigs import load_rig

    (toml,) = _blocks("toml")
    assert toml == (EXAMPLE / "maglev-x200.toml").read_text()
    rig = load_rig(EXAMPLE / "maglev-x200.toml")
    assert rig.params.L_g == pytest.approx(2 * rig.params.k_c)   # Lg = 2 k_c, as the page derives
    assert set(rig.sources) >= {"mechanics.mass", "drive.resistance", "force", "sensor"}


def test_the_pages_python_prints_what_the_page_says(tmp_path):
    (code,) = _blocks("python")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() in DOC.read_text() and out.stdout.strip() == "k_c = 0.000289 N m2/A2, x_0 = -2.88 mm"
    first = _blocks("sh")[0].strip()
    (tmp_path / "examples").symlink_to(REPO / "examples")
    printed = _run(first, tmp_path).strip()
    assert printed == "maglev-x200 [0.423, 0.519, 0.614, 0.709]" and f"`{printed}`" in DOC.read_text()


@pytest.mark.slow   # two simulations, a diagnosis, a calibration, an FMU: about 40 s
def test_every_command_on_the_page_runs_and_gives_the_quoted_figures(tmp_path):
    (tmp_path / "examples").symlink_to(REPO / "examples")
    commands = [ln for block in _blocks("sh") for ln in block.splitlines() if ln.strip()]
    outputs = [_run(c, tmp_path) for c in commands]
    assert len(commands) == 7
    assert outputs[2].startswith("columns 6000 0.002 []")
    assert "verdict: no effect" in outputs[3] and ("current fit 92.1 % (the measured current's own noise, 3.0 mA RMS white, limits it to about 92.0 %), "
                                                  "skill at 20 ms +0.76") in outputs[3]
    # the closed loop with the identified controller ahead of the black box at 50 ms, the model
    # driven by the duty alone behind it
    assert "calibration (1)  50 ms: +0.83 / +0.65 / +0.72 /" in outputs[3]
    d = json.loads((tmp_path / "runs" / "x200" / "diagnosis.json").read_text())
    (seg,) = d["records"][0]["segments"]
    assert round(seg["before"]["current"]["from_actuator"]) == 25 and round(seg["after"]["current"]["from_actuator"]) == 92
    cal = d["coil_calibration"]["values"]
    assert round(cal["R_c"], 2) == 9.94 and round(cal["k_DA"], 1) == 22.3
    assert cal["T_d"] == 0.0   # the simulator's drive has no delay, and the coil stage finds none
    # only the ratio is seen: the simulated coil's 6 % more resistance over its drive's gain
    assert cal["R_c"] / cal["k_DA"] == pytest.approx(1.06 * 10.1 / 24, abs=1e-3)
    assert d["selected"] == [] and d["calibrated_fmu"] is not None
    fb = d["records"][0]["force_balance"]
    assert round(fb["ohm"]["median_V_over_Ri"], 2) == 1.06 and round(100 * fb["median"]) == 100
    assert (tmp_path / "runs" / "x200-cal" / "diagnosis.json").exists() and (tmp_path / "runs" / "x200.fmu").exists()
