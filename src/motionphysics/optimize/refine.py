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

Guidance: ``optimize.guidance`` (``--guidance W``), when given, is the guidance scale of
every configured loss that has a ``guidance`` option and does not set its own in
``optimize.losses``; unset, each loss keeps its own default (lmd / sds: the paper's 100,
flow / video: 6 for the sampled reference). The scale each loss actually used is what
``log.jsonl`` and ``params.json`` record.

Perturbation (LMD, paper Suppl. D): a loss that exposes ``render_perturbation``
(:class:`~motionphysics.losses.lmd.RenderPerturbation`) gets its render from
:class:`PerturbedRenderer`: once per iteration, the object's splat centres move by
``centers · L · N(0, I)`` and every SH coefficient by ``sh · N(0, I)``, the same noise
for every frame of the subsequence, where ``L`` is the largest side of the rest
particles' bounding box [m] (the paper's ε = 0.1 is in a simulation cube in which the
object is normalised to unit size, PhysGaussian's ``transform2origin``). Only the loss
render sees it: the simulation, ``video.mp4`` and ``trajectory.npz`` are rendered and
simulated from the unperturbed scene. The paper perturbs the centres themselves; the
released code uses the perturbed centres only for the SH view direction -- this follows
the paper (the SH view direction uses the unperturbed centre). The noise is drawn from a
generator seeded with ``(optimize.seed, iteration)``, so a resumed run draws the same.

``log.jsonl`` (one line per iteration: loss and components, ``t`` if a loss reports
it, guidance, grad norms, params, substeps, timings) and ``checkpoint.pt`` (theta,
Adam, random states and every loss's ``state_dict()``, so ``--resume`` continues
exactly) are written by the loop; everything else by the caller's writer.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, ClassVar

from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.losses.base import Loss, LossBuildContext, LossContext, Prediction

__all__ = [
    "PerturbedRenderer",
    "WeightedLoss",
    "build_losses",
    "check_prior_path",
    "loss_guidance",
    "run_refinement",
]


class PerturbedRenderer:
    """The loss render with the LMD Gaussian perturbation (see the module docstring).

    Wraps the assembly's :class:`~motionphysics.assembly.SplatRenderer`: ``(xs [S,P,3],
    Fs [S,P,3,3]) -> rgb [S,H,W,3]`` float32 in [0, 1], differentiable in ``xs``/``Fs``.
    Each call is one iteration's render (the loop renders once per iteration): it draws
    ``n_pos [N, 3]`` and ``n_sh [N, K, 3]`` once and uses them for every frame.
    ``calls`` is checkpointed (``state_dict``) so a resumed run continues the sequence.
    """

    def __init__(self, base, perturbation, seed: int):
        import torch

        self.base = base
        self.centers = float(perturbation.centers)
        self.sh = float(perturbation.sh)
        self.seed = int(seed)
        self.calls = 0
        particles = torch.as_tensor(base.sim_scene.particles, dtype=torch.float64)
        self.length = float((particles.max(0).values - particles.min(0).values).max())
        """L [m]: the object's largest side at rest (the unit of the paper's ε)."""
        self.last_noise: tuple | None = None
        """(centre offsets [N,3] m, SH offsets [N,K,3]) of the last call (for tests)."""

    def noise(self, iteration: int):
        """The perturbation of ``iteration``: (centre offsets [N,3] m, SH offsets [N,K,3])."""
        import torch

        splats = self.base.sim_scene.splats
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + int(iteration) + 17)
        n_pos = torch.randn(tuple(splats.means.shape), generator=g, dtype=torch.float32)
        n_sh = torch.randn(tuple(splats.sh.shape), generator=g, dtype=torch.float32)
        return self.centers * self.length * n_pos, self.sh * n_sh

    def __call__(self, xs, Fs):
        import dataclasses

        import torch

        from motionphysics.assembly_scene import static_splats_view
        from motionphysics.render.deform import deform_splats
        from motionphysics.render.rasterize import rasterize

        d_pos, d_sh = self.noise(self.calls)
        self.calls += 1
        self.last_noise = (d_pos, d_sh)
        b = self.base
        scene = b.sim_scene
        splats = dataclasses.replace(scene.splats, sh=scene.splats.sh + d_sh.to(scene.splats.sh))
        parent = scene.splat_parent.long()
        frames = []
        for i in range(xs.shape[0]):
            x = torch.as_tensor(xs[i], dtype=torch.float32)
            F = torch.as_tensor(Fs[i], dtype=torch.float32)
            means, covs, colors = deform_splats(
                splats, x, F, parent, scene.splat_offset.to(x), b.camera
            )
            means = means + d_pos.to(means)
            opac = splats.opacities.to(x)
            if b.ground is not None:  # the ground is not the object: never perturbed
                means = torch.cat([means, b.ground["means"]])
                covs = torch.cat([covs, b.ground["covs"]])
                colors = torch.cat([colors.clamp(0, 1), b.ground["colors"]])
                opac = torch.cat([opac, b.ground["opacities"]])
            static = static_splats_view(scene, b.camera, means)  # scene.region: never perturbed
            if static is not None:
                means = torch.cat([means, static["means"]])
                covs = torch.cat([covs, static["covs"]])
                colors = torch.cat([colors, static["colors"]])
                opac = torch.cat([opac, static["opacities"]])
            frames.append(rasterize(means, covs, colors, opac, b.camera, b.background).rgb)
        return torch.stack(frames)

    # checkpointed with the losses' states (the loop calls these duck-typed)
    def state_dict(self) -> dict:
        return {"perturbation_calls": self.calls}

    def load_state_dict(self, state: dict) -> None:
        self.calls = int(state.get("perturbation_calls", 0))


