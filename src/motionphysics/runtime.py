"""Process-wide runtime setup: devices, threads, Warp initialisation and kernel cache.

Nothing here runs at import time; call the functions. The Warp kernel cache lives in
``$MOTIONPHYSICS_CACHE/warp`` (default ``~/.cache/motionphysics/warp``) because a cold
compile of our kernels costs 12-16 s per module on CPU.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path
from typing import Literal

from motionphysics.errors import UserInputError

Device = Literal["cpu", "cuda"]


def cache_dir() -> Path:
    """Root of the project's on-disk caches (Warp kernels, downloaded-nothing)."""
    root = os.environ.get("MOTIONPHYSICS_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "motionphysics"
    path.mkdir(parents=True, exist_ok=True)
    return path


@cache
def init_warp(quiet: bool = True):
    """Initialise Warp once, with the kernel cache in :func:`cache_dir`. Returns ``warp``."""
    import warp as wp

    wp.config.kernel_cache_dir = str(cache_dir() / "warp")
    # Warp 1.19 prints its banner and "Module ... load" lines to stdout at INFO level,
    # which would corrupt machine-readable output (`--json`): keep it at warnings.
    wp.config.log_level = wp.LOG_WARNING if quiet else wp.LOG_INFO
    wp.init()
    return wp


def check_device(device: str) -> Device:
    """Validate a ``--device`` value; ``cuda`` must actually be present."""
    if device not in ("cpu", "cuda"):
        raise UserInputError(f"--device: expected 'cpu' or 'cuda', got {device!r}")
    if device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise UserInputError(
                "--device cuda: no CUDA device is visible to PyTorch on this machine; use --device cpu"
            )
    return device  # type: ignore[return-value]


THREADS_ENV = "MOTIONPHYSICS_THREADS"
"""Environment variable that caps the default thread count (``motionphysics batch`` sets it per job)."""


def default_threads() -> int:
    """Threads a command uses by default: ``$MOTIONPHYSICS_THREADS``, else
    ``$OMP_NUM_THREADS``, else all cores (at most 8).

    The environment wins so that N parallel jobs (``motionphysics batch``, a cluster
    scheduler) can each be given their share of the machine instead of all of it.
    """
    for name in (THREADS_ENV, "OMP_NUM_THREADS"):
        value = os.environ.get(name, "").strip()
        if value:
            try:
                n = int(value)
            except ValueError:
                raise UserInputError(
                    f"${name}: expected a positive integer thread count, got {value!r}"
                ) from None
            if n < 1:
                raise UserInputError(f"${name}: expected a positive integer, got {value!r}")
            return n
    return min(os.cpu_count() or 1, 8)


def set_threads(n: int | None = None) -> int:
    """Set torch's intra-op threads deliberately (default: :func:`default_threads`)."""
    import torch

    if n is None:
        n = default_threads()
    torch.set_num_threads(max(1, int(n)))
    return torch.get_num_threads()
