#!/usr/bin/env bash
# Set up (idempotent), then run the whole test suite (firmware-in-the-loop tests included),
# its test files spread over the cores.
# HYPOTHESIS_PROFILE=ci (default) is deterministic and bounded; =long searches further.
# Extra arguments go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
cd "$here"
export HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}"
# One pytest-xdist worker per core, at most 4 (each renders and holds wide scenes), a test file per
# worker so that its module fixtures are built once; CTR_BENCH_TEST_WORKERS=0 runs in this process.
workers="${CTR_BENCH_TEST_WORKERS:-$(( $(nproc) < 4 ? $(nproc) : 4 ))}"
exec .venv/bin/python -m pytest -q -n "$workers" --dist loadfile "$@"
