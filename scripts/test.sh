#!/usr/bin/env bash
# The whole test suite on a fresh machine: creates/reuses .venv, installs the project, runs pytest.
#   bash scripts/test.sh [pytest arguments]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/_venv.sh"
# One test process per core (pytest-xdist; a file's tests stay together, so its fixtures are built once), each
# with one math thread so that the processes do not oversubscribe the cores. VYSICS_TEST_WORKERS=0: one process.
WORKERS="${VYSICS_TEST_WORKERS:-auto}"
if [ "$WORKERS" != "0" ]; then
  export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" MKL_NUM_THREADS="${MKL_NUM_THREADS:-1}"
  set -- -n "$WORKERS" --dist loadfile "$@"
fi
set +e
python -m pytest "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  echo "pytest collected no tests" >&2
  exit 0
fi
exit "$rc"
