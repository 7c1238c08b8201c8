"""The ``motionphysics bench mpm`` target: throughput of the MLS-MPM solver.

Standard benchmark scene (the same one ``benchmarks/peers/`` integrates in Taichi and
Genesis): unit domain [0, 1]^3 with ``--grid`` cells per side (nodes 0..G), slip walls
3 cells thick (``bounding_box``), an elastic cube of side 0.25 centred in x and y with
its lower face at z = 0.15, n^3 particles on a cell-centred lattice (n = round(N^(1/3))),
fixed corotated E = 1e5 Pa, nu = 0.3, rho = 1000 kg/m^3, gravity 9.8 m/s^2 along -z,
initial velocity 2 m/s along -z, dt = 1e-4 s, float32.

One run is ``--substeps`` substeps from the initial state; ``particle_substeps_per_s`` is
particles x substeps / (median run time) over ``--repeats`` runs after one untimed
warm-up run (Warp kernel load or compile). With ``--backward`` a run is a checkpointed
forward of ``--frames`` frames of ``--substeps`` substeps plus the full backward pass
(``Rollout.backward``, grad_mode full) of a fixed random linear loss on every frame's
positions; it reports that throughput, its ratio to the forward one, and the process's
peak resident memory. Then the forward runs are ``--frames`` x ``--substeps`` substeps
too and alternate with the forward + backward ones, so both see the same load on a
shared machine: ``backward_over_forward`` is the ratio of the two medians, and
``backward_over_forward_pairs`` the ratio of each pair.

This module must not change the solver; it only builds the scene and times it.
"""

from __future__ import annotations

import json
import resource
import statistics
import time

from motionphysics.errors import UserInputError

CUBE_SIDE = 0.25
CUBE_LOWER_Z = 0.15
MATERIAL = {"class": "elastic", "E": 1.0e5, "nu": 0.3, "density": 1000.0}
GRAVITY = (0.0, 0.0, -9.8)
INITIAL_VELOCITY = (0.0, 0.0, -2.0)
DT = 1.0e-4
WALL_CELLS = 3


def cube_lattice(particles: int):
    """Positions [m] (n^3, 3) float32 and volumes [m^3] (n^3,) of the benchmark cube."""
    import numpy as np

    n = max(1, round(particles ** (1.0 / 3.0)))
    h = CUBE_SIDE / n
    idx = (np.arange(n) + 0.5) * h
    gx, gy, gz = np.meshgrid(idx, idx, idx, indexing="ij")
    x = np.stack(
        [
            gx.ravel() + 0.5 - CUBE_SIDE / 2,
            gy.ravel() + 0.5 - CUBE_SIDE / 2,
            gz.ravel() + CUBE_LOWER_Z,
        ],
        axis=1,
    ).astype(np.float32)
    return x, np.full(n**3, h**3, dtype=np.float32)


def build_scene(
    particles: int,
    grid: int,
    device: str = "cpu",
    threads: int | None = None,
    requires_grad: bool = False,
):
    """(model, solver, x0) of the benchmark scene (material arrays with gradients if asked)."""
    from motionphysics.config import BoundingBox
    from motionphysics.sim.boundary import BoundaryProgram
    from motionphysics.sim.model import Model
    from motionphysics.sim.solver import Solver, SolverConfig

    x0, vol = cube_lattice(particles)
    dx = 1.0 / grid
    dims = (grid + 1,) * 3
    model = Model.from_particles(
        vol,
        MATERIAL,
        domain_lo=(0.0, 0.0, 0.0),
        dx=dx,
        grid_dims=dims,
        gravity=GRAVITY,
        device=device,
        requires_grad=requires_grad,
    )
    model.boundary = BoundaryProgram.from_config(
        [BoundingBox(type="bounding_box", padding=WALL_CELLS)], [], model, x0=x0
    )
    solver = Solver(model, SolverConfig(threads=threads))
    return model, solver, x0


