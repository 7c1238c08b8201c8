"""System identification: fit a config's material to a reference video or trajectory.

The library side of ``motionphysics fit`` (the command is argument handling only).
The config gives the scene, forces, boundary conditions, camera and the *starting*
material; the reference is either a video rendered from the same camera (.mp4 / .gif,
or .npz with ``frames`` [T,H,W,3] and optionally ``mask`` [T,H,W]), fitted with
``video_match``, or a trajectory (.npz with ``x`` [T,P,3], as ``motionphysics
simulate`` writes), fitted with ``trajectory_match``.

What is optimised: theta of the *physical* parameters (``optimize.params``, default
all of the class's but Poisson's ratio, :data:`FIT_DEFAULT_FIXED`, and density),
mapped through the catalogue's ``Parameterisation`` (bounded by the handbook ranges) and then through the assembly's
sim map (:func:`motionphysics.assembly.sim_values`, differentiable) into simulation
values. The simulation is the assembly's: the same config and parameters give the
trajectory ``simulate`` gives, bit for bit; under ``substeps: auto`` the substep count
follows the current parameters (re-resolved before each iteration's rollout and
logged as ``substeps`` in ``log.jsonl``).

The run directory is written by :class:`motionphysics.io.writer.RunWriter`: the same
params.json schema, report.html, scene.ply and plots as ``run``, plus log.jsonl and
checkpoint.pt. ``resume=True`` continues a killed fit from checkpoint.pt and ends with
the same parameters as an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import SimulationError, UserInputError

__all__ = [
    "FitSetup",
    "GlobalResult",
    "global_search",
    "Reference",
    "build_fit",
    "build_problem",
    "load_reference",
    "optimised_names",
    "run_fit",
]

from motionphysics.io.reference import Reference, load_reference  # noqa: F401 - re-exported


@dataclass
class FitSetup:
    """Everything a fit needs, built once from the config and the reference."""

    parts: Any
    """The :class:`~motionphysics.assembly.Assembly` (scene, camera, material, simulation)."""
    names: list[str]
    """Optimised physical parameter names."""
    problem: Any
    """The :class:`~motionphysics.optimize.Problem`."""
    reference: Reference
    kept: str | None = None
    """The one line saying which parameters the default left at the config's value."""

    @property
    def cfg(self):
        return self.parts.cfg

    @property
    def material(self):
        return self.parts.material

    @property
    def sim_scene(self):
        return self.parts.sim_scene

    @property
    def simulation(self):
        return self.parts.simulation

    @property
    def sim_context(self):
        return self.parts.resolution.context


FIT_DEFAULT_FIXED = ("nu",)
"""Parameters ``fit`` leaves at the config's value unless ``optimize.params`` names them:
Poisson's ratio barely changes a drop's motion, so fitted with E it drifts (0.4 -> 0.155
on a reference made with 0.4) while E compensates."""


def optimised_names(cfg, cls: str, fixed: tuple[str, ...] = ()) -> list[str]:
    """``optimize.params`` checked against the class (default: all of its parameters
    except ``fixed``)."""
    from motionphysics.materials.catalog import MATERIALS

    allowed = MATERIALS[cls].names
    if cfg.optimize.params is not None:
        names = list(cfg.optimize.params)
    else:
        names = [n for n in allowed if n not in fixed] or list(allowed)
    bad = [n for n in names if n not in (*allowed, "density")]
    if bad or not names:
        raise UserInputError(
            f"optimize.params: {', '.join(bad) or '(empty)'} not parameters of class {cls}; "
            f"expected names among {', '.join(allowed)} (or density)"
        )
    bad = [n for n in cfg.optimize.per_particle if n not in names]
    if bad:
        raise UserInputError(
            f"optimize.per_particle: {', '.join(bad)} not among the optimised "
            f"parameters ({', '.join(names)})"
        )
    return names


