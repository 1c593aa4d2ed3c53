#!/usr/bin/env bash
# Create (or reuse) the project virtual environment .venv with the pinned dependencies and
# mantis_rig installed in it (editable). Safe to run again: it reinstalls only when
# requirements.txt, setup.py or the node list changed. With --test, also requirements-test.txt,
# and .venv-colcon for the test of the ROS install path, installed alongside .venv (the two
# installs are independent and run side by side).
set -euo pipefail
cd "$(dirname "$0")/.."

python_bin="${PYTHON:-}"
if [ -z "$python_bin" ]; then
  for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then python_bin="$candidate"; break; fi
  done
fi
version="$("$python_bin" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if [ "$version" != "3.11" ]; then
  echo "bootstrap: need Python 3.11 (the ROS 2 Jazzy wheels are built for it); $python_bin is $version" >&2
  exit 1
fi
# The installer: uv, pinned, installed into .venv by pip. On a fresh clone it sets up both venvs
# in about a third of pip's time (it downloads in parallel; pip spent ~85 CPU s). uv does not
# read pip's configuration (a lab's index mirror, say): where uv cannot install, pip does, and
# MANTIS_INSTALLER=pip skips uv altogether.
UV_REQUIREMENT='uv==0.13.8'
UV=.venv/bin/uv

pip_install() {   # pip_install VENV ARGS...: quietly, with uv where it works, else with pip
  local venv="$1"; shift
  if [ -x "$UV" ]; then
    if "$UV" pip install --quiet --compile-bytecode --python "$venv/bin/python" "$@"; then
      return 0
    fi
    echo "bootstrap: uv could not install that (above); trying pip" >&2
  fi
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "$@"
}

make_main_venv() {
  if [ ! -x .venv/bin/python ]; then
    echo "bootstrap: creating .venv with $python_bin" >&2
    "$python_bin" -m venv .venv
  fi
  if [ "${MANTIS_INSTALLER:-uv}" = pip ]; then
    UV=''                                  # pip_install then always takes pip
  elif [ ! -x "$UV" ]; then
    .venv/bin/python -m pip install --quiet --disable-pip-version-check "$UV_REQUIREMENT" \
      || echo "bootstrap: could not install $UV_REQUIREMENT; installing with pip" >&2
  fi
}

install_main() {
  local stamp=.venv/.mantis-installed wanted
  wanted="$(cat requirements.txt setup.py; ls mantis_rig/nodes 2>/dev/null || true)"
  wanted="$(printf '%s' "$wanted" | sha256sum | cut -d' ' -f1)"
  if [ "$(cat "$stamp" 2>/dev/null || true)" != "$wanted" ]; then
    echo "bootstrap: installing pinned dependencies into .venv" >&2
    pip_install .venv -r requirements.txt
    pip_install .venv --no-deps -e .
    echo "$wanted" > "$stamp"
  fi
}

install_colcon() {
  # The ROS install path's own venv: colcon and the runtime dependencies, no mantis_rig (the
  # test builds and installs it with colcon).
  if [ ! -x .venv-colcon/bin/python ]; then
    echo "bootstrap: creating .venv-colcon with $python_bin (colcon build test)" >&2
    "$python_bin" -m venv .venv-colcon
  fi
  local stamp=.venv-colcon/.mantis-colcon-installed wanted
  wanted="$(cat requirements.txt requirements-colcon.txt | sha256sum | cut -d' ' -f1)"
  if [ "$(cat "$stamp" 2>/dev/null || true)" != "$wanted" ]; then
    echo "bootstrap: installing colcon and the runtime dependencies into .venv-colcon" >&2
    pip_install .venv-colcon -r requirements.txt -r requirements-colcon.txt
    echo "$wanted" > "$stamp"
  fi
}

install_test() {
  local stamp=.venv/.mantis-test-installed wanted
  wanted="$(sha256sum requirements-test.txt | cut -d' ' -f1)"
  if [ "$(cat "$stamp" 2>/dev/null || true)" != "$wanted" ]; then
    echo "bootstrap: installing test-only dependencies into .venv" >&2
    pip_install .venv -r requirements-test.txt
    echo "$wanted" > "$stamp"
  fi
}

make_main_venv
if [ "${1:-}" = "--test" ]; then
  install_colcon &
  colcon_job=$!
  # If the installs here fail, set -e exits: take the background install down with us rather
  # than leave it writing into .venv-colcon for the next run to race.
  trap 'kill "$colcon_job" 2>/dev/null || true; wait "$colcon_job" 2>/dev/null || true' EXIT
  install_main
  install_test
  if ! wait "$colcon_job"; then
    trap - EXIT
    echo "bootstrap: installing .venv-colcon failed (above)" >&2
    exit 1
  fi
  trap - EXIT
else
  install_main
fi
# The fast strike engine compiles once per checkout (about a minute on two cores) into its cache
# beside the sources: here, rather than in the first simulation (or in each test worker at once).
.venv/bin/python -m mantis_sim.fast >&2
# The package's own bytecode, written once: with PYTHONDONTWRITEBYTECODE set (as on these
# machines) every process would otherwise compile its modules again (0.3 CPU s a trial).
.venv/bin/python -m compileall -q mantis_rig mantis_sim >&2
