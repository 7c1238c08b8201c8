"""``motionphysics fit CONFIG --reference VIDEO_OR_NPZ``: system identification.

Recovers the material parameters that reproduce a reference, by differentiable
simulation: the config gives the scene, forces, boundary conditions, camera and the
*starting* material; the reference is either a video rendered from the same camera
(.mp4 / .gif, or .npz with ``frames`` [T,H,W,3] and optionally ``mask`` [T,H,W]) —
fitted with ``video_match`` — or a trajectory (.npz with ``x`` [T,P,3], as
``motionphysics simulate`` writes) — fitted with ``trajectory_match``.

What is optimised: theta of the *physical* parameters (``optimize.params``, default
all of the class's, density excluded), mapped through the catalogue's
``Parameterisation`` (bounded by the handbook ranges) and then through
``materials.simmap.physical_to_sim`` (differentiable) into simulation values. The
motion determines the *simulation* values; where the sim map compresses a range
(stiffness, see simmap), the physical value is recovered only as well as the map's
slope allows. params.json reports both.

The run directory holds params.json (final values and the history), log.jsonl,
checkpoint.pt, trajectory.npz and video.mp4 of the final simulation, plots/ (loss,
parameters with their ranges, space-time slice) and run.yaml. ``--resume`` continues a
killed fit from checkpoint.pt and ends with the same parameters as an uninterrupted
one.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from motionphysics.errors import SimulationError, UserInputError

__all__ = [
    "Reference",
    "FitSetup",
    "SimParts",
    "load_reference",
    "prepare_simulation",
    "build_fit",
    "run_fit",
    "register",
]

VIDEO_SUFFIXES = (".mp4", ".gif")


@dataclass
class Reference:
    """A loaded reference: a video or a trajectory."""

    kind: Literal["video", "trajectory"]
    data: np.ndarray
    """frames [T,H,W,3] (uint8 or float in [0,1]) or x [T,P,3] float32 [m]."""
    path: str
    digest: str
    """sha256 of the file (part of the resume fingerprint)."""
    mask: np.ndarray | None = None
    """Optional video mask [T,H,W] or [H,W] in [0,1]."""


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_reference(path: str | Path) -> Reference:
    """Read ``--reference``; a missing or malformed file is a one-line user error."""
    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"{p}: reference not found (expected .mp4, .gif or .npz)")
    suffix = p.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        from motionphysics.io.video import read_video

        return Reference("video", np.asarray(read_video(p)), str(p), _digest(p))
    if suffix != ".npz":
        raise UserInputError(
            f"{p}: unsupported reference type {suffix!r}; expected .mp4, .gif or .npz"
        )
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise UserInputError(f"{p}: not a readable .npz ({err})") from None
    if "frames" in arrays:
        frames = arrays["frames"]
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise UserInputError(
                f"{p}: 'frames' must be [frames, height, width, 3], got {frames.shape}"
            )
        if frames.dtype != np.uint8:
            frames = frames.astype(np.float32)
            if frames.size and (frames.min() < 0 or frames.max() > 1):
                raise UserInputError(f"{p}: float 'frames' must lie in [0, 1]")
        return Reference("video", frames, str(p), _digest(p), mask=arrays.get("mask"))
    if "x" in arrays:
        x = arrays["x"]
        if x.ndim != 3 or x.shape[-1] != 3:
            raise UserInputError(f"{p}: 'x' must be [frames, particles, 3], got {x.shape}")
        return Reference("trajectory", x.astype(np.float32), str(p), _digest(p))
    raise UserInputError(
        f"{p}: no 'frames' (a video [T,H,W,3]) or 'x' (a trajectory [T,P,3]) array in the .npz"
    )


class BridgeSimulator:
    """The MPM torch bridge behind the optimiser's :class:`~motionphysics.optimize.Simulator`."""

    def __init__(self, simulation, num_frames: int):
        self.simulation = simulation
        self.num_particles = int(simulation.model.particle_count)
        self.num_frames = int(num_frames)

    def simulate(self, sim_params, initial_velocity, frames, grad_mode, window):
        from motionphysics.sim.bridge import simulate
        from motionphysics.sim.model import PARAM_NAMES

        params = {k: v for k, v in sim_params.items() if k in PARAM_NAMES}
        return simulate(
            self.simulation,
            params,
            frames=frames,
            initial_velocity=initial_velocity,
            grad_mode=grad_mode,
            window=window,
        )