def start_ranges(
    cls: str, names, start: dict[str, float], label=lambda n: n
) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """The ranges of the optimised ``names`` that must be widened to hold their ``start``
    values (a value a person wrote outside the handbook range is used as written, so its
    refinement starts there), and one line per widened range saying so.

    Returns ``({name: (low, high)}, lines)``; names whose start lies in the handbook
    range keep it (absent from the dict). ``label(name)`` names a parameter in the lines.
    """
    from motionphysics.materials.catalog import _fmt, spec

    ranges: dict[str, tuple[float, float]] = {}
    lines = []
    for n in names:
        ps, x = spec(cls, n), float(start[n])
        tol = 1e-9 * max(abs(ps.low), abs(ps.high))
        if ps.low - tol <= x <= ps.high + tol:
            continue
        lo, hi = min(ps.low, x), max(ps.high, x)
        ranges[n] = (lo, hi)
        unit = "" if ps.unit == "1" else f" {ps.unit}"
        lines.append(
            f"optimize: {label(n)} starts at {_fmt(x)}{unit}, outside the handbook range of "
            f"{cls} ({ps.range_text()}); it is refined within {_fmt(lo)} - {_fmt(hi)}{unit}"
        )
    return ranges, lines


def build_problem(parts, loss, names: list[str] | None = None):
    """The optimisation :class:`~motionphysics.optimize.Problem` of an assembly.

    theta of the physical ``names`` (default ``optimize.params``) through the
    catalogue's Parameterisation, the assembly's sim map, its differentiable simulator
    and (when the loss looks at pixels) its renderer.
    """
    from motionphysics.materials.catalog import spec
    from motionphysics.materials.theta import Parameterisation
    from motionphysics.optimize.problem import ParamSpec, Problem

    cfg, material = parts.cfg, parts.material
    cls = material.cls
    names = names or optimised_names(cfg, cls)
    start = {
        "density": float(material.density),
        **{k: float(v) for k, v in material.values.items()},
    }
    ranges, notes = start_ranges(cls, names, start)
    specs = {}
    for n in names:
        ps = spec(cls, n)
        lo, hi = ranges.get(n, (float(ps.low), float(ps.high)))
        specs[n] = ParamSpec(n, ps.unit, lo, hi, ps.scale)
    return Problem(
        theta_map=Parameterisation(cls, names, ranges=ranges),
        range_notes=notes,
        initial={n: start[n] for n in names},
        fixed={k: v for k, v in start.items() if k not in names},
        to_sim=parts.to_sim,
        simulator=parts.simulator(int(cfg.sim.frames)),
        loss=loss,
        renderer=parts.renderer() if loss.needs_render else None,
        specs=specs,
        per_particle=tuple(cfg.optimize.per_particle),
        initial_velocity=tuple(cfg.sim.initial_velocity) if cfg.optimize.initial_velocity else None,
    )


def build_fit(
    cfg,
    reference: Reference,
    device: str = "cpu",
    config_origin: str = "config",
    *,
    stage=None,
    observer=None,
    on_scene=None,
    on_camera=None,
) -> FitSetup:
    """Assemble the scene, the starting material, the simulation, the renderer and the loss."""
    from motionphysics.assembly import assemble
    from motionphysics.losses import get_loss

    loss_name = "video_match" if reference.kind == "video" else "trajectory_match"
    if cfg.optimize.loss is not None and cfg.optimize.loss != loss_name:
        raise UserInputError(
            f"{config_origin}: optimize.loss is {cfg.optimize.loss!r} but the reference "
            f"{reference.path} is a {reference.kind}, which fit matches with {loss_name!r}"
        )
    if cfg.sim.frames < 2:
        raise UserInputError(
            f"{config_origin}: sim.frames must be >= 2 to fit (frame 0 is the initial state)"
        )
    # A reference of the wrong length is refused before the assembly, so the user reads
    # that one line and nothing the assembly would say about a run that cannot start.
    t_ref = int(np.asarray(reference.data).shape[0]) if reference.data is not None else None
    if t_ref is not None and t_ref != int(cfg.sim.frames):
        raise UserInputError(
            f"{reference.path}: reference has {t_ref} frames but {config_origin} sim.frames "
            f"is {int(cfg.sim.frames)}"
        )
    parts = assemble(
        cfg,
        device,
        needs_grad=True,
        estimate=False,
        reference_image=on_camera is not None,
        stage=stage,
        observer=observer,
        config_origin=config_origin,
        on_scene=on_scene,
        on_camera=on_camera,
    )
    cfg = parts.cfg
    if parts.objects is not None:
        return _build_objects_fit(parts, reference, config_origin)
    names = optimised_names(cfg, parts.material.cls, FIT_DEFAULT_FIXED)
    kept = [n for n in FIT_DEFAULT_FIXED if n in parts.material.values and n not in names]
    note = None
    if kept:
        vals = ", ".join(f"{n} {float(parts.material.values[n]):g}" for n in kept)
        note = (
            f"fit optimises {', '.join(names)}; {vals} stays at the config's value by default "
            "(add it to optimize.params to fit it)"
        )
    num_frames = int(cfg.sim.frames)
    if reference.kind == "video":
        loss = get_loss("video_match")(
            reference.data,
            mask=reference.mask,
            ssim_weight=cfg.optimize.ssim_weight,
            source=reference.path,
        )
        loss.check(num_frames, int(cfg.camera.height), int(cfg.camera.width), config_origin)
    else:
        loss = get_loss("trajectory_match")(
            reference.data, metric=cfg.optimize.trajectory_metric, source=reference.path
        )
        loss.check(num_frames, parts.num_particles, config_origin)
    return FitSetup(parts, names, build_problem(parts, loss, names), reference, note)


