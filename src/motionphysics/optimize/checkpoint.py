"""``checkpoint.pt``: everything needed to continue an optimisation bit for bit.

A checkpoint holds the unconstrained parameters theta, the Adam state, the random
states (the loop's generator, torch's, NumPy's and Python's global ones), the
iteration to run next, the history so far, the convergence counter and a fingerprint
of the problem so a run is never resumed against a different config. It is written
to a temporary file and renamed, so a kill at any moment leaves either the previous
or the new checkpoint, never a torn one.
"""

from __future__ import annotations

import io
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionphysics.errors import UserInputError
from motionphysics.io.rundir import atomic_write

__all__ = [
    "CHECKPOINT_VERSION",
    "Checkpoint",
    "capture_rng",
    "restore_rng",
    "save_checkpoint",
    "load_checkpoint",
]

CHECKPOINT_VERSION = 1


@dataclass
class Checkpoint:
    next_iteration: int
    """0-based index of the iteration a resumed run executes first."""
    theta: dict[str, torch.Tensor]
    """Unconstrained parameters by leaf name (detached copies)."""
    optimizer: dict[str, Any]
    """``torch.optim.Adam.state_dict()``."""
    rng: dict[str, Any]
    """From :func:`capture_rng`."""
    history: list[dict[str, Any]] = field(default_factory=list)
    """One record per finished iteration (what ``log.jsonl`` holds)."""
    calm: int = 0
    """Consecutive iterations whose relative theta change was below the tolerance."""
    stop_reason: str | None = None
    """None while running; 'iterations', 'converged' or 'nan' once finished."""
    message: str = ""
    fingerprint: str = ""
    """Hash of the problem and the optimisation config the run started with."""
    loss_states: list[dict[str, Any]] = field(default_factory=list)
    """``state_dict()`` of each configured loss, in order (e.g. a learnable extractor)."""
    simulator: dict[str, Any] = field(default_factory=dict)
    """Bookkeeping of the simulator (``substeps`` count and ``changes`` under ``substeps:
    auto``), so a resumed run reports the same re-resolutions as an uninterrupted one."""


def capture_rng(generator: torch.Generator) -> dict[str, Any]:
    """Snapshot of every random state the loop or its plug-ins may draw from."""
    return {
        "generator": generator.get_state(),
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),  # noqa: NPY002 - plug-ins may draw from the global one
        "python": random.getstate(),
    }


def restore_rng(state: dict[str, Any], generator: torch.Generator) -> None:
    generator.set_state(state["generator"])
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])  # noqa: NPY002 - see capture_rng
    random.setstate(state["python"])


def save_checkpoint(ckpt: Checkpoint, path: str | Path) -> None:
    """Write ``ckpt`` atomically (temporary file in the same directory, then rename)."""
    path = Path(path)
    payload = {
        "version": CHECKPOINT_VERSION,
        "next_iteration": ckpt.next_iteration,
        "theta": {k: v.detach().clone() for k, v in ckpt.theta.items()},
        "optimizer": ckpt.optimizer,
        "rng": ckpt.rng,
        "history": ckpt.history,
        "calm": ckpt.calm,
        "stop_reason": ckpt.stop_reason,
        "message": ckpt.message,
        "fingerprint": ckpt.fingerprint,
        "loss_states": list(ckpt.loss_states),
        "simulator": dict(ckpt.simulator),
    }
    # Serialised in memory first: torch's zip writer reports a full disk as a bare
    # RuntimeError; a plain file write keeps the errno (atomic_write -> OutputError).
    buf = io.BytesIO()
    torch.save(payload, buf)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getbuffer())


def load_checkpoint(path: str | Path) -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`; unreadable files are user errors."""
    path = Path(path)
    try:
        # weights_only=False: the payload holds NumPy's RNG state tuple and plain dicts;
        # the file is one this program wrote into the run directory.
        data = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001 - any unreadable file is the same user-facing problem
        raise UserInputError(
            f"{path}: not a readable checkpoint ({type(err).__name__}); "
            "remove it or run with --force"
        ) from None
    if not isinstance(data, dict) or data.get("version") != CHECKPOINT_VERSION:
        raise UserInputError(
            f"{path}: checkpoint version {data.get('version') if isinstance(data, dict) else '?'}"
            f", expected {CHECKPOINT_VERSION}; run with --force to start over"
        )
    return Checkpoint(
        next_iteration=int(data["next_iteration"]),
        theta=data["theta"],
        optimizer=data["optimizer"],
        rng=data["rng"],
        history=list(data["history"]),
        calm=int(data["calm"]),
        stop_reason=data["stop_reason"],
        message=data.get("message", ""),
        fingerprint=data.get("fingerprint", ""),
        loss_states=list(data.get("loss_states") or []),
        simulator=dict(data.get("simulator") or {}),
    )
