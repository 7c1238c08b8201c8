"""The main job end to end: prompt + scene + config -> a finished run directory.

Stages (each timed; the names appear in the progress display, ``params.json`` and the
report)::

    load scene         load_scene + prepare -> SimScene (particles in the MPM domain)
    reference render   the rest state from the run camera (plots/reference.png)
    estimate material  init backend (kb | llm | median | naive) from the prompt (+ image)
    resolve material   config ``material:`` overrides, handbook clamps, sim map
    optimise           only when optimize.prior != none (motionphysics.optimize.refine)
    simulate           the assembly's forward rollout -> x [T,P,3], F [T,P,3,3]
    render             splats follow the particles -> video.mp4
    write outputs      trajectory.npz, metrics.json, plots/, splats/, report.html

The parts come from :func:`motionphysics.assembly.assemble` (the same for ``run``,
``simulate`` and ``fit``) and every file goes through
:class:`motionphysics.io.writer.RunWriter` (atomic writes; ``params.json`` rewritten at
each stage with ``partial: true`` until the end). ``run.yaml`` is the fully resolved
config (material filled in, camera resolved, seed, versions): re-running it
reproduces the run.

This module orchestrates; it holds no physics, rendering, material or file-format
knowledge of its own. Names re-exported below keep older imports working.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.assembly import (  # noqa: F401 - re-exported
    assemble,
    ground_splats,
    material_complete,
    render_view,
    resolve_camera,
    resolve_material,
    resolve_simulation,
    simulate_forward,
    warn,
)
from motionphysics.config import RunConfig
from motionphysics.errors import UserInputError
from motionphysics.io.writer import (  # noqa: F401 - re-exported
    PARAMS_SCHEMA,
    UNITS,
    RunResult,
    RunWriter,
    print_summary,
    summary_text,
    write_metrics,
)
from motionphysics.progress import Progress
from motionphysics.runconfig import (  # noqa: F401 - re-exported
    load_run_config,
    read_params_file,
    resolve_paths,
    versions,
)

__all__ = [
    "PARAMS_SCHEMA",
    "RunResult",
    "load_run_config",
    "print_summary",
    "read_params_file",
    "resolve_paths",
    "run_pipeline",
    "simulate_forward",
    "summary_text",
    "versions",
]


def _map_to_sim(material, cfg: RunConfig, sim_scene) -> tuple[dict[str, float], dict[str, Any]]:
    """Simulation values and the ``sim_context`` record (:func:`assembly.resolve_simulation`)."""
    res = resolve_simulation(material, cfg, sim_scene)
    return dict(res.values), res.record()


def _seed_everything(seed: int) -> None:
    import torch

    random.seed(seed)
    np.random.seed(seed % (2**32))  # noqa: NPY002 - seeds legacy global users (third-party code)
    torch.manual_seed(seed)


def run_pipeline(
    cfg: RunConfig,
    out: str | Path,
    *,
    init_backend: str = "kb",
    params_file: str | Path | None = None,
    optimise: bool = True,
    resume: bool = False,
    force: bool = False,
    progress: Progress | None = None,
    config_origin: str = "<config>",
    command: str = "run",
    observer=None,
) -> RunResult:
    """Run the main job and write the run directory at ``out``.

    ``optimise=False`` is ``motionphysics simulate`` (forward only; material from the
    config's ``material:`` block, or ``params_file``, completed by ``init_backend``
    when the block is incomplete). Raises UserInputError / SimulationError /
    RunInterrupted (the directory then holds a consistent partial run).
    """
    from motionphysics.init import INIT_BACKENDS
    from motionphysics.materials.catalog import use_ranges
    from motionphysics.runtime import check_device, set_threads

    if init_backend not in INIT_BACKENDS:
        raise UserInputError(
            f"--init: expected one of {', '.join(INIT_BACKENDS.names())}, got {init_backend!r}"
        )
    device = check_device(cfg.device)
    refine = optimise and wants_refinement(cfg)
    if refine:
        _check_prior_available(cfg)
    progress = progress or Progress(quiet=True)
    from motionphysics.events import Observers
    from motionphysics.progress import ProgressObserver

    writer = RunWriter(
        out,
        command=command,
        resume=resume,
        force=force,
        progress=progress,
        observer=Observers([ProgressObserver(progress), observer]),
    )
    seed = int(cfg.optimize.seed)
    set_threads()
    _seed_everything(seed)
    writer.begin(cfg, seed=seed, device=device)
    cfg_in = cfg  # the camera as the person wrote it (auto-framing is redone on the trajectory)
    # init.ranges: the range table the estimates (and the refinement's bounds) use
    with writer.guard(), use_ranges(cfg.init.ranges):
        base = read_params_file(params_file) if params_file is not None else None
        parts = assemble(
            cfg,
            device,
            needs_grad=refine,
            init_backend=init_backend,
            params_file=base,
            stage=writer.stage,
            observer=writer.observer,
            announce=progress.verbose,
            config_origin=config_origin,
            on_scene=lambda s: writer.record_scene(cfg, s),
            on_camera=writer.record_camera,
        )
        cfg = parts.cfg
        writer.state.setdefault("scene", {}).update(parts.scene_notes)
        writer.record_grid(parts.sim_scene)  # (the domain may have widened for a spread)
        material, res = parts.material, parts.resolution
        writer.record_material(material, res.values, res.record())
        writer.state["provenance"] = parts.provenance
        writer.save_config(cfg)

        # ---- optimisation (the refinement stage) --------------------------------------
        initial_material = None
        if refine and cfg.optimize.iterations > 0:
            initial_material = material
            if parts.objects is not None:  # each object's start (optimize.objects)
                from motionphysics.optimize.objects import initial_record

                writer.state["initial"] = initial_record(material, res)
            else:
                writer.state["initial"] = {
                    "params": {k: float(v) for k, v in material.values.items()},
                    "sim": dict(res.values),
                    "substeps": int(res.substeps),
                }
            with writer.stage("optimise", total=cfg.optimize.iterations) as st:
                opt = _optimise(parts, writer, resume, st)
                material = opt["material"]
                parts = parts.with_material(material)
                res = parts.resolution
                writer.record_material(material, res.values, res.record())
                writer.state["history"] = opt["history"]
                writer.state["optimise"] = {
                    k: v for k, v in opt.items() if k not in ("material", "sim", "history")
                }

        # ---- simulate ------------------------------------------------------------------
        frames = int(cfg.sim.frames)
        with writer.stage("simulate", total=frames) as st:
            xs, Fs, vs, substeps = parts.simulate(frames, st)
            writer.state["sim_context"]["substeps"] = substeps
            writer.state["sim_context"]["dt"] = cfg.sim.frame_dt / substeps
            # (the rollout of parts.simulate; parts.simulation would build another one)
            wall_hits = getattr(parts.last_rollout, "wall_hits", None)
            if wall_hits:
                # (in the scene block: params.json has one key set for every command)
                writer.state["scene"]["wall_hits"] = list(wall_hits)
                first = wall_hits[0]
                advice = (
                    "sim.domain: give more room, or leave it null to fit the motion"
                    if cfg.sim.domain is not None
                    else "the fitted domain is too tight at this sim.grid: give sim.domain "
                    "with more room, or a finer sim.grid"
                )
                warn(
                    f"material reached the domain wall {first['wall']} at frame "
                    f"{first['frame']}; it stops there ({advice})",
                    writer.observer,
                )
        # The automatic camera frames the whole trajectory, not only the first frame.
        parts = parts.reframe(cfg_in, xs)
        if parts.cfg.camera != cfg.camera:
            cfg = parts.cfg
            writer.record_camera(cfg, parts.camera_note, None)

        # ---- render --------------------------------------------------------------------
        with writer.stage("render", total=frames) as st:
            video = parts.render(xs, Fs, on_frame=st.advance)
            writer.write_video(video, cfg.sim.frame_dt)
        if initial_material is not None:
            # The report shows the initial estimate's motion beside the refined one.
            with writer.stage("initial video", total=frames) as st:
                p0 = parts.with_material(initial_material)
                xs0, Fs0, vs0, _ = p0.simulate(frames, st)
                writer.write_video(p0.render(xs0, Fs0), cfg.sim.frame_dt, "video_initial.mp4")
            if parts.objects is None and "optimise" in writer.state:
                # the motion asked for beside the motion before and after refinement
                writer.state["optimise"]["motion"] = _motion_record(
                    cfg, material, (xs0, vs0), (xs, vs), parts.sim_scene
                )

        # ---- outputs -------------------------------------------------------------------
        with writer.stage("write outputs"):
            writer.write_outputs(
                parts.sim_scene,
                xs,
                Fs,
                vs,
                video,
                cfg,
                material,
                active=getattr(parts.last_rollout, "active", None),
            )
            if initial_material is None and parts.objects is None and cfg.prompt:
                # no refinement: the motion the prompt asks for beside the one simulated,
                # so a run that does not do what its sentence says says so
                motion = _plain_motion_record(cfg, material, (xs, vs), parts.sim_scene)
                if motion is not None and writer.state.get("metrics") is not None:
                    writer.state["metrics"]["motion"] = motion
        if cfg.export_ply:
            with writer.stage("export splats", total=frames) as st:
                writer.export_splats(parts.sim_scene, xs, Fs, on_frame=st.advance)
        return writer.finish()


def _eval_inputs(cfg: RunConfig, material, x, sim_scene) -> dict[str, Any]:
    """What eval scores a run's motion adherence with (the same as ``metrics.json``): the
    frame times ``t`` [T] s, particle ``mass`` [P], ``gravity`` [3] and the ``floor``
    height along up (None: the lowest point reached), for positions ``x`` [T, P, 3]."""
    from motionphysics.config import config_to_dict
    from motionphysics.evaluation.evaluate import floor_from_config
    from motionphysics.metrics.physical import up_axis

    gravity = np.asarray(cfg.sim.gravity, dtype=np.float64)
    return {
        "t": np.arange(x.shape[0]) * float(cfg.sim.frame_dt),
        "mass": _f64(sim_scene.volumes) * _f64(material.density),
        "gravity": gravity,
        "floor": floor_from_config(config_to_dict(cfg), up_axis(gravity), x[0]),
    }


def _f64(a) -> np.ndarray:
    return np.asarray(a.detach().cpu() if hasattr(a, "detach") else a, dtype=np.float64)


def _motion_record(cfg: RunConfig, material, before, after, sim_scene) -> dict[str, Any]:
    """The motion group the prompt asks for and those of the initial and the refined
    trajectory (:mod:`motionphysics.priors.motion_summary`), each with eval's motion
    adherence (the same masses, gravity and floor as ``metrics.json``), with its summary
    lines."""
    from motionphysics.priors.motion_summary import motion_lines, motion_record

    (x0, v0), (x1, v1) = before, after
    x0, v0, x1, v1 = _f64(x0), _f64(v0), _f64(x1), _f64(v1)
    ev = _eval_inputs(cfg, material, x1, sim_scene)
    rec = motion_record(
        cfg.prompt or "",
        material.cls,
        ev.pop("t"),
        (x0, v0),
        (x1, v1),
        **ev,
    )
    return {**rec, "lines": motion_lines(rec)}


def _plain_motion_record(cfg: RunConfig, material, traj, sim_scene) -> dict[str, Any] | None:
    """For a run without refinement: the motion the prompt asks for (read for what this
    material can show), the motion simulated and eval's motion adherence, with summary
    lines (None when the prompt asks for no motion the captions know)."""
    from motionphysics.priors.motion_summary import plain_motion_record

    x, v = (_f64(a) for a in traj)
    ev = _eval_inputs(cfg, material, x, sim_scene)
    return plain_motion_record(cfg.prompt or "", material.cls, ev.pop("t"), x, v, **ev)


def wants_refinement(cfg: RunConfig) -> bool:
    """True when ``run`` optimises: a prior is named, or ``optimize.losses`` is given."""
    return cfg.optimize.prior != "none" or cfg.optimize.losses is not None


def _check_prior_available(cfg: RunConfig) -> None:
    """Fail fast (exit 2) when the requested prior's module is not in this build."""
    from motionphysics.priors import PRIORS

    name = cfg.optimize.prior
    if name != "none" and not PRIORS.available(name):
        raise UserInputError(
            f"optimize.prior: '{name}' is not available in this build ({PRIORS.module_of(name)} "
            "is not installed); use --prior none (forward simulation from the estimated material)"
        )


def _optimise(parts, writer, resume: bool, stage_handle) -> dict[str, Any]:
    """The plug-in point: ``motionphysics.optimize.run_prior_optimisation``.

    Expected to return ``{"material": MaterialParams, "sim": {name: float},
    "history": [record, ...], "stop_reason": str}`` and to write ``log.jsonl`` and
    ``checkpoint.pt`` in ``rd.path``.
    """
    from motionphysics.optimize.refine import run_refinement

    return run_refinement(parts, writer, resume=resume, stage=stage_handle)
