#!/usr/bin/env bash
# One prepared GPU check (`make gpu-check`): a thin wrapper around benchmarks/gpu_check.py,
# which holds the logic and picks the Python that runs the parts (one whose torch sees a
# CUDA device). This only finds an interpreter to start it with: its standard library is
# enough. Without a CUDA device the check prints one line and exits 0.
set -u
cd "$(dirname "$0")/.." || exit 1
if [ -x .venv/bin/python ]; then
    PY=.venv/bin/python
elif command -v python3 >/dev/null 2>&1; then
    PY=python3
else
    echo "gpu-check: no Python here (neither .venv/bin/python nor python3); nothing run."
    exit 1
fi
exec "$PY" benchmarks/gpu_check.py "$@"
