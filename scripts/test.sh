#!/usr/bin/env bash
# Set everything up, lint, and run the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test
. scripts/ros_env.sh
.venv/bin/ruff check .
.venv/bin/python -m pytest -q "$@"
