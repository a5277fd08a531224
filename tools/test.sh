#!/usr/bin/env bash
# Set up .venv if needed, lint the repository, then run the test suite.
# Extra arguments go to pytest, e.g.: bash tools/test.sh -k equilibrium -x
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
bash tools/bootstrap.sh

export VIRTUAL_ENV="$repo/.venv"
export PATH="$VIRTUAL_ENV/bin:$PATH"
unset PYTHONHOME

ruff check --quiet . || { echo 'test: ruff check failed (see above)' >&2; exit 1; }

status=0
# Two worker processes, one test file each at a time (its module fixtures stay in one process).
python -m pytest -n "${SOFTSEQ_TEST_WORKERS:-2}" --dist loadfile "$@" || status=$?
if [[ $status -eq 5 ]]; then
    # pytest's "no tests collected": a filter or path that matches nothing is a mistake, not a pass.
    echo 'test: no test ran (pytest exit 5); check the arguments or the test folder' >&2
fi
exit "$status"
