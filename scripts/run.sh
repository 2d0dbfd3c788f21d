#!/usr/bin/env bash
# The main job: set up (idempotent), then render the default twin scene (scenes/paper.toml),
# reconstruct every frame with the paper's method and score it against the ground truth.
# Extra arguments go to `ctr-bench run` (e.g. a scene file, --method fast, --out DIR).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
cd "$here"
exec .venv/bin/ctr-bench run "$@"
