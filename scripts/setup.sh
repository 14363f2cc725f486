#!/usr/bin/env bash
# Create .venv (if missing) and install stereovox with pinned versions (constraints.txt).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "setup: stereovox needs Python >= 3.11; found $("$PY" --version 2>&1). Set PYTHON=/path/to/python3.11" >&2
  exit 1
fi
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv || { echo "setup: '$PY -m venv' failed (on Debian/Ubuntu: apt install python3-venv)" >&2; exit 1; }
fi
.venv/bin/python -m pip install --quiet --upgrade pip >/dev/null
.venv/bin/python -m pip install --quiet -c constraints.txt -e ".[dev]"
# compile the numba kernels (voxel map, flood fill, tracker) once into .numba/ (common/numba_cache.py), so
# that no service stalls for its first frame: 30 s cold on a 2-core machine, 3 s once cached; six
# frames, since the tracker's left-behind test (services/tracker/left_behind.py) first looks three back
echo "setup: compiling the numba kernels on 6 frames of the bundled recording (once)" >&2
warm=$(mktemp -d)
.venv/bin/stereovox process recordings/urban.mcap --out "$warm/warm.mcap" --max-frames 6 >/dev/null
rm -rf "$warm"