def loss_guidance(cfg) -> list[dict]:
    """Each configured loss spec's options with ``optimize.guidance`` applied (see above)."""
    from motionphysics.losses import LOSSES

    out = []
    for spec in cfg.optimize.loss_specs():
        options = dict(spec.options())
        model = getattr(LOSSES.get(spec.type), "Options", None)
        fields = getattr(model, "model_fields", {}) if model is not None else {}
        if cfg.optimize.guidance is not None and "guidance" in fields and "guidance" not in options:
            options["guidance"] = float(cfg.optimize.guidance)
        out.append(options)
    return out


def check_prior_path(cfg) -> None:
    """Check ``optimize.prior_path`` holds the prior's diffusers components (exit 2 with
    one line otherwise) before anything is written; priors without a directory layout
    (``motion``) check at load."""
    import importlib

    from motionphysics.priors import PRIORS

    name = cfg.optimize.prior
    if name == "none" or not PRIORS.available(name):
        return  # not refining, or the pipeline's availability check answers
    module = importlib.import_module(PRIORS.get(name).__module__)
    components, hub_id = getattr(module, "COMPONENTS", None), getattr(module, "HUB_ID", None)
    if components is None or hub_id is None:
        return
    from motionphysics.priors.loading import open_model_dir

    path = cfg.optimize.prior_path
    if path is not None and not Path(path).expanduser().exists():
        text = str(path)
        if text.count("/") == 1 and not text.startswith((".", "/", "~")):
            return  # a hub id: resolved (downloaded) when the prior loads
    open_model_dir(path, prior=name, hub_id=hub_id, components=components)


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


def loss_build_context(cfg, parts, prior, out_dir, device) -> LossBuildContext:
    """What the losses of ``cfg`` are built with: the prompt, ``prior``, the run's frames,
    camera size, seed and particle count (``run`` and ``bench iteration`` alike)."""
    return LossBuildContext(
        prompt=cfg.prompt,
        prior=prior,
        num_frames=int(cfg.sim.frames),
        frame_dt=float(cfg.sim.frame_dt),
        out_dir=out_dir,
        device=device,
        seed=int(cfg.optimize.seed),
        height=int(cfg.camera.height),
        width=int(cfg.camera.width),
        num_particles=parts.num_particles,
    )


