"""The ``motionphysics bench fit`` target: cost of one ``fit`` iteration, split by stage.

Measures exactly the path ``motionphysics fit`` runs: the assembly of a config (a
builtin object dropped on a frictional floor, ``--particles`` particles, ``--grid``
cells over the scene, ``--frames`` frames, ``sim.substeps`` as given, ``auto`` by
default), the :class:`~motionphysics.optimize.Problem` of :func:`~.fit.build_fit`
against a reference trajectory simulated with the true material, and
:func:`~.loop.optimize` (the gradient stage, ``--boost`` 1: every frame supervised, so
each iteration simulates all frames). Per iteration it reports the loop's own timings
(``simulate``: theta -> sim values + the checkpointed forward; ``render``; ``loss``;
``backward``: the adjoint rollout and the torch graph; ``step``: Adam) and
``bookkeeping`` = the iteration's wall time minus those (report, log.jsonl line,
checkpoint.pt, progress). The reference for the ratio is the forward ``simulate`` of
the same frames at the same parameters (:meth:`Assembly.simulate`, what the
``simulate`` command runs), timed alternately with the iterations so both see the
same load on a shared machine: ``iteration_over_simulate`` is the ratio of medians (wall clock), and
``iteration_over_simulate_cpu`` the same ratio of process CPU times (what a loaded,
shared machine does not distort).

With ``--loss video`` the reference is the rendered video (``video_match``: the
renderer runs in every iteration).

This module only builds and times; it changes nothing of the fit.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from motionphysics.errors import UserInputError

__all__ = ["bench_config", "register_target", "time_fit"]


def bench_config(
    particles: int,
    grid: int,
    frames: int,
    substeps: int | str = "auto",
    E: float = 5.0e7,
    source: str = "builtin:duck",
) -> dict[str, Any]:
    """Run-config mapping of the benchmark drop (elastic, E [Pa] physical)."""
    return {
        "scene": {
            "source": source,
            "scale": 0.6,
            "translate": [0, 0, 0.45],
            "max_particles": int(particles),
        },
        "material": {"class": "elastic", "density": 1000.0, "E": float(E), "nu": 0.3},
        "sim": {
            "grid": int(grid),
            "frames": int(frames),
            "frame_dt": 0.04,
            "substeps": substeps,
            "initial_velocity": [0.0, 0.0, -2.0],
        },
        "boundary_conditions": [
            {
                "type": "surface_collider",
                "point": [0, 0, 0],
                "normal": [0, 0, 1],
                "mode": "frictional",
                "friction": 0.4,
            },
            {"type": "bounding_box"},
        ],
        "camera": {"width": 64, "height": 64},
        "optimize": {"params": ["E"], "boost": 1, "global_search": False},
    }


def time_fit(
    particles: int = 4000,
    grid: int = 32,
    frames: int = 24,
    substeps: int | str = "auto",
    iterations: int = 3,
    loss: str = "trajectory",
    source: str = "builtin:duck",
) -> dict[str, Any]:
    """Time ``iterations`` fit iterations and as many forward simulates; the result dict."""
    import numpy as np

    from motionphysics.assembly import assemble
    from motionphysics.config import config_from_dict
    from motionphysics.io.reference import Reference
    from motionphysics.optimize.fit import build_fit
    from motionphysics.optimize.loop import optimize
    from motionphysics.runtime import set_threads

    set_threads()
    true_cfg = config_from_dict(
        bench_config(particles, grid, frames, substeps, source=source), "bench:fit"
    )
    ref_parts = assemble(true_cfg, estimate=False, reference_image=False)
    xs, Fs, _vs, ref_substeps = ref_parts.simulate()
    if loss == "video":
        data = ref_parts.render(xs, Fs).astype(np.float32) / 255.0
        reference = Reference("video", data, "bench:video", "bench")
    else:
        reference = Reference("trajectory", xs, "bench:trajectory", "bench")
    # Start 20 % softer: the gradient is not zero and the substep count is the truth's
    # or close to it (the comparison is at the start's own count).
    cfg = config_from_dict(
        bench_config(particles, grid, frames, substeps, E=4.0e7, source=source), "bench:fit"
    )
    setup = build_fit(cfg, reference)
    parts = setup.parts

    sim_times: list[float] = []
    sim_cpu: list[float] = []
    it_cpu: list[float] = []
    iters: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory(prefix="mp-bench-fit-") as tmp:
        # Warm-up: Warp kernel loads, the tape's first allocation, torch's first graph.
        parts.simulate()
        optimize(setup.problem, cfg.optimize, Path(tmp) / "warm", iterations=1)
        marks: list[float] = []
        for i in range(int(iterations)):
            t0, c0 = time.perf_counter(), time.process_time()
            parts.simulate()
            sim_times.append(time.perf_counter() - t0)
            sim_cpu.append(time.process_time() - c0)
            marks.clear()
            marks.append(time.perf_counter())
            c0 = time.process_time()
            res = optimize(
                setup.problem,
                cfg.optimize,
                Path(tmp) / f"it{i}",
                iterations=1,
                progress=lambda rec: marks.append(time.perf_counter()),
            )
            it_cpu.append(time.process_time() - c0)
            rec = res.history[-1]
            t = dict(rec["time"])
            wall = marks[-1] - marks[0]
            parts_sum = sum(
                t.get(k, 0.0) for k in ("simulate", "render", "loss", "backward", "step")
            )
            t["bookkeeping"] = max(0.0, wall - parts_sum)
            t["wall"] = wall
            iters.append(t)
    med = {k: statistics.median(it.get(k, 0.0) for it in iters) for k in iters[0]}
    sim_med = statistics.median(sim_times)
    n_sub = int(setup.problem.simulator.substeps)
    return {
        "target": "fit",
        "loss": setup.problem.loss.name,
        "particles": int(parts.num_particles),
        "grid_dims": [int(v) for v in parts.sim_scene.grid_dims],
        "frames": int(frames),
        "substeps": n_sub,
        "reference_substeps": int(ref_substeps),
        "iterations": int(iterations),
        "simulate_s": sim_med,
        "simulate_ms_per_substep": 1e3 * sim_med / (n_sub * (frames - 1)),
        "iteration_s": med["wall"],
        "split_s": {
            k: med.get(k, 0.0)
            for k in ("simulate", "backward", "render", "loss", "step", "bookkeeping")
        },
        "iteration_over_simulate": med["wall"] / sim_med,
        "simulate_cpu_s": statistics.median(sim_cpu),
        "iteration_cpu_s": statistics.median(it_cpu),
        "iteration_over_simulate_cpu": statistics.median(it_cpu) / statistics.median(sim_cpu),
        "forward_in_fit_over_simulate": med.get("simulate", 0.0) / sim_med,
    }


def _run(args) -> int:
    if args.particles < 1 or args.grid < 2 or args.frames < 2 or args.iterations < 1:
        raise UserInputError(
            "bench fit: expected --particles >= 1, --grid >= 2, --frames >= 2, --iterations >= 1"
        )
    substeps: int | str = args.substeps
    if substeps != "auto":
        try:
            substeps = int(substeps)
        except ValueError:
            raise UserInputError(
                f"--substeps: expected a count or 'auto', got {args.substeps!r}"
            ) from None
    r = time_fit(
        args.particles, args.grid, args.frames, substeps, args.iterations, args.loss, args.source
    )
    if args.json:
        print(json.dumps(r))
        return 0
    s = r["split_s"]
    print(
        f"fit iteration ({r['loss']}, {r['particles']} particles, grid {r['grid_dims']}, "
        f"{r['frames']} frames x {r['substeps']} substeps): {r['iteration_s']:.3f} s = "
        + ", ".join(f"{k} {v:.3f}" for k, v in s.items())
    )
    print(
        f"forward simulate of the same frames: {r['simulate_s']:.3f} s "
        f"({r['simulate_ms_per_substep']:.2f} ms/substep); iteration / simulate = "
        f"{r['iteration_over_simulate']:.2f} (CPU time: {r['iteration_over_simulate_cpu']:.2f})"
    )
    return 0


def register_target(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="time one fit iteration, split by stage, against simulate",
        description=(
            "Time exactly the path motionphysics fit runs: one object dropped on a "
            "frictional floor, fitted against a reference trajectory simulated with the "
            "true material, every frame supervised. Prints per iteration the split "
            "(simulate, render, loss, backward, step, bookkeeping) and the ratio of an "
            "iteration to a forward simulate of the same frames, timed alternately so "
            "both see the same load (wall clock and process CPU time)."
        ),
    )
    p.add_argument("--particles", type=int, default=4000, help="particles (default 4000)")
    p.add_argument("--grid", type=int, default=32, help="grid cells (default 32)")
    p.add_argument("--frames", type=int, default=24, help="frames (default 24)")
    p.add_argument("--substeps", default="auto", help="substeps per frame or 'auto' (default)")
    p.add_argument("--iterations", type=int, default=3, help="timed iterations (default 3)")
    p.add_argument(
        "--loss",
        choices=["trajectory", "video"],
        default="trajectory",
        help="fit a trajectory (default) or the rendered video (the renderer runs each iteration)",
    )
    p.add_argument("--source", default="builtin:duck", help="scene source (default builtin:duck)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)
