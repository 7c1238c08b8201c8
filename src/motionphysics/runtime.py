"""Process-wide runtime setup: devices, threads, Warp initialisation and kernel cache.

Nothing here runs at import time; call the functions. The Warp kernel cache lives in
``$MOTIONPHYSICS_CACHE/warp`` (default ``~/.cache/motionphysics/warp``) because a cold
compile of our kernels costs 12-16 s per module on CPU.
"""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager
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


CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"
"""What Warp's native library writes to file descriptor 2 when it probes CUDA on a
machine without the driver (every CPU machine)."""

_WARP_STATE: dict[str, bool] = {"cuda_driver_missing": False}


@cache
def init_warp(quiet: bool = True):
    """Initialise Warp once, with the kernel cache in :func:`cache_dir`. Returns ``warp``.

    Warp probes CUDA at ``wp.init()`` and, without a driver, its C code prints a warning
    straight to file descriptor 2 on every command of a CPU machine. The probe's output
    is captured and that one line dropped (anything else Warp writes is passed on); a
    missing driver is remembered and reported by :func:`check_device` only when CUDA
    was asked for (``--device cuda``).
    """
    import warp as wp

    wp.config.kernel_cache_dir = str(cache_dir() / "warp")
    # Warp 1.19 prints its banner and "Module ... load" lines to stdout at INFO level,
    # which would corrupt machine-readable output (`--json`): keep it at warnings.
    wp.config.log_level = wp.LOG_WARNING if quiet else wp.LOG_INFO
    text = _capture_fd2(wp.init)
    for line in text.splitlines():
        if CUDA_DRIVER_WARNING in line:
            _WARP_STATE["cuda_driver_missing"] = True
        elif line.strip():
            print(line, file=sys.stderr)
    return wp


def _capture_fd2(fn) -> str:
    """Run ``fn()`` with file descriptor 2 redirected to a temporary file; its text."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable fd 2 (embedded interpreters): run as is
        fn()
        return ""
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            fn()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        return tmp.read().decode("utf-8", errors="replace")


def cuda_driver_present() -> bool:
    """Whether the NVIDIA driver library loads (no CUDA initialisation, no output)."""
    import ctypes

    for name in ("libcuda.so", "libcuda.so.1", "nvcuda.dll"):
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def check_device(device: str) -> Device:
    """Validate a ``--device`` value; ``cuda`` must actually be present."""
    if device not in ("cpu", "cuda"):
        raise UserInputError(f"--device: expected 'cpu' or 'cuda', got {device!r}")
    if device == "cuda":
        import torch

        if _WARP_STATE["cuda_driver_missing"] or not cuda_driver_present():
            raise UserInputError(
                "--device cuda: the NVIDIA CUDA driver (libcuda) is not installed or cannot be "
                "loaded on this machine, so GPU execution is not available; use --device cpu"
            )
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


@contextmanager
def single_thread():
    """Run torch ops on one CPU thread inside the block, then restore the count. For many
    small ops (the renderer's torch work, the motion prior's 0.4M-parameter network on a
    few clips): an OpenMP region per op waits for a free core on a busy shared machine,
    measured up to 50x slower at 2 threads under load (the motion prior's 8 predictions
    of one refinement iteration: 2.5 s at 2 threads, 0.017 s at 1). Yields the count it
    restores."""
    import torch

    n = torch.get_num_threads()
    if n == 1:
        yield n
        return
    torch.set_num_threads(1)
    try:
        yield n
    finally:
        torch.set_num_threads(n)


def set_threads(n: int | None = None) -> int:
    """Set torch's intra-op threads deliberately (default: :func:`default_threads`)."""
    import torch

    if n is None:
        n = default_threads()
    torch.set_num_threads(max(1, int(n)))
    return torch.get_num_threads()
