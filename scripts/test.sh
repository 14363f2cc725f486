#!/usr/bin/env bash
# Set up, then run the whole default test suite (pytest exit 5, no tests collected, fails too).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
