#!/usr/bin/env bash
# Create or reuse .venv and install egograph (editable) with its test runner and optional extras
# (sourced by demo.sh/test.sh).
# Re-installs only when setup.cfg changes. Installs the system libraries (libusb-1.0-0 for Open3D,
# libegl1 and libgl1-mesa-dri for the generator's OpenGL renderer) when missing.
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3
"$PY" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 11) else 1)' || {
  echo "egograph needs Python 3.11 or newer (found: $("$PY" --version 2>&1))" >&2; exit 1; }

# System libraries: libusb-1.0 (Open3D), EGL + Mesa's software OpenGL (the generator's PV renderer).
NEED=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || NEED+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || NEED+=(libegl1)
ls /usr/lib/*/dri/swrast_dri.so /usr/lib/dri/swrast_dri.so >/dev/null 2>&1 || NEED+=(libgl1-mesa-dri)
if [ "${#NEED[@]}" -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing ${NEED[*]} (Open3D, the PV renderer)..." >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${NEED[@]}") >&2
  else
    echo "egograph needs the system packages ${NEED[*]}: run 'sudo apt-get install ${NEED[*]}'" >&2; exit 1
  fi
fi

VENV="$REPO/.venv"
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
STAMP="$VENV/.egograph-installed"
WANT="$(sha256sum "$REPO/setup.cfg" "$REPO/pyproject.toml" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$WANT" ] || ! "$VENV/bin/python" -c 'import egograph' 2>/dev/null; then
  echo "installing egograph and its dependencies into $VENV ..." >&2
  "$VENV/bin/python" -m pip install -q --upgrade pip >&2
  # setup.cfg asks for open3d-cpu on Linux x86_64; open3d and open3d-cpu install the same files, so a
  # .venv made before the switch drops the full build first rather than mixing the two.
  if [ "$(uname -sm)" = "Linux x86_64" ] && "$VENV/bin/python" -m pip show -q open3d >/dev/null 2>&1; then
    "$VENV/bin/python" -m pip uninstall -q -y open3d >&2
  fi
  # opencv-contrib-python-headless (required) and opencv-python-headless install the same cv2
  # files: a .venv made before the switch drops the plain build first rather than mixing the two.
  if "$VENV/bin/python" -m pip show -q opencv-python-headless >/dev/null 2>&1; then
    "$VENV/bin/python" -m pip uninstall -q -y opencv-python-headless >&2
  fi
  # Editable (the checkout's files are the ones run), with the test runner and the optional
  # COLMAP (refine.colmap), KISS-ICP (refine.icp) and rerun (export --rrd) extras.
  "$VENV/bin/python" -m pip install -q -e "$REPO[test,colmap,icp,viewer]" >&2
  echo "$WANT" > "$STAMP"
fi
export PATH="$VENV/bin:$PATH"
