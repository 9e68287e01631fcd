#!/usr/bin/env bash
# The main job on the embedded default: generate a synthetic recording, lift its detections,
# track, evaluate under the IT3DEgo protocol, and draw every tracker's results (egograph plot);
# the last line printed is the path of the pictures' index.html. Extra arguments go to
# `egograph demo` (`egograph demo --help`: the steps, and how long they take on 2 cores).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
exec egograph demo "$@"
