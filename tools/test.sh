#!/usr/bin/env bash
# Run the test suite (creates/reuses .venv first). Extra arguments go to pytest:
#   bash tools/test.sh                 everything (what CI runs)
#   bash tools/test.sh -m "not slow"   the fast tier: no renders, pose refinements, CLI pipelines or wheel build
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$REPO"
exec python -m pytest -q -p no:cacheprovider "$@"