def _peak_rss_mb() -> float:
    # ru_maxrss is in KiB on Linux: the process's high-water mark so far.
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def time_mpm(
    particles: int,
    grid: int,
    substeps: int,
    repeats: int,
    backward: bool = False,
    frames: int = 1,
    device: str = "cpu",
    threads: int | None = None,
    seed: int = 0,
) -> dict:
    """Run the benchmark; returns the JSON-ready result dict."""
    import numpy as np

    from motionphysics.runtime import init_warp

    wp = init_warp()
    model, solver, x0 = build_scene(particles, grid, device, threads, requires_grad=backward)
    p = model.particle_count
    a = model.state(x0, INITIAL_VELOCITY)
    b = model.state(x0, INITIAL_VELOCITY)
    start = model.state(x0, INITIAL_VELOCITY)

    steps = substeps * (frames if backward else 1)

    def forward_once() -> float:
        nonlocal a, b
        a.assign(start)
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        for k in range(steps):
            solver.step(a, b, DT, t=k * DT, substep=k)
            a, b = b, a
        wp.synchronize_device(device)
        return time.perf_counter() - t0

    result: dict = {
        "target": "mpm",
        "device": device,
        "particles": p,
        "grid": grid,
        "substeps": substeps,
        "dt": DT,
        "threads": solver.chunks if wp.get_device(device).is_cpu else None,
        "repeats": repeats,
        "warp": wp.__version__,
    }
    try:
        warm = forward_once()
        if backward:
            once = _backward_timer(model, solver, start, substeps, frames, seed)
            rss_before = _peak_rss_mb()
            warm_b = once(1)  # loads / compiles the adjoint kernels; one frame is enough
            runs, back = [], []
            for _ in range(repeats):  # alternated: both see the same load
                runs.append(forward_once())
                back.append(once(frames))
        else:
            runs = [forward_once() for _ in range(repeats)]
        state = a.numpy()
        med = statistics.median(runs)
        result.update(
            {
                "warmup_s": warm,
                "seconds": runs,
                "seconds_median": med,
                "particle_substeps_per_s": p * steps / med,
                "com_z_end": float(state["x"][:, 2].mean()),
                "vz_mean_end": float(state["v"][:, 2].mean()),
            }
        )
        if backward:
            med_b = statistics.median(back)
            gE = model.params["E"].grad.numpy()
            result.update(
                {
                    "frames": frames,
                    "backward_warmup_s": warm_b,
                    "backward_seconds": back,
                    "backward_seconds_median": med_b,
                    "backward_particle_substeps_per_s": p * steps / med_b,
                    "grad_E_sum": float(gE.sum()),
                    "grad_E_finite": bool(np.all(np.isfinite(gE))),
                    "peak_rss_mb_before_backward": rss_before,
                    "backward_over_forward": med_b / med,
                    "backward_over_forward_pairs": [b / f for f, b in zip(runs, back, strict=True)],
                }
            )
        result["peak_rss_mb"] = _peak_rss_mb()
    finally:
        solver.close()
    return result


def _backward_timer(model, solver, start, substeps: int, frames: int, seed: int):
    """``once(n_frames) -> seconds`` of a checkpointed forward + full backward."""
    import numpy as np

    from motionphysics.runtime import init_warp
    from motionphysics.sim.rollout import Rollout

    wp = init_warp()
    device = model.device
    rollout = Rollout(solver, substeps, substeps * DT)
    rng = np.random.default_rng(seed)
    p = model.particle_count
    weights = {f: rng.standard_normal((p, 3)).astype(np.float32) for f in range(1, frames + 1)}
    adjoints = {f: {"x": w} for f, w in weights.items()}

    def once(n_frames: int) -> float:
        model.zero_grad()
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        # as the torch bridge does when a full backward follows
        rollout.forward(start, n_frames + 1, keep_checkpoints=True, check=False, record_tapes=True)
        rollout.backward({f: adjoints[f] for f in range(1, n_frames + 1)}, grad_mode="full")
        wp.synchronize_device(device)
        return time.perf_counter() - t0

    return once


