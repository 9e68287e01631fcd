#!/usr/bin/env bash
# Run the test suite (creates/reuses .venv first). Extra arguments go to pytest:
#   bash tools/test.sh                 everything (what CI runs)
#   bash tools/test.sh -m "not slow"   the fast tier: no renders, pose refinements, CLI pipelines or wheel build
#   bash tools/test.sh -n 0            in this one process (pytest-xdist off: a debugger, print-debugging)
# Tests run in one worker process per CPU (pytest-xdist, EGOGRAPH_TEST_WORKERS to choose how many),
# each test file whole on one worker (its module fixtures made once). On 2 CPUs this takes the suite
# from 9 min 24 s to 7 min 36 s (stop 54, one run each on the same machine).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$REPO"
exec python -m pytest -q -p no:cacheprovider -n "${EGOGRAPH_TEST_WORKERS:-auto}" --dist loadfile "$@"