class SplatRenderer:
    """Differentiable frames of the run camera (splats follow the particles, plus the ground)."""

    def __init__(self, sim_scene, camera, background, ground):
        self.sim_scene, self.camera, self.background, self.ground = (
            sim_scene,
            camera,
            background,
            ground,
        )

    def __call__(self, xs, Fs):
        import torch

        from motionphysics.pipeline import render_view

        return torch.stack(
            [
                render_view(self.sim_scene, xs[i], Fs[i], self.camera, self.background, self.ground)
                for i in range(xs.shape[0])
            ]
        )


@dataclass
class FitSetup:
    """Everything a fit needs, built once from the config and the reference."""

    cfg: Any
    """RunConfig with the camera resolved and ``sim.substeps`` fixed to an integer."""
    sim_scene: Any
    material: Any
    """Starting MaterialParams (physical)."""
    names: list[str]
    """Optimised physical parameter names."""
    sim_context: Any
    """materials.simmap.SimContext the map uses (dt of the fixed substeps)."""
    simulation: Any
    problem: Any
    camera: Any
    background: tuple[float, float, float]
    ground: Any
    reference: Reference


def _optimised_names(cfg, cls: str) -> list[str]:
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


def _fix_substeps(cfg, material, names, sim_scene) -> tuple[Any, Any]:
    """(cfg with integer substeps, SimContext of the map).

    Fixed substeps: the map uses their dt, so every theta maps to a stable material.
    ``auto``: the map uses ``dt = frame_dt / 512`` like ``run``/``simulate`` (so the same
    physical values give the same simulation values as the reference run) and the
    substeps are those of the stiffest material the optimiser can reach (optimised
    parameters at their range highs).
    """
    from motionphysics.materials.catalog import spec
    from motionphysics.materials.simmap import SimContext, physical_to_sim

    particles = sim_scene.particles.detach().cpu().numpy()
    length = float(np.max(particles.max(0) - particles.min(0)))
    gravity = float(np.linalg.norm(np.asarray(cfg.sim.gravity, dtype=np.float64)))
    frame_dt = float(cfg.sim.frame_dt)
    values = {
        "density": float(material.density),
        **{k: float(v) for k, v in material.values.items()},
    }
    if cfg.sim.substeps != "auto":
        n = int(cfg.sim.substeps)
        ctx = SimContext(
            dx=float(sim_scene.dx),
            dt=frame_dt / n,
            density=values["density"],
            length=length,
            gravity=gravity,
        )
        return cfg, ctx
    from motionphysics.sim.solver import auto_substeps

    ctx = SimContext(
        dx=float(sim_scene.dx),
        dt=frame_dt / 512,
        density=values["density"],
        length=length,
        gravity=gravity,
    )
    stiff = dict(values)
    for n in names:
        stiff[n] = float(spec(material.cls, n).high) if n != "density" else values["density"]
    sim = physical_to_sim(stiff, ctx, cls=material.cls)
    n = int(
        auto_substeps(
            {"class": material.cls, **{k: float(v) for k, v in sim.items()}},
            float(sim_scene.dx),
            frame_dt,
        )
    )
    new_sim = cfg.sim.model_copy(update={"substeps": n})
    return cfg.model_copy(update={"sim": new_sim}), ctx


@dataclass
class SimParts:
    """The scene, starting material and simulation of a config (no reference, no loss)."""

    cfg: Any
    """RunConfig with the camera resolved and ``sim.substeps`` fixed to an integer."""
    sim_scene: Any
    material: Any
    names: list[str]
    sim_context: Any
    simulation: Any
    camera: Any
    background: tuple[float, float, float]
    ground: Any