def _run(args) -> int:
    from motionphysics.runtime import check_device

    if (
        args.particles < 1
        or args.grid < 8
        or args.substeps < 1
        or args.repeats < 1
        or args.frames < 1
    ):
        raise UserInputError(
            "bench mpm: --particles >= 1, --grid >= 8, --substeps >= 1, --repeats >= 1 and --frames >= 1 expected"
        )
    if args.threads is not None and args.threads not in (1, 2):
        raise UserInputError(f"--threads: expected 1 or 2, got {args.threads}")
    if 0.5 + CUBE_SIDE / 2 > 1.0 - (WALL_CELLS + 2) / args.grid:
        raise UserInputError(
            f"--grid: {args.grid} cells leaves no room for the cube inside the walls"
        )
    device = check_device(args.device)
    res = time_mpm(
        args.particles,
        args.grid,
        args.substeps,
        args.repeats,
        args.backward,
        args.frames,
        device,
        args.threads,
    )
    if args.json:
        print(json.dumps(res))
    else:
        print(
            f"mpm forward: {res['particles']} particles, grid {res['grid']}^3, {res['substeps']} "
            f"substeps, {device}, threads {res['threads']}: {res['particle_substeps_per_s']:.4g} "
            f"particle-substeps/s (median {res['seconds_median']:.3f} s of {res['repeats']} runs)"
        )
        if args.backward:
            print(
                f"mpm forward+backward ({res['frames']} frame(s)): "
                f"{res['backward_particle_substeps_per_s']:.4g} particle-substeps/s, "
                f"{res['backward_over_forward']:.2f}x the forward time; "
                f"peak RSS {res['peak_rss_mb']:.0f} MB"
            )
    return 0


def register_target(sub) -> None:
    p = sub.add_parser(
        "mpm",
        help="time the MLS-MPM solver on the standard cube scene",
        description="Throughput of the MLS-MPM solver on the standard benchmark scene (the "
        "one benchmarks/peers/ integrates in Taichi and Genesis): unit domain [0, 1]^3 with "
        "--grid cells per side, slip walls 3 cells thick, an elastic cube of side 0.25 with "
        "its lower face at z = 0.15, fixed corotated E = 1e5 Pa, nu = 0.3, rho = 1000 kg/m^3, "
        "gravity 9.8 m/s^2 and an initial velocity of 2 m/s along -z, dt = 1e-4 s, float32. "
        "One timed run is --substeps substeps; particle_substeps_per_s is particles x "
        "substeps / median run time over --repeats runs after one untimed warm-up run. With "
        "--backward a run is a checkpointed forward pass of --frames frames plus the full "
        "backward pass of a random linear loss on every frame's positions; it also reports "
        "backward_over_forward (ratio of the two medians) and the peak resident memory.",
    )
    p.add_argument(
        "--particles",
        type=int,
        default=20000,
        help="particles (rounded to a cube number, default 20000 -> 27^3)",
    )
    p.add_argument(
        "--grid", type=int, default=64, help="grid cells per side of the unit domain (default 64)"
    )
    p.add_argument("--substeps", type=int, default=100, help="substeps per timed run (default 100)")
    p.add_argument(
        "--repeats", type=int, default=5, help="timed runs after the warm-up (default 5)"
    )
    p.add_argument(
        "--backward", action="store_true", help="also time a checkpointed forward + full backward"
    )
    p.add_argument(
        "--frames",
        type=int,
        default=1,
        help="with --backward: frames of SUBSTEPS substeps each (default 1)",
    )
    p.add_argument(
        "--threads", type=int, default=None, help="CPU particle threads, 1 or 2 (default: auto)"
    )
    p.add_argument(
        "--device", default="cpu", choices=["cpu", "cuda"], help="where to run (default cpu)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)
