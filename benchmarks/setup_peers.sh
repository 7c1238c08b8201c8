#!/usr/bin/env bash
# Build the SEPARATE environment for the peer simulators used by benchmarks/bench_mpm.py
# (Taichi's MLS-MPM and Genesis' MPM). It never touches the project's .venv: Taichi and
# Genesis pin their own numpy/torch and must not leak into motionphysics' dependencies.
#
#   bash benchmarks/setup_peers.sh            # creates benchmarks/.venv-peers
#   PEERS_VENV=/elsewhere bash benchmarks/setup_peers.sh
#
# torch is installed first and alone, pinned to the CPU build the project uses, so that
# genesis-world cannot pull a multi-GB CUDA torch. Genesis is optional: if it does not
# install, the script says so and the benchmark reports Genesis as unavailable.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="${PEERS_VENV:-$HERE/.venv-peers}"
PY="${PY:-python3.11}"

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q "numpy<2.3" taichi==1.7.4
echo "taichi: $("$VENV/bin/python" -c 'import taichi as ti; print(ti.__version__)' 2>/dev/null | tail -1)"

if [ "${SKIP_GENESIS:-0}" != "1" ]; then
  # CPU torch first (the wheel the project pins); then genesis-world without upgrading it.
  if "$VENV/bin/pip" install -q torch==2.13.0 \
     && "$VENV/bin/pip" install -q genesis-world; then
    echo "genesis: $("$VENV/bin/python" -c 'import genesis as gs; print(gs.__version__)' 2>&1 | tail -1)"
  else
    echo "genesis: NOT installed (pip failed; see output above)" >&2
  fi
fi
echo "peers venv: $VENV"
