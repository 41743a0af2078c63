#!/usr/bin/env bash
# Sets up everything from a fresh clone: .venv with the package installed from source (`pip install .`:
# scikit-build-core runs CMake, so the installed package carries the FMU, the C sources and the
# fast-path library) plus the test tools, and the CMake build in build/ (build/maglev.fmu, build/maglev3.fmu,
# build/maglev_pid.fmu, build/maglev_pid3.fmu, C tests; build/modelDescription3.xml and build/fmu_variables.md
# generated from the C variable table), then the closed loop build/maglev_loop.ssp and build/maglev_loop.fmu.
# Needs only python3 (with venv), gcc and cmake. Safe to run again: it reinstalls the package only
# when its sources changed (a hash of pyproject.toml, CMakeLists.txt, modelDescription.xml, c/, python/).
set -euo pipefail
cd "$(dirname "$0")/.."
# apt_install <what is missing without them> <package>...: installs the Debian packages (--no-install-recommends)
# when this runs as root with apt-get (CI). Without root or apt-get, with MAGLEV_NO_APT=1, or when the
# installation fails, it prints a notice saying what is missing and returns 0: never fatal.
apt_install() {
  local without=$1; shift
  local need=("$@")
  if [ -n "${MAGLEV_NO_APT:-}" ] || [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "[setup] notice: ${need[*]} missing and not installed (needs root and apt-get; MAGLEV_NO_APT=${MAGLEV_NO_APT:-}):" \
         "$without"
    return 0
  fi
  echo "[setup] installing ${need[*]} from Debian (apt-get, --no-install-recommends)"
  local t0=$SECONDS log=/tmp/maglev-apt-$$.log
  local apt=(apt-get -y -q --no-install-recommends -o DPkg::Lock::Timeout=120)
  # apt-get update only when the package lists do not have them (or are too old to download from)
  if ! DEBIAN_FRONTEND=noninteractive "${apt[@]}" install "${need[@]}" >"$log" 2>&1; then
    echo "[setup] apt-get install failed; running apt-get update and trying again"
    if ! { DEBIAN_FRONTEND=noninteractive apt-get -q update -o DPkg::Lock::Timeout=120 >>"$log" 2>&1 &&
           DEBIAN_FRONTEND=noninteractive "${apt[@]}" install "${need[@]}" >>"$log" 2>&1; }; then
      echo "[setup] notice: installing ${need[*]} failed (last lines of $log below): $without"
      tail -n 5 "$log" | sed 's/^/[setup]   /'
      return 0
    fi
  fi
  rm -f "$log"
  echo "[setup] installed ${need[*]} in $((SECONDS - t0)) s"
}
# The Windows binaries (docs/fmu.md, "Windows binaries"): the mingw-w64 cross compiler and wine, from Debian,
# installed here when missing. Without them the FMUs carry the Linux binaries only and the Windows test
# says why it skips.
win64_tools() {
  local need=()
  command -v x86_64-w64-mingw32-gcc >/dev/null 2>&1 || need+=(gcc-mingw-w64-x86-64)
  # Debian's wine64 package puts its loader at /usr/lib/wine/wine64 (the "wine" package adds /usr/bin/wine)
  command -v wine64 >/dev/null 2>&1 || [ -x /usr/lib/wine/wine64 ] || need+=(wine64)
  [ "${#need[@]}" -eq 0 ] && return 0
  apt_install "the FMUs get no Windows binaries" "${need[@]}"
}
win64_tools
# Headless Chromium (Debian's chromium, about 100 MB to download, 390 MB installed), in which
# tests/test_report_browser.py opens report.html; without it that test says why it skips.
browser() {
  command -v chromium >/dev/null 2>&1 && return 0
  apt_install "tests/test_report_browser.py skips (report.html is not opened in a browser)" chromium
}
browser

if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating virtual environment .venv"
  python3 -m venv .venv
fi
pip_quiet() {  # pip, quiet, without the warnings about unreachable extra package indexes
  .venv/bin/python -m pip --quiet --disable-pip-version-check "$@" 2>&1 | { grep -v "^WARNING: Location" || true; }
  return "${PIPESTATUS[0]}"
}
sources_hash() {
  find pyproject.toml CMakeLists.txt modelDescription.xml modelDescription_pid.xml \
       modelDescription_pid3.xml c python -type f \
       \( -name '*.py' -o -name '*.c' -o -name '*.h' -o -name '*.toml' -o -name '*.txt' -o -name '*.xml' \) \
       -not -path '*/__pycache__/*' -print0 | LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1
}
stamp=.venv/.maglev-installed
want="$(sources_hash)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  rm -f "$stamp"
  if ! .venv/bin/python -c "import pytest, maglev_cosim" 2>/dev/null; then
    echo "[setup] installing the package and its dependencies (fmpy, numpy, scipy, cffi, control, matplotlib, markdown, threadpoolctl, pytest)"
    pip_quiet install --upgrade pip
  else
    echo "[setup] sources changed: reinstalling the package (pip install .)"
  fi
  # --force-reinstall --no-deps would skip dependency changes; uninstalling first makes pip rebuild
  # the package from source even when its version did not change.
  pip_quiet uninstall --yes maglev-cosim >/dev/null || true
  pip_quiet install ".[test]"
  .venv/bin/python -c "import fmpy, numpy, scipy, cffi, control, matplotlib, pytest, maglev_cosim; maglev_cosim.fmu_path(); maglev_cosim.fmu_path(fmi_version=3)" \
    || { echo "[setup] package installation failed" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
echo "[setup] building build/maglev.fmu, build/maglev3.fmu, build/maglev_pid.fmu, build/maglev_pid3.fmu and the C tests with CMake"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 >/dev/null
test -f build/maglev.fmu && test -f build/maglev3.fmu && test -f build/maglev_pid.fmu && test -f build/maglev_pid3.fmu
echo "[setup] writing the closed loop: build/maglev_loop.ssp and build/maglev_loop.fmu (container)"
.venv/bin/python -m maglev_cosim.loop.loop_fmu build >/dev/null
test -f build/maglev_loop.ssp && test -f build/maglev_loop.fmu
