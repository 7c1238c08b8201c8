"""The torch ↔ Warp autograd bridge: simulate frames as a differentiable torch op.

:func:`simulate` writes torch tensors (sim-unit material parameters, density, initial
velocity, boundary/force parameters) into the Warp arrays of a
:class:`~.build.Simulation`, runs the frames (checkpointed, no tape), and returns the
particle positions and deformation gradients of the requested frames as torch tensors.
In backward, the incoming torch gradients become the frame adjoints of
:meth:`~.rollout.Rollout.backward`, whose parameter gradients come back as torch
gradients. Scalar parameters are broadcast per particle in torch (outside the autograd
Function), so their gradients sum back automatically.

This module owns no physics: it only moves values and gradients across the boundary.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from motionphysics.runtime import init_warp
from motionphysics.sim.model import PARAM_NAMES
from motionphysics.sim.rollout import GradMode


def _wp_to_torch(a) -> torch.Tensor:
    wp = init_warp()
    return wp.to_torch(a).detach().clone().float().cpu()


class _SimulateFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, sim, names, force_names, frames, grad_mode, window, v0, *tensors):
        nparam = len(names)
        values = tensors[:nparam]
        force_values = tensors[nparam:]
        _write(sim, names, values, force_names, force_values, v0)
        rollout = sim.rollout
        need_grad = any(ctx.needs_input_grad[6:])
        res = rollout.forward(
            sim.state0,
            max(frames) + 1,
            keep_checkpoints=need_grad,
            record_tapes=need_grad and grad_mode == "full",
        )
        ctx.sim = sim
        ctx.names = names
        ctx.force_names = force_names
        ctx.frames = frames
        ctx.grad_mode = grad_mode
        ctx.window = window
        ctx.save_for_backward(v0, *tensors)
        xs = torch.from_numpy(res.xs[list(frames)])
        Fs = torch.from_numpy(res.Fs[list(frames)])
        rollout._owner = ctx if need_grad else None
        return xs, Fs

    @staticmethod
    def backward(ctx, gxs, gFs):
        sim = ctx.sim
        model = sim.model
        v0, *tensors = ctx.saved_tensors
        names, force_names = ctx.names, ctx.force_names
        nparam = len(names)
        # Another simulate() call may have overwritten the shared Warp arrays since forward.
        _write(sim, names, tensors[:nparam], force_names, tensors[nparam:], v0)
        rollout = sim.rollout
        if getattr(rollout, "_owner", None) is not ctx:
            rollout.forward(
                sim.state0,
                max(ctx.frames) + 1,
                keep_checkpoints=True,
                check=False,
                record_tapes=ctx.grad_mode == "full",
            )
        adjoints: dict[int, dict[str, Any]] = {}
        for i, f in enumerate(ctx.frames):
            entry = adjoints.setdefault(int(f), {})
            for key, g in (("x", gxs), ("F", gFs)):
                if g is None:
                    continue
                gi = g[i].detach().float().cpu().contiguous().numpy()
                entry[key] = gi if key not in entry else entry[key] + gi
        model.zero_grad()
        if model.boundary is not None:
            model.boundary.zero_param_grads()
        adj0 = rollout.backward(adjoints, grad_mode=ctx.grad_mode, window=ctx.window)
        grads: list[torch.Tensor | None] = []
        grads.append(torch.from_numpy(adj0.v.numpy().copy()) if ctx.needs_input_grad[6] else None)
        for j, name in enumerate(names):
            grads.append(
                _wp_to_torch(model.params[name].grad) if ctx.needs_input_grad[7 + j] else None
            )
        pg = model.boundary.param_grads() if model.boundary is not None else {}
        for j, name in enumerate(force_names):
            if ctx.needs_input_grad[7 + nparam + j]:
                grads.append(torch.from_numpy(pg[name].copy()).reshape(tensors[nparam + j].shape))
            else:
                grads.append(None)
        return (None, None, None, None, None, None, *grads)


def _write(sim, names, values, force_names, force_values, v0) -> None:
    model = sim.model
    for name, t in zip(names, values, strict=True):
        model.params[name].assign(t.detach().float().cpu().contiguous().numpy())
    if force_names:
        model.boundary.set_param_values(
            {
                n: t.detach().float().cpu().numpy()
                for n, t in zip(force_names, force_values, strict=True)
            }
        )
    sim.state0.v.assign(v0.detach().float().cpu().contiguous().numpy())


def simulate(
    sim,
    params: dict[str, torch.Tensor] | None = None,
    frames: Sequence[int] | None = None,
    initial_velocity: torch.Tensor | None = None,
    forces: dict[str, torch.Tensor] | None = None,
    grad_mode: GradMode = "full",
    window: int = 8,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable rollout of ``sim`` (a :class:`~.build.Simulation`).

    Args:
        sim: the simulation (its model must be built with ``requires_grad=True``).
        params: sim-unit material values by name (``E nu tau_Y eta theta_fric mu kappa n
            density``), each a scalar tensor (scene-wide) or shape [P] (per particle).
            Parameters not given keep the model's values (and get no gradient).
        frames: frame indices to return (0 = initial state); default ``range(sim.frames)``.
            Frame boosting passes a subset; the rollout runs up to ``max(frames)``.
        initial_velocity: [3] or [P, 3] m/s (default: the current initial velocity).
        forces: boundary/force parameters by ``BoundaryParam.name`` (e.g.
            ``"forces[0].force"``), tensors of their size.
        grad_mode: ``full`` (checkpointed, through all substeps), ``window`` (last
            ``window`` substeps before each returned frame), ``last_substep``.

    Returns:
        ``xs`` [len(frames), P, 3] positions [m] and ``Fs`` [len(frames), P, 3, 3], float32.
    """
    model = sim.model
    p = model.particle_count
    params = dict(params or {})
    for name in params:
        if name not in PARAM_NAMES:
            raise KeyError(f"unknown sim parameter {name!r}; expected one of {PARAM_NAMES}")
    frames = tuple(int(f) for f in (range(sim.frames) if frames is None else frames))
    if not frames or min(frames) < 0:
        raise ValueError("frames must be a non-empty list of indices >= 0")
    names = tuple(sorted(params))
    values = []
    for name in names:
        t = torch.as_tensor(params[name], dtype=torch.float32)
        values.append(t.reshape(1).expand(p) if t.numel() == 1 else t.reshape(p))
    if initial_velocity is None:
        v0 = torch.from_numpy(sim.state0.v.numpy().copy())
    else:
        v = torch.as_tensor(initial_velocity, dtype=torch.float32)
        v0 = v.reshape(1, 3).expand(p, 3) if v.numel() == 3 else v.reshape(p, 3)
    forces = dict(forces or {})
    force_names = tuple(sorted(forces))
    if force_names and model.boundary is None:
        raise KeyError("forces given but the simulation has no boundary program")
    force_values = [torch.as_tensor(forces[n], dtype=torch.float32) for n in force_names]
    if (
        torch.is_grad_enabled()
        and any(t.requires_grad for t in (v0, *values, *force_values))
        and not model.requires_grad
    ):
        raise ValueError("build the simulation with requires_grad=True to differentiate it")
    return _SimulateFn.apply(
        sim, names, force_names, frames, grad_mode, int(window), v0, *values, *force_values
    )
