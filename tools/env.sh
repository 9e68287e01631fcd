#!/usr/bin/env bash
# Create or reuse .venv and install egograph (editable) with its test runner and optional extras
# (sourced by demo.sh/test.sh).
# Re-installs only when setup.cfg, pyproject.toml or tools/constraints.txt change; installs under
# tools/constraints.txt (the pinned versions the tests and benchmark records are made with).
# Installs the system libraries (libusb-1.0-0 for Open3D, libegl1 and libgl1-mesa-dri for the
# generator's OpenGL renderer) when missing.
# Prints one line per set-up step it runs (to stderr); what apt-get and pip print goes to
# .venv/setup.log (to a temporary file until .venv exists), whose path is printed when a step fails
# (exit 1).
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3
"$PY" -c 'import sys; sys.exit(0 if sys.version_info[:2] >= (3, 11) else 1)' || {
  echo "egograph needs Python 3.11 or newer (found: $("$PY" --version 2>&1))" >&2; exit 1; }

if [ -d "$VENV" ]; then
  SETUP_LOG="$VENV/setup.log"
else
  SETUP_LOG="$(mktemp "${TMPDIR:-/tmp}/egograph-setup.XXXXXX.log")"
fi

# step MESSAGE COMMAND...: say what is being set up, run it with its output in the log, and on
# failure name the log and stop.
step() {
  local what="$1"; shift
  echo "set-up: $what" >&2
  echo "=== $(date -u +%FT%TZ) $what: $*" >> "$SETUP_LOG"
  if ! "$@" >> "$SETUP_LOG" 2>&1; then
    echo "set-up failed: $what. What it printed: $SETUP_LOG" >&2
    exit 1
  fi
}

# System libraries: libusb-1.0 (Open3D), EGL + Mesa's software OpenGL (the generator's PV renderer).
NEED=()
# (grep without -q reads all of ldconfig's output: with -q it may close the pipe early, ldconfig
# dies of SIGPIPE, and under pipefail a library that is there looks missing, at random)
ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null || NEED+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep 'libEGL.so.1' >/dev/null || NEED+=(libegl1)
SWRAST=""  # (ls of both paths fails whenever one is missing: test each)
for f in /usr/lib/*/dri/swrast_dri.so /usr/lib/dri/swrast_dri.so; do [ -e "$f" ] && SWRAST="$f"; done
[ -n "$SWRAST" ] || NEED+=(libgl1-mesa-dri)
if [ "${#NEED[@]}" -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    step "apt-get install ${NEED[*]} (Open3D, the PV renderer)" \
      bash -c 'apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"' apt "${NEED[@]}"
  else
    echo "egograph needs the system packages ${NEED[*]}: run 'sudo apt-get install ${NEED[*]}'" >&2; exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  step "creating $VENV" "$PY" -m venv "$VENV"
  if [ "$SETUP_LOG" != "$VENV/setup.log" ]; then  # from now on the log lives in .venv
    cat "$SETUP_LOG" >> "$VENV/setup.log" && rm -f "$SETUP_LOG"
    SETUP_LOG="$VENV/setup.log"
  fi
fi
STAMP="$VENV/.egograph-installed"
WANT="$(sha256sum "$REPO/setup.cfg" "$REPO/pyproject.toml" "$REPO/tools/constraints.txt" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$WANT" ] || ! "$VENV/bin/python" -c 'import egograph' 2>/dev/null; then
  step "upgrading pip" "$VENV/bin/python" -m pip install --upgrade pip
  # setup.cfg asks for open3d-cpu on Linux x86_64; open3d and open3d-cpu install the same files, so a
  # .venv made before the switch drops the full build first rather than mixing the two.
  if [ "$(uname -sm)" = "Linux x86_64" ] && "$VENV/bin/python" -m pip show -q open3d >/dev/null 2>&1; then
    step "removing open3d (replaced by open3d-cpu)" "$VENV/bin/python" -m pip uninstall -y open3d
  fi
  # opencv-contrib-python-headless (required) and opencv-python-headless install the same cv2
  # files: a .venv made before the switch drops the plain build first rather than mixing the two.
  if "$VENV/bin/python" -m pip show -q opencv-python-headless >/dev/null 2>&1; then
    step "removing opencv-python-headless (replaced by the contrib build)" \
      "$VENV/bin/python" -m pip uninstall -y opencv-python-headless
  fi
  # Editable (the checkout's files are the ones run), with the test runner and the optional
  # COLMAP (refine.colmap), KISS-ICP (refine.icp) and rerun (export --rrd) extras, at the pinned
  # versions (a .venv made before the pins is brought to them: pip -c up- or downgrades).
  step "installing egograph and its dependencies into $VENV (pip; a few minutes the first time)" \
    "$VENV/bin/python" -m pip install -c "$REPO/tools/constraints.txt" -e "$REPO[test,colmap,icp,viewer]"
  echo "$WANT" > "$STAMP"
else
  echo "set-up: $VENV is up to date" >&2
fi
export PATH="$VENV/bin:$PATH"
