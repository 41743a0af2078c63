#!/usr/bin/env bash
# Sets up (scripts/setup.sh) and runs every test: the C tests under AddressSanitizer and
# UndefinedBehaviorSanitizer (ctest), the Windows binaries (the cross-compiled C tests and
# tests/test_win64.py, under wine when it runs here), then the Python test suite (pytest): first the
# quick tier (plain pytest skips tests marked slow), then the slow tier (pytest -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "[test] C tests under ASan + UBSan (build-asan)"
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug -DMAGLEV_SANITIZE=ON >/dev/null
cmake --build build-asan --parallel 2 >/dev/null
(cd build-asan && ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --output-on-failure)
# The Windows binaries (docs/fmu.md, "Windows binaries"): with wine, the C tests of the cross-compiled build
# (build/win64) under wine and tests/test_win64.py (the importer under wine against the Linux run);
# without wine (or a wine that cannot run here), tests/test_win64.py checks the DLLs' export tables.
wine=$(command -v wine64 || { [ -x /usr/lib/wine/wine64 ] && echo /usr/lib/wine/wine64; } || true)
if [ ! -f build/win64/fmi_importer.exe ]; then
  echo "[test] notice: no mingw-w64 cross compiler (scripts/setup.sh installs it as root): the FMUs carry no" \
       "Windows binaries, nothing to check"
else
  mkdir -p build/wine
  probe=""  # the importer without arguments prints its usage: wine runs a Windows program here
  [ -z "$wine" ] || probe=$(WINEPREFIX="$PWD/build/wine" WINEDEBUG=-all "$wine" build/win64/fmi_importer.exe 2>&1 || true)
  if [[ "$probe" == *"fmi_importer: usage"* ]]; then
    echo "[test] Windows binaries: the C tests of build/win64 under wine ($("$wine" --version))"
    (cd build/win64 && ctest --output-on-failure)
  else
    echo "[test] notice: wine ${wine:-is not installed}${wine:+ cannot run a Windows program here}: the Windows" \
         "binaries are checked by their export tables only (objdump)"
  fi
  echo "[test] Windows binaries: tests/test_win64.py (the importer under wine against linux64, export tables)"
  rc=0
  .venv/bin/python -m pytest tests/test_win64.py -m "slow or not slow" -n 0 -v -s -rs "$@" || rc=$?
  [ "$rc" -eq 0 ] || [ "$rc" -eq 5 ] || exit "$rc"   # 5: the arguments selected none of them
fi
echo "[test] Python tests against the installed package, quick tier (on every core: pytest-xdist)"
.venv/bin/python -m pytest --ignore=tests/test_win64.py "$@"
echo "[test] Python tests, slow tier (diagnosis matrix, the wheel in a fresh venv; one line per test)"
rc=0
.venv/bin/python -m pytest -m slow -n 0 --ignore=tests/test_win64.py -v --durations=5 "$@" || rc=$?
[ "$rc" -eq 0 ] || [ "$rc" -eq 5 ] || exit "$rc"   # 5: the arguments selected no slow test