def build_losses(cfg, ctx: LossBuildContext) -> WeightedLoss:
    """Every entry of ``optimize.losses`` (or ``optimize.loss``) built through the registry."""
    from motionphysics.losses import LOSSES

    terms = []
    for spec, opts in zip(cfg.optimize.loss_specs(), loss_guidance(cfg), strict=True):
        cls = LOSSES.get(spec.type)
        if cls.needs_prior and ctx.prior is None:
            raise UserInputError(
                f"optimize.losses: loss {spec.type!r} needs a video prior but optimize.prior is "
                "none; pass --prior NAME"
            )
        # the prior's own defaults for this loss (VideoPrior.loss_defaults) under the config's
        defaults = dict(getattr(ctx.prior, "loss_defaults", {}).get(spec.type, {}))
        options = LOSSES.options(spec.type, {**defaults, **opts})
        terms.append((spec.type, float(spec.weight), cls.build(options, ctx)))
    return WeightedLoss(terms)


def prior_limits(prior: Any, names: list[str]) -> list[str]:
    """The warnings of the optimised parameters ``names`` (``PARAM`` or ``OBJECT.PARAM``)
    that ``prior`` declares it cannot read from words (``VideoPrior.unreadable``), once
    per parameter."""
    from motionphysics.io.object_params import SEP

    unreadable = getattr(prior, "unreadable", {})
    params = dict.fromkeys(n.rpartition(SEP)[2] for n in names)
    return [unreadable[p] for p in params if p in unreadable]


def _boost_for_prior(cfg, prior):
    """``cfg.optimize`` with the frame boosting capped for the prior (``prior_boost``), and
    a one-line note when the cap changed it (None otherwise)."""
    from motionphysics.optimize.boosting import effective_boost, prior_boost

    frames = int(cfg.sim.frames)
    asked = effective_boost(frames, int(cfg.optimize.boost))
    n = getattr(prior, "num_frames", None)
    if prior is None or n is None:
        return cfg.optimize, None
    m = prior_boost(frames, asked, int(n))
    if m == asked:
        return cfg.optimize, None
    note = (
        f"optimize.boost: {cfg.optimize.boost} -> {m}, so that each of the subsequences of "
        f"the {frames} frames shown to the prior has at least {min(int(n), 16)} frames "
        f"(the prior takes {n})"
    )
    return cfg.optimize.model_copy(update={"boost": m}), note


