#!/usr/bin/env bash
# Set everything up, lint, and run the test suite. Extra arguments go to pytest.
# The tests run in MANTIS_TEST_WORKERS worker processes (pytest-xdist, default 3), one test file
# per worker at a time so that a module's fixtures are built once, handed out in
# test/conftest.py's order (the slow modules first; xdist's own reordering, by number of tests,
# is turned off). Three on two cores: about a third of the suite is waiting (trials at 1x rig
# time, processes starting), not computing. Every test that uses ROS claims a domain of its
# own, so workers never hear each other.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test
. scripts/ros_env.sh
.venv/bin/ruff check .
.venv/bin/mantis doctor --backend sim    # the commissioning check on the simulated rig
.venv/bin/python -m pytest -q -n "${MANTIS_TEST_WORKERS:-3}" --dist loadfile --no-loadscope-reorder "$@"