def _build_objects_fit(parts, reference: Reference, config_origin: str) -> FitSetup:
    """:func:`build_fit` of a scene of several objects (:mod:`.objects`): every object's
    optimised parameters in one theta, the trajectory or video of the whole scene."""
    from motionphysics.losses import get_loss
    from motionphysics.optimize.objects import build_objects_problem, objects_optimised

    cfg = parts.cfg
    per = objects_optimised(cfg, parts.objects, for_fit=True)
    num_frames = int(cfg.sim.frames)
    if reference.kind == "video":
        loss = get_loss("video_match")(
            reference.data,
            mask=reference.mask,
            ssim_weight=cfg.optimize.ssim_weight,
            source=reference.path,
        )
        loss.check(num_frames, int(cfg.camera.height), int(cfg.camera.width), config_origin)
    else:
        loss = get_loss("trajectory_match")(
            reference.data, metric=cfg.optimize.trajectory_metric, source=reference.path
        )
        loss.check(num_frames, parts.num_particles, config_origin)
    problem = build_objects_problem(parts, loss, per)
    return FitSetup(parts, list(problem.theta_map.names), problem, reference)


@dataclass
class GlobalResult:
    """Outcome of the global stage (:func:`global_search`)."""

    initial: dict[str, float]
    """Physical values of the optimised names at the best candidate (the gradient start)."""
    records: list[dict[str, Any]]
    """One ``log.jsonl`` record per candidate (``stage: "global"``, negative ``iteration``)."""
    best: int
    """Index of the best candidate in ``records``."""
    seconds: float