def _fingerprint(cfg) -> str:
    from motionphysics.config import config_to_dict

    data = config_to_dict(cfg)
    data["optimize"].pop("iterations", None)
    data.pop("versions", None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def _quiet_hub_progress() -> None:
    """Turn off the weight-loading progress bars of transformers and diffusers."""
    for module in ("transformers.utils.logging", "diffusers.utils.logging"):
        try:
            import importlib

            importlib.import_module(module).disable_progress_bar()
        except (ImportError, AttributeError):  # not installed: the prior load reports it
            pass


def scene_context(parts, index=None):
    """The :class:`~motionphysics.priors.base.SceneContext` of an assembly: the rest
    positions of its particles, the ground under them, the gravity and the frame time
    (what a prior that observes states measures the motion against). ``index`` [P_k]
    (long): one object's particles only (its rest state, the ground under it)."""
    import numpy as np
    import torch

    from motionphysics.assembly import _ground_height, _up
    from motionphysics.priors.base import SceneContext

    cfg = parts.cfg
    rest = torch.as_tensor(np.asarray(parts.sim_scene.particles), dtype=torch.float32)
    if index is not None:
        rest = rest.index_select(0, index)
    up = _up(cfg)
    centre = rest.double().mean(0).numpy()
    ground = _ground_height(cfg, centre, up)
    return SceneContext(
        rest=rest,
        ground=None if ground is None else float(ground),
        gravity=tuple(float(v) for v in cfg.sim.gravity),
        frame_dt=float(cfg.sim.frame_dt),
    )


def _states_perturbation(loss, prior) -> dict[str, Any] | None:
    """params.json's ``perturbation`` for an lmd term whose prior observes states."""
    if prior is None or getattr(prior, "observes", "frames") != "states":
        return None
    for _, _, lo in loss.terms:
        p = getattr(lo, "render_perturbation", None)
        if p is not None:
            return {
                "centers_epsilon": p.centers,
                "applies_to": "the observed particle positions and rest state (the prior "
                "observes states; there is no appearance to perturb)",
            }
    return None


def _side_by_side(problem, start, final) -> dict[str, dict[str, Any]]:
    """``{name: {"initial", "final", "unit", "optimised"}}`` of the class's parameters
    (a per-particle final value as ``{"mean", "min", "max"}``)."""
    import numpy as np

    def value(v):
        a = np.asarray(v, dtype=np.float64)
        if a.size == 1:
            return float(a.reshape(()))
        return {"mean": float(a.mean()), "min": float(a.min()), "max": float(a.max())}

    out = {}
    for name, v0 in {"density": start.density, **start.values}.items():
        v1 = final.density if name == "density" else final.values.get(name, v0)
        spec = problem.specs.get(name)
        out[name] = {
            "initial": value(v0),
            "final": value(v1),
            "unit": spec.unit if spec is not None else None,
            "optimised": name in problem.theta_map.names,
        }
    return out


def _per_object_losses(parts, prior, bctx, optimised: set[str]):
    """Several objects and a prior that observes states: the configured losses built
    once per object, each with its phrase (:func:`~.objects.object_prompts`; required
    for the ``optimised`` objects, the others are observed when they have one) and a
    view of the prior that knows that object's rest state, summed by
    :class:`~.objects.PerObjectLoss`. Returns (the loss, ``{object: phrase}``)."""
    from dataclasses import replace

    from motionphysics.optimize.objects import (
        PerObjectLoss,
        object_indices,
        object_prior,
        object_prompts,
    )

    names = [o.name for o in parts.objects]
    phrases = object_prompts(parts.cfg, names, optimised)
    per = []
    for name, idx in zip(names, object_indices(parts), strict=True):
        if name not in phrases:
            continue
        view = object_prior(prior, phrases[name], scene_context(parts, idx))
        ctx = replace(bctx, prompt=phrases[name], prior=view, num_particles=int(idx.numel()))
        per.append((name, idx, build_losses(parts.cfg, ctx)))
    return PerObjectLoss(per), phrases


def run_refinement(parts, writer, *, resume: bool = False, stage=None) -> dict[str, Any]:
    """Optimise theta of ``parts.material`` (an Assembly built with ``needs_grad=True``).

    Returns ``{"material": MaterialParams, "parameters": {name: {initial, final, unit,
    optimised}}, "history": [...], "stop_reason", "message",
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

        _quiet_hub_progress()  # the run's own display shows the stage; no tqdm bars
        prior = load_prior(name, cfg.optimize.prior_path, device=parts.device)
        prior.set_prompt(cfg.prompt)
        if getattr(prior, "observes", "frames") == "states":
            prior.set_scene(scene_context(parts))
    bctx = loss_build_context(cfg, parts, prior, writer.path, parts.device)
    several = parts.objects is not None
    phrases = None
    if several:
        from motionphysics.optimize.objects import build_objects_problem, objects_optimised

        optimised = objects_optimised(cfg, parts.objects)
    if several and prior is not None and getattr(prior, "observes", "frames") == "states":
        # each object's own phrase and particles (optimize.objects)
        loss, phrases = _per_object_losses(parts, prior, bctx, set(optimised))
        weighted = loss.parts[0][2]
    else:
        loss = weighted = build_losses(cfg, bctx)
    if several:
        problem = build_objects_problem(parts, loss, optimised)
    else:
        problem = build_problem(parts, loss)
    stateful = [loss] if phrases is not None else [lo for _, _, lo in loss.terms]
    perturbations = [
        lo.render_perturbation
        for _, _, lo in weighted.terms
        if getattr(lo, "render_perturbation", None) is not None
    ]
    perturbed = None
    if perturbations and problem.renderer is not None and loss.needs_render:
        # One render feeds every loss of the sum: the perturbation of the first loss
        # that asks for one (a second lmd term would share it).
        perturbed = PerturbedRenderer(problem.renderer, perturbations[0], int(cfg.optimize.seed))
        problem.renderer = perturbed
        stateful.append(perturbed)
    guidances = [
        float(getattr(lo, "opts", None).guidance)
        for _, _, lo in weighted.terms
        if hasattr(getattr(lo, "opts", None), "guidance")
    ]
    guidance = guidances[0] if guidances else None
    extras: dict[str, Any] = {"prompt": cfg.prompt, "prior": prior}
    if guidance is not None:
        extras["guidance"] = guidance
    opt_cfg, boost_note = _boost_for_prior(cfg, prior)
    if boost_note:
        writer.observer.message("info", boost_note)
    limits = [*problem.range_notes, *prior_limits(prior, problem.theta_map.names)]
    if limits:
        from motionphysics.assembly_material import warn

        for text in limits:
            warn(text, writer.observer)
    result = optimize(
        problem,
        opt_cfg,
        writer.path,
        resume=resume,
        fingerprint=_fingerprint(cfg),
        progress=(lambda rec: stage.advance()) if stage is not None else None,
        observer=writer.observer,
        extras=extras,
        losses=stateful,
    )
    writer.add_files("log.jsonl", "checkpoint.pt")
    if (writer.path / "prior_reference.mp4").is_file():
        writer.add_files("prior_reference.mp4")
    if several:
        from motionphysics.optimize.objects import final_scene_material, side_by_side

        final = final_scene_material(problem, parts, result.theta)
        parameters = side_by_side(problem, parts.material, final)
    else:
        final = final_material(problem, parts.material, result.theta)
        parameters = _side_by_side(problem, parts.material, final)
    return {
        "material": final,
        "parameters": parameters,
        "history": result.history,
        "stop_reason": result.stop_reason,
        "message": result.message,
        "iterations_run": result.iterations,
        "loss": loss.label,
        "losses": [{"type": n, "weight": w} for n, w, _ in weighted.terms],
        "object_prompts": phrases,
        "prior": name,
        "prior_path": cfg.optimize.prior_path,
        "guidance": guidance,
        "loss_options": {
            n: {
                **lo.opts.model_dump(),
                **(
                    {"negative_prompt_used": lo.negative_prompt}
                    if hasattr(lo, "negative_prompt")
                    else {}
                ),
                **(
                    {
                        "negative_prompt_used_per_object": {
                            obj: getattr(wl.terms[i][2], "negative_prompt", None)
                            for obj, _, wl in loss.parts
                        }
                    }
                    if phrases is not None
                    else {}
                ),
            }
            for i, (n, _, lo) in enumerate(weighted.terms)
            if hasattr(getattr(lo, "opts", None), "model_dump")
        },
        "guidance_per_loss": {
            n: float(lo.opts.guidance)
            for n, _, lo in weighted.terms
            if hasattr(getattr(lo, "opts", None), "guidance")
        },
        "perturbation": _states_perturbation(weighted, prior)
        or (
            {
                "centers_std": perturbed.centers * perturbed.length,
                "centers_epsilon": perturbed.centers,
                "object_size": perturbed.length,
                "sh_std": perturbed.sh,
                "applies_to": "the loss render only",
            }
            if perturbed is not None
            else None
        ),
        "per_particle": list(cfg.optimize.per_particle),
        "grad_mode": cfg.optimize.grad_mode,
        "boost": opt_cfg.boost,
        "boost_requested": cfg.optimize.boost,
        "boost_note": boost_note,
        "prior_limits": limits,
        "optimised": list(problem.theta_map.names),
        "substeps_changes": [list(c) for c in getattr(problem.simulator, "changes", [])],
    }
