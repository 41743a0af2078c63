#!/usr/bin/env bash
# Sets up everything from a fresh clone: .venv with the Python packages, the CMake build of the FMU.
# Needs only python3 (with venv), gcc and cmake. Safe to run again: it only redoes what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating virtual environment .venv"
  python3 -m venv .venv
fi
stamp=.venv/.maglev-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[setup] installing Python packages (fmpy, numpy, scipy, cffi, control, matplotlib, pytest)"
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -e . 2>&1 | grep -v "^WARNING: Location" || true
  .venv/bin/python -c "import fmpy, numpy, scipy, cffi, control, matplotlib, pytest, maglev_cosim" \
    || { echo "[setup] package installation failed" >&2; exit 1; }
  touch "$stamp"
fi
echo "[setup] building the FMU (build/maglev.fmu)"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 >/dev/null
test -f build/maglev.fmu