def prepare_simulation(cfg, device: str = "cpu", requires_grad: bool = True) -> SimParts:
    """Scene -> prepared particles -> camera -> material of the config -> Simulation.

    The material is the config's ``material:`` block (fields it leaves out take the
    centre of the class's range); no estimate from the prompt is made.
    """
    from motionphysics.materials.simmap import physical_to_sim
    from motionphysics.pipeline import ground_splats, resolve_camera, resolve_material
    from motionphysics.render.camera import camera_from_config
    from motionphysics.scene import load_scene
    from motionphysics.scene.prepare import prepare
    from motionphysics.sim import build_simulation

    scene = load_scene(cfg.scene.source)
    sim_scene = prepare(scene, cfg.scene, cfg.sim, list(cfg.boundary_conditions))
    cfg, _ = resolve_camera(cfg, sim_scene)
    camera = camera_from_config(cfg.camera)
    background = tuple(float(v) for v in cfg.camera.background)
    ground = ground_splats(cfg, sim_scene)
    material = resolve_material(cfg, None)["material"]
    names = _optimised_names(cfg, material.cls)
    cfg, ctx = _fix_substeps(cfg, material, names, sim_scene)
    start = {
        "density": float(material.density),
        **{k: float(v) for k, v in material.values.items()},
    }
    sim_values = physical_to_sim(start, ctx, cls=material.cls)
    simulation = build_simulation(
        sim_scene, cfg, {"class": material.cls, **sim_values}, device, requires_grad=requires_grad
    )
    return SimParts(cfg, sim_scene, material, names, ctx, simulation, camera, background, ground)


def build_fit(
    cfg, reference: Reference, device: str = "cpu", config_origin: str = "config"
) -> FitSetup:
    """Prepare the scene, the starting material, the simulation, the renderer and the loss."""
    from motionphysics.losses import get_loss
    from motionphysics.materials.catalog import spec
    from motionphysics.materials.simmap import physical_to_sim
    from motionphysics.materials.theta import Parameterisation
    from motionphysics.optimize import ParamSpec, Problem

    loss_name = "video_match" if reference.kind == "video" else "trajectory_match"
    if "loss" in cfg.optimize.model_fields_set and cfg.optimize.loss != loss_name:
        raise UserInputError(
            f"{config_origin}: optimize.loss is {cfg.optimize.loss!r} but the reference "
            f"{reference.path} is a {reference.kind}, which fit matches with {loss_name!r}"
        )
    if cfg.sim.frames < 2:
        raise UserInputError(
            f"{config_origin}: sim.frames must be >= 2 to fit (frame 0 is the initial state)"
        )
    parts = prepare_simulation(cfg, device, requires_grad=True)
    cfg, material, names, ctx = parts.cfg, parts.material, parts.names, parts.sim_context
    start = {
        "density": float(material.density),
        **{k: float(v) for k, v in material.values.items()},
    }

    num_frames = int(cfg.sim.frames)
    if reference.kind == "video":
        loss = get_loss("video_match")(
            reference.data,
            mask=reference.mask,
            ssim_weight=cfg.optimize.ssim_weight,
            source=reference.path,
        )
        loss.check(num_frames, int(cfg.camera.height), int(cfg.camera.width), config_origin)
        renderer = SplatRenderer(parts.sim_scene, parts.camera, parts.background, parts.ground)
    else:
        loss = get_loss("trajectory_match")(
            reference.data, metric=cfg.optimize.trajectory_metric, source=reference.path
        )
        loss.check(num_frames, int(parts.sim_scene.particles.shape[0]), config_origin)
        renderer = None

    cls = material.cls
    specs = {}
    for n in names:
        ps = spec(cls, n)
        specs[n] = ParamSpec(n, ps.unit, float(ps.low), float(ps.high), ps.scale)
    problem = Problem(
        theta_map=Parameterisation(cls, names),
        initial={n: start[n] for n in names},
        fixed={k: v for k, v in start.items() if k not in names},
        to_sim=lambda phys: physical_to_sim(phys, ctx, cls=cls),
        simulator=BridgeSimulator(parts.simulation, num_frames),
        loss=loss,
        renderer=renderer,
        specs=specs,
        per_particle=tuple(cfg.optimize.per_particle),
        initial_velocity=tuple(cfg.sim.initial_velocity) if cfg.optimize.initial_velocity else None,
    )
    return FitSetup(
        cfg,
        parts.sim_scene,
        material,
        names,
        ctx,
        parts.simulation,
        problem,
        parts.camera,
        parts.background,
        parts.ground,
        reference,
    )


