"""The optimisation loop: boosted subsequence -> simulate -> render -> loss -> Adam.

One iteration:

1. pick the supervised frames (frame boosting, :mod:`.boosting`);
2. map theta to physical and simulation values and run the differentiable simulator
   through every substep up to the last supervised frame (gradients as ``grad_mode``);
3. render those frames when the loss needs pixels; evaluate the loss;
4. backpropagate to theta; stop cleanly (no step) if the loss or a gradient is not
   finite or the simulation diverged;
5. one Adam step with per-parameter learning rates under the warm-up + cosine
   schedule (:mod:`.schedule`);
6. append one line to ``log.jsonl`` and rewrite ``checkpoint.pt``.

The run stops after ``iterations``, or early once the relative change of theta
(``|d theta| / max(|theta|, 1)``, all leaves together) stays below
``optimize.tolerance`` for 3 consecutive iterations after warm-up.

``resume=True`` continues from ``checkpoint.pt``: theta, the Adam moments, the random
states and the history are restored, and log lines written after that checkpoint (a
kill between the log append and the checkpoint) are dropped, so a killed-and-resumed
run takes exactly the steps of an uninterrupted one.

This module writes only ``log.jsonl`` and ``checkpoint.pt`` in the given directory;
the caller writes everything else of the run directory.
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from motionphysics.config import OptimizeConfig
from motionphysics.errors import SimulationError, UserInputError
from motionphysics.losses.base import LossContext
from motionphysics.optimize.boosting import frames_for_iteration
from motionphysics.optimize.checkpoint import (
    Checkpoint,
    capture_rng,
    load_checkpoint,
    restore_rng,
    save_checkpoint,
)
from motionphysics.optimize.problem import Problem
from motionphysics.optimize.schedule import learning_rates
from motionphysics.runtime import single_thread

__all__ = [
    "CALM_ITERATIONS",
    "LOG_NAME",
    "CHECKPOINT_NAME",
    "OptimizeResult",
    "horizon",
    "optimize",
]

LOG_NAME = "log.jsonl"
CHECKPOINT_NAME = "checkpoint.pt"
CALM_ITERATIONS = 3
"""Consecutive small-change iterations that count as convergence."""
ADAM_EPS = 1e-12
"""Adam's epsilon. Trajectory losses are in m^2 and their gradients can be ~1e-8; the
usual 1e-8 would then shrink every step, so it is set far below any real gradient."""


@dataclass
class OptimizeResult:
    theta: dict[str, Tensor]
    """Final unconstrained parameters (detached)."""
    params: dict[str, Any]
    """Final physical values (JSON-able; see :meth:`Problem.report`)."""
    sim_params: dict[str, Any]
    """Final simulation values (JSON-able)."""
    history: list[dict[str, Any]]
    """One record per iteration (the lines of ``log.jsonl``)."""
    stop_reason: str
    """'iterations', 'converged' or 'nan'."""
    message: str
    iterations: int
    """Iterations completed (steps taken)."""


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _truncate_log(path: Path, next_iteration: int) -> None:
    """Keep only log lines of iterations before ``next_iteration``."""
    from motionphysics.io.rundir import atomic_write

    if not path.exists():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            break  # a torn last line from a kill mid-write
        if int(rec.get("iteration", -1)) < next_iteration:
            kept.append(line)
    with atomic_write(path, "w") as fh:
        fh.write("".join(k + "\n" for k in kept))


def _clean(obj: Any) -> Any:
    """JSON has no NaN/inf: write them as null."""
    if isinstance(obj, float):
        return _finite(obj)
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def _append_log(path: Path, record: dict[str, Any]) -> None:
    from motionphysics.io.rundir import output_errors

    with output_errors(path), open(path, "a") as fh:
        fh.write(json.dumps(_clean(record), allow_nan=False) + "\n")
        fh.flush()
        os.fsync(fh.fileno())


def horizon(iteration: int, total: int, num_frames: int, curriculum: float) -> int:
    """Frames (indices ``0 .. h-1``) the loss may see at 0-based ``iteration``.

    Grows linearly from ``max(2, num_frames // 4 + 1)`` to ``num_frames`` over the first
    ``ceil(curriculum * total)`` iterations; ``num_frames`` after (and for
    ``curriculum`` 0).
    """
    ramp = math.ceil(curriculum * total)
    if ramp <= 0 or iteration >= ramp:
        return num_frames
    h0 = min(num_frames, max(2, num_frames // 4 + 1))
    return int(h0 + (num_frames - h0) * iteration // ramp)


def _simulator_state(simulator: Any) -> dict[str, Any]:
    """The simulator's bookkeeping worth keeping across a resume (duck-typed: the
    assembly's BridgeSimulator has ``substeps`` and ``changes``; test doubles need not)."""
    state: dict[str, Any] = {}
    if isinstance(getattr(simulator, "changes", None), list):
        state["changes"] = [list(c) for c in simulator.changes]
    if getattr(simulator, "simulation", None) is not None and hasattr(simulator, "substeps"):
        state["substeps"] = int(simulator.substeps)
    return state


def _restore_simulator(simulator: Any, state: dict[str, Any]) -> None:
    """Put back :func:`_simulator_state`: the count the last iteration ran with (so the
    first resumed iteration re-resolves from it, as the uninterrupted run did) and the
    list of changes so far. The numbers do not depend on it (the count is a function of
    the current parameters); the record of re-resolutions does."""
    if "changes" in state and isinstance(getattr(simulator, "changes", None), list):
        simulator.changes[:] = [tuple(c) for c in state["changes"]]
    sim = getattr(simulator, "simulation", None)
    n = state.get("substeps")
    if sim is not None and n is not None and int(sim.substeps) != int(n):
        sim.substeps = int(n)
        sim._rollout = None  # rebuilt with the restored count (as BridgeSimulator._retime)


def _flat(theta: dict[str, Tensor]) -> Tensor:
    return torch.cat([t.detach().reshape(-1).double() for t in theta.values()])


def iteration_threads(loss):
    """The torch threads of one iteration (forward, loss, backward) as a context: a loss on
    the simulated states (a trajectory, the motion prior) is many small torch ops, so one
    torch thread (:func:`motionphysics.runtime.single_thread`; the simulation keeps its own
    threads); a loss on rendered frames keeps the count set (a video prior's network).
    With 2 threads on a busy 2-core machine the motion prior's 8 predictions of one
    iteration took 2.5 s instead of 0.017 s (BENCHMARKS.md, issue 26)."""
    return nullcontext() if loss.needs_render else single_thread()


def optimize(
    problem: Problem,
    cfg: OptimizeConfig,
    out_dir: str | Path,
    *,
    iterations: int | None = None,
    resume: bool = False,
    fingerprint: str = "",
    progress: Callable[[dict[str, Any]], None] | None = None,
    observer: Any = None,
    extras: dict[str, Any] | None = None,
    losses: Any = None,
    curriculum: float = 0.0,
    stage: str | None = None,
    keep_log: bool = False,
) -> OptimizeResult:
    """Run (or continue) the optimisation of ``problem``; see the module docstring.

    iterations: total iterations (default ``cfg.iterations``).
    fingerprint: identifies the problem and config; resuming a checkpoint with a
    different fingerprint is refused.
    progress: called with each iteration's record.
    observer: an :class:`~motionphysics.events.Observer`; told ``iteration_done``.
    extras: put in every :class:`LossContext` (``prompt``, ``prior``: what a
    prior-driven loss reads).
    losses: objects with ``state_dict()`` / ``load_state_dict()`` (the configured
    losses) whose state goes into ``checkpoint.pt`` and comes back on resume; default
    ``problem.loss``.
    curriculum: fraction of ``iterations`` over which the supervised horizon grows
    (:func:`horizon`): early frames first, all frames after.
    stage: written as ``"stage"`` in every record (``fit``: ``"gradient"``).
    keep_log: keep the records of ``log.jsonl`` with negative ``iteration`` (an earlier
    stage's, e.g. the global stage of ``fit``) instead of starting a fresh log.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log_path, ckpt_path = out / LOG_NAME, out / CHECKPOINT_NAME
    total = cfg.iterations if iterations is None else int(iterations)
    num_frames = problem.simulator.num_frames
    if num_frames < 2:
        raise UserInputError(
            "sim.frames: optimisation needs at least 2 frames (frame 0 is the initial state)"
        )

    generator = torch.Generator()
    generator.manual_seed(cfg.seed)
    theta = problem.initial_theta()
    names = problem.leaf_names
    unknown_lr = sorted(set(cfg.lr_per_param) - set(names))
    if unknown_lr:
        raise UserInputError(
            f"optimize.lr_per_param: {', '.join(unknown_lr)} not optimised; expected names among "
            f"{', '.join(names)}"
        )
    opt = torch.optim.Adam(
        [{"params": [theta[n]], "lr": cfg.lr, "name": n} for n in names], lr=cfg.lr, eps=ADAM_EPS
    )
    start, history, calm = 0, [], 0
    stateful = list(losses) if losses is not None else [problem.loss]

    if resume and ckpt_path.exists():
        ck = load_checkpoint(ckpt_path)
        if ck.fingerprint != fingerprint:
            raise UserInputError(
                f"{ckpt_path}: this checkpoint belongs to a different config or reference; "
                "use --force to start over"
            )
        if sorted(ck.theta) != sorted(names) or any(
            ck.theta[n].shape != theta[n].shape for n in names
        ):
            raise UserInputError(
                f"{ckpt_path}: checkpoint optimises {sorted(ck.theta)}, the config {names}; "
                "use --force to start over"
            )
        with torch.no_grad():
            for n in names:
                theta[n].copy_(ck.theta[n])
        opt.load_state_dict(ck.optimizer)
        for i, state in enumerate(ck.loss_states or []):
            if i < len(stateful) and state:
                stateful[i].load_state_dict(state)
        restore_rng(ck.rng, generator)
        _restore_simulator(problem.simulator, ck.simulator)
        start, history, calm = ck.next_iteration, ck.history, ck.calm
        _truncate_log(log_path, start)
        if ck.stop_reason == "converged" or start >= total:
            params, sim_params = problem.report(theta)
            return OptimizeResult(
                {k: v.detach().clone() for k, v in theta.items()},
                params,
                sim_params,
                history,
                ck.stop_reason or "iterations",
                ck.message or "already finished",
                start,
            )
    else:
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed % 2**32)  # noqa: NPY002 - seeds plug-ins that use the global RNG
        random.seed(cfg.seed)
        if keep_log:
            _truncate_log(log_path, 0)
        else:
            log_path.unlink(missing_ok=True)

    stop_reason: str | None = None
    message = ""
    it = start
    for it in range(start, total):
        frames = frames_for_iteration(it, num_frames, cfg.boost)
        h = horizon(it, total, num_frames, curriculum)
        if h < num_frames:
            # Early frames first: the boosted frames inside the horizon (all of the
            # horizon's frames when none of the subsequence's is inside it).
            frames = tuple(f for f in frames if f < h) or tuple(range(1, h))
        lrs = learning_rates(names, cfg.lr, cfg.lr_per_param, it, total, cfg.warmup)
        for group in opt.param_groups:
            group["lr"] = lrs[group["name"]]
        params_now, sim_now = problem.report(theta)
        timings: dict[str, float] = {}
        t_start = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        loss_value = float("nan")
        try:
            with iteration_threads(problem.loss):
                pred = problem.forward(theta, frames, cfg.grad_mode, cfg.window, timings)
                t0 = time.perf_counter()
                loss = problem.loss(
                    pred,
                    LossContext(
                        iteration=it,
                        num_frames=num_frames,
                        rng=generator,
                        extras=dict(extras or {}),
                    ),
                )
                loss_value = float(loss.detach())
                timings["loss"] = time.perf_counter() - t0
                t0 = time.perf_counter()
                if math.isfinite(loss_value):
                    loss.backward()
                timings["backward"] = time.perf_counter() - t0
        except SimulationError as err:
            stop_reason = "nan"
            message = (
                f"iteration {it}: the simulation diverged ({err}); stopped with the parameters "
                "of the previous iteration. Lower optimize.lr or raise sim.substeps."
            )
        grads = {
            n: (theta[n].grad if theta[n].grad is not None else torch.zeros_like(theta[n]))
            for n in names
        }
        grad_norm = {n: float(g.detach().double().norm()) for n, g in grads.items()}
        grad_norm["total"] = float(math.sqrt(sum(v * v for v in grad_norm.values())))
        record: dict[str, Any] = {
            "iteration": it,
            **({"stage": stage} if stage else {}),
            "loss": _finite(loss_value),
            **{f"loss_{k}": v for k, v in problem.loss.components().items()},
            "frames": list(frames),
            "params": params_now,
            "sim_params": sim_now,
            "grad_norm": {k: _finite(v) for k, v in grad_norm.items()},
            "lr": lrs,
        }
        comps = problem.loss.components()
        if "t" in comps:
            record["t"] = comps["t"]  # the diffusion timestep a prior loss drew
        if extras and "guidance" in extras:
            record["guidance"] = extras["guidance"]
        substeps = getattr(problem.simulator, "substeps", None)
        if h < num_frames:
            record["horizon"] = h
        if substeps is not None:
            # Under ``substeps: auto`` the simulator re-resolves the count for the
            # parameters of this iteration (logged, so a change is visible).
            record["substeps"] = int(substeps)
        if stop_reason is None and not (
            math.isfinite(loss_value) and math.isfinite(grad_norm["total"])
        ):
            what = "loss" if not math.isfinite(loss_value) else "gradient"
            stop_reason = "nan"
            message = (
                f"iteration {it}: the {what} is not finite; stopped with the parameters of the "
                "previous iteration. Lower optimize.lr or raise sim.substeps."
            )
        if stop_reason == "nan":
            record["stopped"] = "nan"
            record["time"] = {**timings, "total": time.perf_counter() - t_start}
            _append_log(log_path, record)
            history.append(record)
            save_checkpoint(
                Checkpoint(
                    it,
                    theta,
                    opt.state_dict(),
                    capture_rng(generator),
                    history[:-1],
                    calm,
                    "nan",
                    message,
                    fingerprint,
                    [lo.state_dict() for lo in stateful],
                    _simulator_state(problem.simulator),
                ),
                ckpt_path,
            )
            break

        before = _flat(theta)
        t0 = time.perf_counter()
        opt.step()
        timings["step"] = time.perf_counter() - t0
        after = _flat(theta)
        change = float((after - before).norm() / max(float(before.norm()), 1.0))
        calm = calm + 1 if (change < cfg.tolerance and it >= cfg.warmup) else 0
        record["theta_change"] = change
        record["time"] = {**timings, "total": time.perf_counter() - t_start}
        _append_log(log_path, record)
        history.append(record)
        if calm >= CALM_ITERATIONS:
            stop_reason = "converged"
            message = (
                f"converged after {it + 1} iterations (theta changed by less than "
                f"{cfg.tolerance:g} for {CALM_ITERATIONS} iterations)"
            )
        elif it + 1 >= total:
            stop_reason = "iterations"
            message = f"finished {total} iterations"
        save_checkpoint(
            Checkpoint(
                it + 1,
                theta,
                opt.state_dict(),
                capture_rng(generator),
                history,
                calm,
                stop_reason,
                message,
                fingerprint,
                [lo.state_dict() for lo in stateful],
                _simulator_state(problem.simulator),
            ),
            ckpt_path,
        )
        if progress is not None:
            progress(record)
        if observer is not None:
            observer.iteration_done(it, record)
        if stop_reason is not None:
            break

    if stop_reason is None:
        stop_reason, message = "iterations", f"finished {total} iterations"
    completed = sum(1 for r in history if "stopped" not in r)
    params, sim_params = problem.report(theta)
    return OptimizeResult(
        {k: v.detach().clone() for k, v in theta.items()},
        params,
        sim_params,
        history,
        stop_reason,
        message,
        completed,
    )
