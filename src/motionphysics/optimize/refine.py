"""The refinement stage of ``run``: theta of the estimated material, optimised against
the configured losses (a video prior's LMD / SDS / flow, or any registered loss).

:func:`run_refinement` is what :mod:`motionphysics.pipeline` calls when
``optimize.prior != none`` (or a prior-free loss list is given): it loads the prior
(``load_prior(name, optimize.prior_path, device=...)``, ``prior.set_prompt(prompt)``),
builds each entry of ``optimize.losses`` through the registry
(``LOSSES.get(type).build(LOSSES.options(type, options), LossBuildContext(...))``),
combines them with their weights (:class:`WeightedLoss`), and runs the optimisation
loop (:mod:`.loop`) over theta of the estimated class, starting from the estimate,
on the assembly's simulator and renderer. Frame boosting renders each interleaved
subsequence at the config camera; a prior's ``encode`` resamples it to
``prior.num_frames`` and resizes it to ``prior.height x prior.width``. Gradients flow
through every substep by default (``optimize.grad_mode``).

``log.jsonl`` (one line per iteration: loss and components, ``t`` if a loss reports
it, guidance, grad norms, params, substeps, timings) and ``checkpoint.pt`` (theta,
Adam, random states and every loss's ``state_dict()``, so ``--resume`` continues
exactly) are written by the loop; everything else by the caller's writer.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, ClassVar

from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction

__all__ = ["WeightedLoss", "build_losses", "run_refinement"]


class WeightedLoss(Loss):
    """``sum_i w_i L_i`` of built losses; components are each loss's value and parts."""

    name: ClassVar[str] = "weighted"

    def __init__(self, terms: list[tuple[str, float, Loss]]):
        if not terms:
            raise ValueError("WeightedLoss needs at least one loss")
        self.terms = terms
        self._last: dict[str, float] = {}

    @property
    def needs_render(self) -> bool:  # type: ignore[override]
        return any(lo.needs_render for _, _, lo in self.terms)

    @property
    def needs_states(self) -> bool:  # type: ignore[override]
        return any(lo.needs_states for _, _, lo in self.terms)

    @property
    def label(self) -> str:
        """``lmd`` for one loss, ``1*lmd+0.1*flow`` for several."""
        if len(self.terms) == 1:
            return self.terms[0][0]
        return "+".join(f"{w:g}*{n}" for n, w, _ in self.terms)

    def __call__(self, pred: Prediction, ctx: LossContext) -> Tensor:
        total = None
        parts: dict[str, float] = {}
        for name, weight, loss in self.terms:
            value = loss(pred, ctx)
            parts[name] = float(value.detach())
            for k, v in loss.components().items():
                parts[f"{name}_{k}" if len(self.terms) > 1 else k] = v
            term = weight * value
            total = term if total is None else total + term
        self._last = (
            parts
            if len(self.terms) > 1
            else {k: v for k, v in parts.items() if k != self.terms[0][0]}
        )
        return total

    def components(self) -> dict[str, float]:
        return dict(self._last)

    def state_dict(self) -> dict:
        return {"terms": [lo.state_dict() for _, _, lo in self.terms]}

    def load_state_dict(self, state: dict) -> None:
        for (_, _, lo), st in zip(self.terms, state.get("terms", []), strict=False):
            lo.load_state_dict(st)


def build_losses(cfg, ctx: LossBuildContext) -> WeightedLoss:
    """Every entry of ``optimize.losses`` (or ``optimize.loss``) built through the registry."""
    from motionphysics.losses import LOSSES

    terms = []
    for spec in cfg.optimize.loss_specs():
        cls = LOSSES.get(spec.type)
        if cls.needs_prior and ctx.prior is None:
            raise UserInputError(
                f"optimize.losses: loss {spec.type!r} needs a video prior but optimize.prior is "
                "none; pass --prior NAME"
            )
        options = LOSSES.options(spec.type, spec.options())
        terms.append((spec.type, float(spec.weight), cls.build(options, ctx)))
    return WeightedLoss(terms)


def _fingerprint(cfg) -> str:
    from motionphysics.config import config_to_dict

    data = config_to_dict(cfg)
    data["optimize"].pop("iterations", None)
    data.pop("versions", None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def run_refinement(parts, writer, *, resume: bool = False, stage=None) -> dict[str, Any]:
    """Optimise theta of ``parts.material`` (an Assembly built with ``needs_grad=True``).

    Returns ``{"material": MaterialParams, "history": [...], "stop_reason", "message",
    "iterations_run", "loss", "losses", "prior", "grad_mode", "boost", "optimised",
    "substeps_changes"}`` (the caller records it in params.json as ``optimise``).
    """
    from motionphysics.optimize.fit import build_problem, final_material
    from motionphysics.optimize.loop import optimize

    cfg = parts.cfg
    prior = None
    name = cfg.optimize.prior
    if name != "none":
        from motionphysics.priors import load_prior

        prior = load_prior(name, cfg.optimize.prior_path, device=parts.device)
        prior.set_prompt(cfg.prompt)
    bctx = LossBuildContext(
        prompt=cfg.prompt,
        prior=prior,
        num_frames=int(cfg.sim.frames),
        frame_dt=float(cfg.sim.frame_dt),
        out_dir=writer.path,
        device=parts.device,
        seed=int(cfg.optimize.seed),
        height=int(cfg.camera.height),
        width=int(cfg.camera.width),
        num_particles=parts.num_particles,
    )
    loss = build_losses(cfg, bctx)
    problem = build_problem(parts, loss)
    result = optimize(
        problem,
        cfg.optimize,
        writer.path,
        resume=resume,
        fingerprint=_fingerprint(cfg),
        progress=(lambda rec: stage.advance()) if stage is not None else None,
        observer=writer.observer,
        extras={"prompt": cfg.prompt, "prior": prior, "guidance": float(cfg.optimize.guidance)},
        losses=[lo for _, _, lo in loss.terms],
    )
    writer.add_files("log.jsonl", "checkpoint.pt")
    return {
        "material": final_material(problem, parts.material, result.theta),
        "history": result.history,
        "stop_reason": result.stop_reason,
        "message": result.message,
        "iterations_run": result.iterations,
        "loss": loss.label,
        "losses": [{"type": n, "weight": w} for n, w, _ in loss.terms],
        "prior": name,
        "prior_path": cfg.optimize.prior_path,
        "guidance": float(cfg.optimize.guidance),
        "grad_mode": cfg.optimize.grad_mode,
        "boost": cfg.optimize.boost,
        "optimised": list(problem.theta_map.names),
        "substeps_changes": [list(c) for c in getattr(problem.simulator, "changes", [])],
    }
