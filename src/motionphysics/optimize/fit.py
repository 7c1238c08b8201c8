"""System identification: fit a config's material to a reference video or trajectory.

The library side of ``motionphysics fit`` (the command is argument handling only).
The config gives the scene, forces, boundary conditions, camera and the *starting*
material; the reference is either a video rendered from the same camera (.mp4 / .gif,
or .npz with ``frames`` [T,H,W,3] and optionally ``mask`` [T,H,W]), fitted with
``video_match``, or a trajectory (.npz with ``x`` [T,P,3], as ``motionphysics
simulate`` writes), fitted with ``trajectory_match``.

What is optimised: theta of the *physical* parameters (``optimize.params``, default
all of the class's, density excluded), mapped through the catalogue's
``Parameterisation`` (bounded by the handbook ranges) and then through the assembly's
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import SimulationError, UserInputError

__all__ = [
    "FitSetup",
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


def optimised_names(cfg, cls: str) -> list[str]:
    """``optimize.params`` checked against the class (default: all of its parameters)."""
    from motionphysics.materials.catalog import MATERIALS

    allowed = MATERIALS[cls].names
    names = list(cfg.optimize.params) if cfg.optimize.params is not None else list(allowed)
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
    specs = {}
    for n in names:
        ps = spec(cls, n)
        specs[n] = ParamSpec(n, ps.unit, float(ps.low), float(ps.high), ps.scale)
    return Problem(
        theta_map=Parameterisation(cls, names),
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
        # (assembly.ObjectsSimulator is the differentiable simulator of several objects,
        # one parameter vector each; this fit loop has one parameter vector)
        raise UserInputError(
            f"{config_origin}: objects: fitting the materials of several objects is not "
            "available yet; fit one object at a time"
        )
    names = optimised_names(cfg, parts.material.cls)
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
    return FitSetup(parts, names, build_problem(parts, loss, names), reference)


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
    from motionphysics.optimize.loop import optimize
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
        writer.record_camera(setup.cfg, setup.parts.camera_note, setup.parts.reference_image)
        parts, problem = setup.parts, setup.problem
        cfg = parts.cfg
        material, res = parts.material, parts.resolution
        writer.record_material(material, res.values, res.record())
        writer.state["provenance"] = parts.provenance
        writer.state["initial"] = {
            "params": {k: float(v) for k, v in material.values.items()},
            "sim": dict(res.values),
            "substeps": int(res.substeps),
        }
        fit = {
            "optimised": setup.names,
            "loss": problem.loss.name,
            "space": "physical theta through materials.simmap (sim values are what the motion "
            "determines)",
            "grad_mode": cfg.optimize.grad_mode,
            "boost": cfg.optimize.boost,
            "iterations": total,
            "start": {k: float(v) for k, v in material.values.items()},
        }
        writer.state["fit"] = fit
        writer.save_config(cfg)

        with writer.stage("optimise", total=total) as st:
            if resume:
                st.advance(len(writer.rd.read_jsonl("log.jsonl")))
            result = optimize(
                problem,
                cfg.optimize,
                writer.path,
                iterations=total,
                resume=resume,
                fingerprint=fingerprint(cfg, reference.digest),
                progress=lambda rec: st.advance(),
                observer=writer.observer,
            )
        writer.add_files("log.jsonl", "checkpoint.pt")
        writer.state["history"] = result.history
        fit.update(
            {
                "stop_reason": result.stop_reason,
                "message": result.message,
                "iterations_run": result.iterations,
                "substeps_changes": [list(c) for c in getattr(problem.simulator, "changes", [])],
            }
        )

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
