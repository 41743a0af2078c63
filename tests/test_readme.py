"""The README does what it says: its Python API section is a script a user would write and runs as
printed; its variable table and docs/fmu.md's are the model description's; its levitating fmpy
command line levitates; its links and docs/'s resolve."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_api_runs(tmp_path):
    text = README.read_text()
    section = text[text.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert len(code.strip().splitlines()) <= 16           # the short script the issue asks for
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "poles [1/s]: [  61.3  -63.7 -333.3]" in r.stdout
    dy = float(re.search(r"max \|dy\| = ([0-9.e+-]+) MU", r.stdout).group(1))
    assert dy < 1e-6
    assert (tmp_path / "step.csv").stat().st_size > 50000


def test_public_api_names_resolve():
    import maglev_cosim

    for name in maglev_cosim.__all__:
        assert getattr(maglev_cosim, name) is not None, name


def _run_script(*args: str) -> str:
    r = subprocess.run([sys.executable, str(README.parent / "scripts" / "fmu_variables.py"), *args],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_variable_tables_are_what_the_model_description_says():
    """The README's key variables and docs/fmu.md's full list are printed from modelDescription.xml
    by scripts/fmu_variables.py, not written by hand: regenerate them when the C table changes."""
    key, full = _run_script("--key"), _run_script()
    assert key in README.read_text(), "README.md: paste `python scripts/fmu_variables.py --key` under Variables"
    fmu_md = (README.parent / "docs" / "fmu.md").read_text()
    assert full in fmu_md, "docs/fmu.md: paste `python scripts/fmu_variables.py` under Every variable"
    assert full.count("\n") >= 40 and "| `u` | input | MU |" in key and "| `y` | output | MU |" in key


def test_levitating_start_values_are_the_equilibrium_and_keep_the_ball_off_the_stops(tmp_path):
    """The README's fmpy command line with --start-values: the values are the Section 3 equilibrium
    at x_start (to the last digit: open loop the equilibrium is unstable), and the FMU run with
    them for its default 3 s keeps the ball between the stops."""
    from fmpy import simulate_fmu

    import maglev_cosim
    from maglev_cosim import get_params, operating_point

    m = re.search(r"simulate build/maglev\.fmu.*?--start-values ((?:\S+ [0-9.e+-]+ ?)+)\n", README.read_text(), re.S)
    assert m, "README.md: the levitating fmpy command line is missing"
    words = m.group(1).split()
    start = {k: float(v) for k, v in zip(words[::2], words[1::2])}
    assert set(start) == {"x_start", "i_start", "u"}
    p = get_params("section3")
    op = operating_point(p, start["x_start"])
    assert start["i_start"] == op.i and start["u"] == op.u_MU
    r = simulate_fmu(str(maglev_cosim.fmu_path()), start_values=start, output=["x"])
    assert r["time"][-1] == pytest.approx(3.0)
    assert np.all((r["x"] > p.x_min + 1e-4) & (r["x"] < p.x_max - 1e-4))


def test_relative_links_of_the_readme_and_docs_resolve():
    root = README.parent
    for page in [README, *sorted((root / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), f"{page.name}: link to {target} does not resolve"
    img = root / "docs" / "img" / "step.png"
    assert img.stat().st_size < 150_000


def test_the_readme_is_a_front_door_within_its_length():
    """Issue 23: at most 12,000 characters, and "diagnose my record" on its first screen (the first
    60 lines)."""
    text = README.read_text(encoding="utf-8")
    assert len(text) <= 12_000, f"README.md has {len(text)} characters (at most 12,000)"
    assert "diagnose" in "\n".join(text.splitlines()[:60]).lower()
