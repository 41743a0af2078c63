"""The README's Python API section is a script a user would write: it runs as printed."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

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
