"""The scripts in examples/ run and print what they promise (quick tier)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(name: str) -> str:
    r = subprocess.run([sys.executable, str(EXAMPLES / name)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_fmpy_closed_loop_reaches_the_reference():
    out = run("fmpy_closed_loop.py")
    y, w = map(float, re.search(r"y = ([\d.]+) MU after 2 s \(reference ([\d.]+) MU\)", out).groups())
    assert abs(y - w) < 0.002 and y != pytest.approx(w - 0.05, abs=0.01)


def test_linearize_and_design_prints_the_papers_poles_and_two_stable_loops():
    out = run("linearize_and_design.py")
    assert "61.27" in out and "-333.33" in out
    assert out.count("stable True") == 2


@pytest.mark.slow   # a whole diagnosis (6 s): the quick tier keeps its margin under 2 minutes
def test_diagnose_your_record_finds_the_planted_delay():
    out = run("diagnose_your_record.py")
    assert "selected ['delay']" in out