def _fingerprint(setup: FitSetup) -> str:
    from motionphysics.config import config_to_dict

    data = config_to_dict(setup.cfg)
    data["optimize"].pop("iterations", None)
    data.pop("versions", None)
    text = json.dumps({"config": data, "reference": setup.reference.digest}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _final_values(setup: FitSetup, theta) -> tuple[dict[str, Any], dict[str, Any]]:
    """Final physical and simulation values as floats (scene-wide) or float32 arrays [P]."""
    import torch

    with torch.no_grad():
        phys = setup.problem.all_physical(theta)
        sim = setup.problem.to_sim(phys)

    def conv(v):
        a = torch.as_tensor(v).detach().cpu().double()
        return float(a) if a.numel() == 1 else a.numpy().astype(np.float32)

    return {k: conv(v) for k, v in phys.items()}, {k: conv(v) for k, v in sim.items()}


def _plot_records(history: list[dict], names: list[str]) -> list[dict]:
    out = []
    for r in history:
        params = {}
        for n in names:
            v = (r.get("params") or {}).get(n)
            if isinstance(v, dict):
                v = v.get("mean")
            if v is not None:
                params[n] = v
        out.append({"iteration": r.get("iteration"), "loss": r.get("loss"), "params": params})
    return out


def run_fit(
    cfg,
    reference_path: str | Path,
    out: str | Path,
    *,
    resume: bool = False,
    force: bool = False,
    iterations: int | None = None,
    progress=None,
    config_origin: str = "config",
) -> dict[str, Any]:
    """Fit ``cfg``'s material to the reference and write the run directory at ``out``.

    Returns the ``params.json`` content. Raises UserInputError (bad input) and
    SimulationError (the optimisation hit a NaN / divergence: the directory then holds
    the outputs of the last good parameters, ``stop_reason: nan``).
    """
    from motionphysics.config import config_to_dict
    from motionphysics.io.plots import plot_loss, plot_params, space_time_slice
    from motionphysics.io.rundir import RunDirectory
    from motionphysics.optimize import optimize
    from motionphysics.pipeline import (
        PARAMS_SCHEMA,
        UNITS,
        render_video,
        simulate_forward,
        versions,
        write_metrics,
        write_run_trajectory,
    )
    from motionphysics.progress import Progress
    from motionphysics.runtime import check_device, set_threads

    progress = progress or Progress(quiet=True)
    device = check_device(cfg.device)
    reference = load_reference(reference_path)
    rd = RunDirectory(out, resume=resume, force=force)
    set_threads()
    t0 = time.perf_counter()
    with progress.stage("prepare"):
        setup = build_fit(cfg, reference, device, config_origin)
    cfg = setup.cfg
    total = cfg.optimize.iterations if iterations is None else int(iterations)
    material = setup.material
    state: dict[str, Any] = {
        "schema": PARAMS_SCHEMA,
        "command": "fit",
        "partial": True,
        "status": "running",
        "class": material.cls,
        "density": float(material.density),
        "reference": {
            "path": str(reference.path),
            "kind": reference.kind,
            "sha256": reference.digest,
        },
        "fit": {
            "optimised": setup.names,
            "loss": setup.problem.loss.name,
            "space": "physical theta through materials.simmap (sim values are what the motion "
            "determines)",
            "grad_mode": cfg.optimize.grad_mode,
            "boost": cfg.optimize.boost,
            "iterations": total,
            "start": {k: float(v) for k, v in material.values.items()},
        },
        "seed": int(cfg.optimize.seed),
        "device": device,
        "versions": versions(),
    }
    data = config_to_dict(cfg)
    data["versions"] = versions()
    rd.write_yaml("run.yaml", data)
    rd.write_json("params.json", state)

    with progress.stage("optimise", total=total) as st:
        if resume:
            st.advance(len(rd.read_jsonl("log.jsonl")))
        result = optimize(
            setup.problem,
            cfg.optimize,
            rd.path,
            iterations=total,
            resume=resume,
            fingerprint=_fingerprint(setup),
            progress=lambda rec: st.advance(),
        )

    phys, sim_values = _final_values(setup, result.theta)
    final_cfg = cfg
    if "initial_velocity" in result.theta:
        v = tuple(float(x) for x in result.theta["initial_velocity"].detach())
        final_cfg = cfg.model_copy(
            update={"sim": cfg.sim.model_copy(update={"initial_velocity": v})}
        )
    frames = int(cfg.sim.frames)
    with progress.stage("simulate", total=frames) as st:
        xs, Fs, vs, _ = simulate_forward(
            setup.sim_scene, final_cfg, material, sim_values, device, frames, st
        )
    with progress.stage("render", total=frames) as st:
        video = render_video(
            rd, setup.sim_scene, xs, Fs, setup.camera, setup.background, setup.ground, final_cfg, st
        )
    with progress.stage("write outputs"):
        final_material = type(material)(
            material.cls,
            phys.get("density", material.density),
            {k: v for k, v in phys.items() if k != "density"},
        )
        traj = write_run_trajectory(rd, setup.sim_scene, xs, Fs, vs, final_cfg, final_material)
        metrics = write_metrics(rd, traj)
        records = _plot_records(result.history, setup.names)
        plots = []
        try:
            plot_loss(records, rd.file("plots/loss.png"))
            plots.append("plots/loss.png")
        except ValueError:
            pass
        ranges = {n: (s.low, s.high) for n, s in setup.problem.specs.items()}
        try:
            plot_params(records, ranges, rd.file("plots/params.png"))
            plots.append("plots/params.png")
        except ValueError:
            pass
        space_time_slice(
            video,
            rd.file("plots/slice.png"),
            frame_dt=cfg.sim.frame_dt,
            title="space-time slice of the fitted simulation",
        )
        plots.append("plots/slice.png")

    def jsonable(v):
        return (
            v
            if isinstance(v, float)
            else {"mean": float(np.mean(v)), "min": float(np.min(v)), "max": float(np.max(v))}
        )

    state.update(
        {
            "partial": False,
            "status": "complete" if result.stop_reason != "nan" else "stopped_nan",
            "params": {k: jsonable(v) for k, v in phys.items() if k != "density"},
            "sim": {k: jsonable(v) for k, v in sim_values.items()},
            "units": {k: UNITS.get(k, "") for k in phys},
            "sim_context": {
                "dx": setup.sim_context.dx,
                "dt_map": setup.sim_context.dt,
                "substeps": int(cfg.sim.substeps),
                "frame_dt": float(cfg.sim.frame_dt),
                "length": setup.sim_context.length,
            },
            "history": result.history,
            "metrics": {
                k: metrics[k] for k in ("final_height_ratio", "spread_ratio") if k in metrics
            },
            "plots": plots,
            "wall_time_s": time.perf_counter() - t0,
            "timings": dict(progress.timings),
        }
    )
    if "initial_velocity" in result.theta:
        state["params"]["initial_velocity"] = [float(x) for x in result.theta["initial_velocity"]]
    state["fit"].update(
        {
            "stop_reason": result.stop_reason,
            "message": result.message,
            "iterations_run": result.iterations,
        }
    )
    rd.write_json("params.json", state)
    if result.stop_reason == "nan":
        raise SimulationError(f"{result.message} Outputs in {rd.path} use those parameters.")
    return state


def _main(args) -> int:
    from motionphysics.commands.run import default_out
    from motionphysics.pipeline import load_run_config
    from motionphysics.progress import Progress

    if args.iters is not None and args.iters < 0:
        raise UserInputError(f"--iters: expected a count >= 0, got {args.iters}")
    cfg = load_run_config(args.config, {"device": args.device})
    out = Path(args.out) if args.out else default_out(args.config, "fit")
    with Progress(
        quiet=getattr(args, "quiet", False), verbose=getattr(args, "verbose", False)
    ) as prog:
        state = run_fit(
            cfg,
            args.reference,
            out,
            resume=args.resume,
            force=args.force,
            iterations=args.iters,
            progress=prog,
            config_origin=args.config,
        )
    if not getattr(args, "quiet", False):
        fit = state["fit"]
        print(
            f"fit:       {state['class']}, {fit['message']} ({fit['loss']}, "
            f"grad_mode {fit['grad_mode']})"
        )
        for name in fit["optimised"]:
            v = state["params"].get(name)
            s = state["sim"].get(name)
            print(
                f"  {name:<10} {json.dumps(v):>24} {state['units'].get(name, ''):<6}"
                f"  (simulation: {json.dumps(s)}; start {fit['start'].get(name)})"
            )
        print(f"run dir:   {out}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="system identification: fit the material to a reference",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "config", metavar="CONFIG", help="run config (YAML): scene, forces, camera, start material"
    )
    p.add_argument(
        "--reference",
        required=True,
        metavar="VIDEO_OR_NPZ",
        help=".mp4/.gif or .npz with 'frames' (video) or 'x' (trajectory.npz of simulate)",
    )
    p.add_argument("--out", metavar="DIR", help="run directory (default: runs/<config name>)")
    p.add_argument("--resume", action="store_true", help="continue a killed fit in --out")
    p.add_argument("--force", action="store_true", help="overwrite a run already in --out")
    p.add_argument(
        "--iters", type=int, metavar="N", help="optimisation iterations (default: the config's)"
    )
    p.add_argument("--device", choices=["cpu", "cuda"], help="where to simulate and render")
    p.set_defaults(func=_main)
