#!/usr/bin/env bash
# The main job on the embedded default: generate a synthetic recording, lift its detections,
# track, and evaluate under the IT3DEgo protocol. Extra arguments go to `egograph demo`.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
exec egograph demo "$@"