def _lhs(n: int, k: int, rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``n`` points [n, k] of a Latin hypercube in the box ``[lo, hi]`` (u coordinates).

    One parameter: the centres of ``n`` equal strata (a regular grid); several: one
    random point per stratum and coordinate, strata permuted independently.
    """
    strata = (np.arange(n)[:, None] + (0.5 if k == 1 else rng.random((n, k)))) / n
    if k > 1:
        for j in range(k):
            strata[:, j] = strata[rng.permutation(n), j]
    return lo + strata * (hi - lo)


def global_search(
    problem, opt, log_path: str | Path | None = None, *, observer=None
) -> GlobalResult:
    """The forward-only global stage of ``fit``: the best of a coarse search over theta.

    Candidates live in u, the position of each optimised parameter in its range
    (``problem.specs``: the handbook range; log-scaled parameters: a log grid), mapped
    to theta by the problem's theta map (``fit``: ``theta = logit(u)``, see
    :mod:`motionphysics.materials.theta`). Round 1: the start, then
    ``opt.global_points`` regularly spaced values for one parameter, in ascending order,
    stopped early after ``opt.global_patience`` consecutive values each worse than 10x
    the best so far (a Latin hypercube of ``global_points * k`` points for ``k``
    parameters). Round 2: ``opt.global_refine``
    (``* k``) values in the box of one coarse spacing around the round-1 best. Each
    candidate is one forward rollout of ``opt.global_frames`` frames (no tape, no
    backward) scored by the problem's loss on every frame of that horizon; a candidate
    that diverges scores +inf. Per-particle names are scanned as uniform fields, the
    initial velocity (when optimised) stays at its start.

    Candidates run one after another in this process: Warp's CPU runtime is not safe
    across ``fork``, and a ``spawn`` pool would have to import Warp, load its kernels
    and rebuild the scene and simulation in every worker (seconds each), more than a
    scan of a dozen short rollouts costs on two shared cores.

    ``log_path``: ``log.jsonl`` to (re)write with the candidates' records.
    """
    import time

    import torch

    from motionphysics.io.object_params import flat_params
    from motionphysics.losses.base import LossContext
    from motionphysics.optimize.loop import _append_log

    t_start = time.perf_counter()
    names = list(problem.theta_map.names)
    k = len(names)
    num_frames = int(problem.simulator.num_frames)
    h = num_frames if opt.global_frames is None else min(num_frames, int(opt.global_frames))
    frames = tuple(range(1, h))
    missing = [n for n in names if n not in problem.specs]
    if missing:
        raise ValueError(f"global_search: no range (Problem.specs) for {missing}")
    specs = [problem.specs[n] for n in names]
    base = problem.initial_theta()
    u0 = np.array([_u_of(ps, float(problem.initial[ps.name])) for ps in specs])
    rng = np.random.default_rng(int(opt.seed))
    n1, n2 = int(opt.global_points), int(opt.global_refine)
    lo_u, hi_u = np.full(k, 1e-4), np.full(k, 1.0 - 1e-4)
    total = 1 + n1 * k + n2 * k
    path = Path(log_path) if log_path is not None else None
    if path is not None:
        path.unlink(missing_ok=True)
    records: list[dict[str, Any]] = []
    scores: list[float] = []
    points: list[np.ndarray] = []

    def evaluate(u: np.ndarray, rnd: int) -> None:
        values = {ps.name: _x_of(ps, float(u[j])) for j, ps in enumerate(specs)}
        vec = problem.theta_map.to_theta(values).detach().to(torch.float32)
        theta = {n: vec[j].expand_as(base[n]).clone() for j, n in enumerate(names)}
        for n in base:
            theta.setdefault(n, base[n].detach().clone())
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        loss_value = float("inf")
        stopped = None
        with torch.no_grad():
            try:
                pred = problem.forward(theta, frames, "full", 1, timings)
                t1 = time.perf_counter()
                loss_value = float(
                    problem.loss(
                        pred,
                        LossContext(
                            iteration=0,
                            num_frames=num_frames,
                            rng=torch.Generator().manual_seed(int(opt.seed)),
                            extras={},
                        ),
                    )
                )
                timings["loss"] = time.perf_counter() - t1
            except SimulationError as err:
                stopped = f"diverged: {err}"
        if not np.isfinite(loss_value):
            loss_value = float("inf")
        params, sim_params = problem.report(theta)
        i = len(records)
        rec: dict[str, Any] = {
            "iteration": i - total,
            "stage": "global",
            "candidate": i,
            "round": rnd,
            "loss": loss_value if np.isfinite(loss_value) else None,
            "frames": list(frames),
            "params": params,
            "sim_params": sim_params,
            "u": [float(x) for x in u],
        }
        substeps = getattr(problem.simulator, "substeps", None)
        if substeps is not None:
            rec["substeps"] = int(substeps)
        if stopped:
            rec["stopped"] = stopped
        rec["time"] = {**timings, "total": time.perf_counter() - t0}
        records.append(rec)
        scores.append(loss_value)
        points.append(np.asarray(u, dtype=np.float64))
        if path is not None:
            _append_log(path, rec)
        if observer is not None:
            observer.message(
                "info",
                f"global stage {i + 1}/{total}: "
                + ", ".join(f"{n}={_fmt(flat_params(params)[n])}" for n in names)
                + f" loss {loss_value:.4g}",
            )

    evaluate(u0, 0)
    if k > 1 and getattr(problem, "objects", None):
        _coordinate_search(evaluate, scores, points, k, n1, n2, lo_u, hi_u, opt.global_patience)
    worse = 0
    for u in () if k > 1 and getattr(problem, "objects", None) else _lhs(n1, k, rng, lo_u, hi_u):
        evaluate(u, 1)
        # Patience counts only past a minimum of the scan itself (not the start's
        # score): the values after it, each far worse, are the climb out of its valley.
        scan = scores[1:]
        past = len(scan) > 1 and int(np.argmin(scan)) < len(scan) - 1
        worse = worse + 1 if past and scan[-1] > 10.0 * min(scan) else 0
        if k == 1 and opt.global_patience and worse >= opt.global_patience:
            break  # the rest of the ascending scan is far from the best (and dearer)
    if n2 > 0 and not (k > 1 and getattr(problem, "objects", None)):
        best = points[int(np.argmin(scores))]
        half = (hi_u - lo_u) / n1
        lo2, hi2 = np.maximum(lo_u, best - half), np.minimum(hi_u, best + half)
        # One parameter: the refine points split the spacing on both sides of the best
        # evenly (the best itself is not evaluated twice).
        if k == 1:
            m = n2 // 2
            left = [best[0] - half[0] * (i + 1) / (m + 1) for i in range(m)]
            right = [best[0] + half[0] * (i + 1) / (n2 - m + 1) for i in range(n2 - m)]
            pts = [np.clip(np.array([v]), lo_u, hi_u) for v in (*left, *right)]
        else:
            pts = list(_lhs(n2 * k, k, rng, lo2, hi2))
        for u in pts:
            if not any(np.allclose(u, q, rtol=0, atol=1e-9) for q in points):
                evaluate(u, 2)  # (a point clipped onto a bound is not evaluated twice)
    best_i = int(np.argmin(scores))
    params = flat_params(records[best_i]["params"])  # several objects: OBJECT.PARAM keys
    initial = {
        n: float(params[n]) if not isinstance(params[n], dict) else float(params[n]["mean"])
        for n in names
    }
    return GlobalResult(initial, records, best_i, time.perf_counter() - t_start)


def _coordinate_search(evaluate, scores, points, k, n1, n2, lo_u, hi_u, patience) -> None:
    """The global stage of several objects: one parameter at a time.

    Round 1: for each optimised parameter in turn, the ``n1`` regularly spaced values of
    its range (ascending, stopped by ``patience`` as the one-parameter scan), the other
    parameters at the best point so far. Round 2: for each in turn, ``n2`` values
    within one spacing on both sides of the best. Each object's parameter mostly shapes
    that object's own motion, so a scan along each axis lands near the truth where a
    Latin hypercube of as many points in k dimensions (the single-object stage) puts
    few points near it (measured on a stiff and a soft ball: BENCHMARKS.md)."""
    half = (hi_u - lo_u) / n1

    def axis(j: int, values, rnd: int, stop: int) -> None:
        base = points[int(np.argmin(scores))].copy()
        first, worse = len(scores), 0
        for v in values:
            u = base.copy()
            u[j] = float(np.clip(v, lo_u[j], hi_u[j]))
            if any(np.allclose(u, q, rtol=0, atol=1e-9) for q in points):
                continue
            evaluate(u, rnd)
            scan = scores[first:]
            past = len(scan) > 1 and int(np.argmin(scan)) < len(scan) - 1
            worse = worse + 1 if past and scan[-1] > 10.0 * min(scan) else 0
            if stop and worse >= stop:
                break

    for j in range(k):
        axis(j, lo_u[j] + (np.arange(n1) + 0.5) / n1 * (hi_u[j] - lo_u[j]), 1, patience)
    if n2 > 0:
        for j in range(k):
            b = points[int(np.argmin(scores))][j]
            m = n2 // 2
            left = [b - half[j] * (i + 1) / (m + 1) for i in range(m)]
            right = [b + half[j] * (i + 1) / (n2 - m + 1) for i in range(n2 - m)]
            axis(j, (*left, *right), 2, 0)


def _u_of(ps, x: float) -> float:
    """Position of ``x`` in the range of ``ps`` (log-scaled: of ``log x``), in [0, 1]."""
    import math

    if ps.scale == "log":
        u = (math.log(x) - math.log(ps.low)) / (math.log(ps.high) - math.log(ps.low))
    else:
        u = (x - ps.low) / (ps.high - ps.low)
    return min(max(u, 0.0), 1.0)


def _x_of(ps, u: float) -> float:
    import math

    if ps.scale == "log":
        return math.exp(math.log(ps.low) + u * (math.log(ps.high) - math.log(ps.low)))
    return ps.low + u * (ps.high - ps.low)


def _fmt(v) -> str:
    if isinstance(v, dict):
        v = v.get("mean")
    return f"{float(v):.4g}"


class _Advance:
    """Observer wrapper: each global-stage candidate advances the progress stage."""

    def __init__(self, observer, st):
        self._observer, self._st = observer, st

    def message(self, level: str, text: str) -> None:
        self._st.advance()
        self._st.note(text)


def fingerprint(cfg, reference_digest: str) -> str:
    """Identifies a fit's config and reference (resuming another fit's checkpoint is refused)."""
    from motionphysics.config import config_to_dict

    data = config_to_dict(cfg)
    data["optimize"].pop("iterations", None)
    data.pop("versions", None)
    text = json.dumps({"config": data, "reference": reference_digest}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def final_material(problem, material, theta):
    """The physical MaterialParams at ``theta`` (floats, or float32 arrays [P] per particle)."""
    import torch

    with torch.no_grad():
        phys = problem.all_physical(theta)

    def conv(v):
        a = torch.as_tensor(v).detach().cpu().double()
        return float(a) if a.numel() == 1 else a.numpy().astype(np.float32)

    phys = {k: conv(v) for k, v in phys.items()}
    order = [k for k in material.values if k in phys]  # the class's order, as the start
    order += [k for k in phys if k not in order and k != "density"]
    return type(material)(
        material.cls, phys.get("density", material.density), {k: phys[k] for k in order}
    )


def run_fit(
    cfg,
    reference_path: str | Path,
    out: str | Path,
    *,
    resume: bool = False,
    force: bool = False,
    iterations: int | None = None,
    progress=None,
    observer=None,
    config_origin: str = "config",
):
    """Fit ``cfg``'s material to the reference and write the run directory at ``out``.

    Returns the :class:`~motionphysics.io.writer.RunResult` (``.params`` is the
    ``params.json`` content). Raises UserInputError (bad input) and SimulationError
    (the optimisation hit a NaN / divergence: the directory then holds the outputs of
    the last good parameters, ``stop_reason: nan``).
    """
    from motionphysics.events import Observers
    from motionphysics.io.writer import RunWriter
    from motionphysics.optimize.loop import CHECKPOINT_NAME, LOG_NAME, optimize
    from motionphysics.progress import Progress, ProgressObserver
    from motionphysics.runtime import check_device, set_threads

    progress = progress or Progress(quiet=True)
    device = check_device(cfg.device)
    reference = load_reference(reference_path)
    writer = RunWriter(
        out,
        command="fit",
        resume=resume,
        force=force,
        progress=progress,
        observer=Observers([ProgressObserver(progress), observer]),
    )
    set_threads()
    total = cfg.optimize.iterations if iterations is None else int(iterations)
    # The reference is checked against the prepared scene and camera before anything is
    # written: a mismatch is a user error that leaves the run directory untouched.
    setup = build_fit(
        cfg,
        reference,
        device,
        config_origin,
        stage=progress.stage,
        observer=writer.observer,
        on_camera=lambda c, note, img: None,
    )
    writer.begin(
        setup.cfg,
        seed=int(cfg.optimize.seed),
        device=device,
        reference={"path": str(reference.path), "kind": reference.kind, "sha256": reference.digest},
    )
    with writer.guard():
        writer.record_scene(cfg, setup.parts.sim_scene)
        writer.state["scene"].update(setup.parts.scene_notes)
        writer.record_grid(setup.parts.sim_scene)
        writer.record_camera(setup.cfg, setup.parts.camera_note, setup.parts.reference_image)
        parts, problem = setup.parts, setup.problem
        cfg = parts.cfg
        material, res = parts.material, parts.resolution
        writer.record_material(material, res.values, res.record())
        writer.state["provenance"] = parts.provenance
        several = parts.objects is not None
        if several:  # (each object's values: optimize.objects)
            from motionphysics.optimize.objects import final_scene_material, initial_record

            writer.state["initial"] = initial_record(material, res)
            start = {o: v["params"] for o, v in writer.state["initial"]["objects"].items()}
        else:
            writer.state["initial"] = {
                "params": {k: float(v) for k, v in material.values.items()},
                "sim": dict(res.values),
                "substeps": int(res.substeps),
            }
            start = {k: float(v) for k, v in material.values.items()}
        fit = {
            "optimised": setup.names,
            "loss": problem.loss.name,
            "space": "physical theta through materials.simmap (sim values are what the motion "
            "determines)",
            "grad_mode": cfg.optimize.grad_mode,
            "boost": cfg.optimize.boost,
            "iterations": total,
            "start": start,
        }
        writer.state["fit"] = fit
        writer.save_config(cfg)
        if problem.range_notes:
            from motionphysics.assembly_material import warn

            for text in problem.range_notes:
                warn(text, writer.observer)

        log_path = writer.path / LOG_NAME
        resuming = resume and (writer.path / CHECKPOINT_NAME).exists()
        global_records: list[dict[str, Any]] = []
        if resuming:
            # The gradient stage continues from its checkpoint; the global stage's
            # candidates are already in log.jsonl (negative iterations).
            global_records = [
                r for r in writer.rd.read_jsonl(LOG_NAME) if r.get("stage") == "global"
            ]
        elif cfg.optimize.global_search and total > 0:
            n = 1 + (cfg.optimize.global_points + cfg.optimize.global_refine) * len(setup.names)
            with writer.stage("global search", total=n) as st:
                found = global_search(
                    problem, cfg.optimize, log_path, observer=_Advance(writer.observer, st)
                )
                st.set_total(len(found.records))  # an ascending scan may stop early
            global_records = found.records
            problem = replace(problem, initial={**problem.initial, **found.initial})
            fit["global"] = {
                "candidates": len(found.records),
                "best": found.best,
                "start": found.initial,
                "seconds": found.seconds,
                "frames": int(cfg.optimize.global_frames or cfg.sim.frames),
            }
        elif not resume:
            log_path.unlink(missing_ok=True)

        with writer.stage("optimise", total=total) as st:
            if resume:
                st.advance(
                    sum(1 for r in writer.rd.read_jsonl(LOG_NAME) if r.get("stage") != "global")
                )
            result = optimize(
                problem,
                cfg.optimize,
                writer.path,
                iterations=total,
                resume=resume,
                fingerprint=fingerprint(cfg, reference.digest),
                progress=lambda rec: st.advance(),
                observer=writer.observer,
                curriculum=float(cfg.optimize.curriculum),
                stage="gradient",
                keep_log=True,
            )
        writer.add_files("log.jsonl", "checkpoint.pt")
        writer.state["history"] = global_records + result.history
        fit.update(
            {
                "stop_reason": result.stop_reason,
                "message": f"{result.message} {setup.kept}" if setup.kept else result.message,
                "iterations_run": result.iterations,
                "substeps_changes": [list(c) for c in getattr(problem.simulator, "changes", [])],
            }
        )

        if several:
            fitted = final_scene_material(problem, parts, result.theta)
        else:
            fitted = final_material(problem, material, result.theta)
        final_cfg = cfg
        if "initial_velocity" in result.theta:
            v = tuple(float(x) for x in result.theta["initial_velocity"].detach())
            final_cfg = cfg.model_copy(
                update={"sim": cfg.sim.model_copy(update={"initial_velocity": v})}
            )
        final = parts.with_material(fitted)
        frames = int(cfg.sim.frames)
        with writer.stage("simulate", total=frames) as st:
            xs, Fs, vs, substeps = final.simulate(frames, st, cfg=final_cfg)
        record = final.resolution.record()
        record.update({"substeps": substeps, "dt": cfg.sim.frame_dt / substeps})
        writer.record_material(fitted, final.resolution.values, record)
        if "initial_velocity" in result.theta:
            writer.state["params"]["initial_velocity"] = [
                float(x) for x in result.theta["initial_velocity"]
            ]
        with writer.stage("render", total=frames) as st:
            video = final.render(xs, Fs, on_frame=st.advance)
            writer.write_video(video, cfg.sim.frame_dt)
        with writer.stage("write outputs"):
            writer.write_outputs(final.sim_scene, xs, Fs, vs, video, final_cfg, fitted)
        out_result = writer.finish("complete" if result.stop_reason != "nan" else "stopped_nan")
    if result.stop_reason == "nan":
        raise SimulationError(f"{result.message} Outputs in {writer.path} use those parameters.")
    return out_result
