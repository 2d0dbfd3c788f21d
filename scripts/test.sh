#!/usr/bin/env bash
# Set up (idempotent), then run the whole test suite (firmware-in-the-loop tests included).
# HYPOTHESIS_PROFILE=ci (default) is deterministic and bounded; =long searches further.
# Extra arguments go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
cd "$here"
export HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}"
exec .venv/bin/python -m pytest -q "$@"
