#!/usr/bin/env bash
# Sets up (scripts/setup.sh) and runs the main job: builds the FMU, runs a closed-loop step,
# the linearisation and the diagnosis of a generated record; plots and reports go to out/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/maglev-cosim demo --out out "$@"
