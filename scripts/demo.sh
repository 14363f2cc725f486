#!/usr/bin/env bash
# Set up, then run the demo on the bundled recording.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/stereovox demo "$@"
