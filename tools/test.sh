#!/usr/bin/env bash
# Run the test suite (creates/reuses .venv first). Extra arguments go to pytest.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$REPO"
exec python -m pytest -q -p no:cacheprovider "$@"
