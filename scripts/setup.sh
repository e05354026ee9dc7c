#!/usr/bin/env bash
# Install what treesim needs on a fresh Debian/Ubuntu machine. Safe to re-run; skips apt
# when the libraries are already there.
#
#   scripts/setup.sh demo   the shared libraries open3d and pymeshlab load, a virtualenv in
#                           $VENV (.venv) and treesim itself: what `make demo` needs, quietly
#   scripts/setup.sh test   (the default) all of that, plus the dev extra (with the service,
#                           dask, e57 and postgres extras), the docs extra (the manual's
#                           pages are checked by the tests) and headless Chromium: what the
#                           test suite needs (`make test`)
#   scripts/setup.sh docs   what `demo` installs plus the docs extra (MkDocs): what
#                           `make docs` needs to build the manual
set -euo pipefail
cd "$(dirname "$0")/.."
MODE="${1:-test}"
case "$MODE" in
  demo|test|docs) ;;
  *) echo "usage: scripts/setup.sh [demo|test|docs]" >&2; exit 2 ;;
esac
VENV="${VENV:-.venv}"
PYTHON="${PYTHON:-python3}"
say() { if [ "$MODE" = test ]; then echo "setup: $*"; fi; }

need_pkgs=()
for pair in "libusb-1.0.so.0:libusb-1.0-0" "libGL.so.1:libgl1" "libglib-2.0.so.0:libglib2.0-0" \
            "libgomp.so.1:libgomp1"; do
  lib="${pair%%:*}"; pkg="${pair##*:}"
  if ! ldconfig -p 2>/dev/null | grep -q "$lib"; then need_pkgs+=("$pkg"); fi
done
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
apt_updated=0
if [ "${#need_pkgs[@]}" -gt 0 ]; then
  echo "setup: installing system libraries: ${need_pkgs[*]}"
  $SUDO apt-get update -qq && apt_updated=1
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    "${need_pkgs[@]}" >/dev/null
fi
# Headless Chromium renders the HTML report in the tests only; optional (those tests skip
# with a reason without it), so a failure here only warns. TREESIM_NO_BROWSER=1 skips it.
if [ "$MODE" = test ] && [ "${TREESIM_NO_BROWSER:-0}" != "1" ] \
   && ! command -v chromium >/dev/null 2>&1; then
  echo "setup: installing chromium (for the report rendering tests)"
  { [ "$apt_updated" = 1 ] || $SUDO apt-get update -qq; } \
    && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium \
    || echo "setup: warning: chromium could not be installed; report rendering tests will skip"
fi

if [ ! -x "$VENV/bin/python" ]; then
  say "creating virtualenv $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip install -q --disable-pip-version-check)
if [ "$MODE" = demo ]; then
  echo "setup: installing treesim into $VENV (a minute on a fresh machine)"
  "${PIP[@]}" -q -e .  # -qq: errors only
elif [ "$MODE" = docs ]; then
  "${PIP[@]}" -e ".[docs]"
else
  "${PIP[@]}" --upgrade pip
  # dev pulls in the service, dask, e57 and postgres extras; docs the site's builder
  "${PIP[@]}" -e ".[dev,docs]"
fi
"$VENV/bin/python" -c "import open3d, pymeshlab, laspy, trimesh, pgeof" \
  || { echo "setup: the native libraries failed to import (see above)"; exit 1; }
if [ "$MODE" != demo ]; then
  # the edge beam model's kernels compiled once into numba's cache (its time: see
  # docs/validation.md), not by each test worker that first scans with it
  "$VENV/bin/python" -c "from treesim.scan.warmup import warm_edge_model; warm_edge_model()" \
    || { echo "setup: compiling the edge beam model's kernels failed (see above)"; exit 1; }
fi
say "ready ($("$VENV/bin/python" --version), treesim in $VENV)"
