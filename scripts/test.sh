#!/usr/bin/env bash
# Sets up (scripts/setup.sh) and runs every test: the C tests under AddressSanitizer and
# UndefinedBehaviorSanitizer (ctest), then the Python test suite (pytest): first the quick tier
# (plain pytest skips tests marked slow), then the slow tier (pytest -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "[test] C tests under ASan + UBSan (build-asan)"
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug -DMAGLEV_SANITIZE=ON >/dev/null
cmake --build build-asan --parallel 2 >/dev/null
(cd build-asan && ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --output-on-failure)
echo "[test] Python tests against the installed package, quick tier"
.venv/bin/python -m pytest "$@"
echo "[test] Python tests, slow tier (diagnosis matrix, the wheel in a fresh venv; one line per test)"
rc=0
.venv/bin/python -m pytest -m slow -v --durations=5 "$@" || rc=$?
[ "$rc" -eq 0 ] || [ "$rc" -eq 5 ] || exit "$rc"   # 5: the arguments selected no slow test
