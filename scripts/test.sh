#!/usr/bin/env bash
# Set everything up, lint, and run the test suite. Extra arguments go to pytest.
# The tests run in MANTIS_TEST_WORKERS worker processes (pytest-xdist, default 2), one test file
# per worker at a time so that a module's fixtures are built once, handed out in
# test/conftest.py's order (the slow modules first; xdist's own reordering, by number of tests,
# is turned off). Two on two cores: with three, the slow tests that freeze, kill and time a
# rig at real-time factor 0 saw their node processes starved past the rig's own guards (a
# stale force reading, a release heard seconds late). Every test that uses ROS claims a domain
# of its own, so workers never hear each other.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test
. scripts/ros_env.sh
.venv/bin/ruff check .
.venv/bin/mantis doctor --backend sim    # the commissioning check on the simulated rig
.venv/bin/python -m pytest -q -n "${MANTIS_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder "$@"
