"""Two solver variants in ONE process, alternated run by run: a kernel change measured
without the drift between processes on a shared machine.

The ``motionphysics bench mpm`` scene; one :class:`~motionphysics.sim.solver.Solver` per
``SolverConfig`` variant over the same model, each run ``--substeps`` substeps from the
same initial state, the variants alternating (A B, B A, ...) for ``--rounds`` rounds.
Reports per variant the median wall and process CPU time per run and the median of the
per-round ratios (A / B: B's speed-up), and checks that both end at the same state.

    MOTIONPHYSICS_CACHE=.cache .venv/bin/python benchmarks/bench_kernel_ab.py \\
        --particles 20000 --substeps 50 --rounds 20 --threads 1 --flag fuse_elastic_p2g
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--flag", default="fuse_elastic_p2g", help="SolverConfig bool: B sets it")
    args = ap.parse_args()

    import numpy as np

    from motionphysics.runtime import init_warp
    from motionphysics.sim import bench as B
    from motionphysics.sim.solver import Solver, SolverConfig

    wp = init_warp()
    model, _, x0 = B.build_scene(args.particles, args.grid, threads=args.threads)
    solvers = {
        "A": Solver(model, SolverConfig(threads=args.threads, **{args.flag: False})),
        "B": Solver(model, SolverConfig(threads=args.threads, **{args.flag: True})),
    }
    start = model.state(x0, B.INITIAL_VELOCITY)
    a = model.state(x0, B.INITIAL_VELOCITY)
    b = model.state(x0, B.INITIAL_VELOCITY)

    def run(solver) -> tuple[float, float, np.ndarray]:
        nonlocal a, b
        a.assign(start)
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(args.substeps):
            solver.step(a, b, B.DT, t=k * B.DT, substep=k)
            a, b = b, a
        wp.synchronize()
        return time.perf_counter() - t0, time.process_time() - c0, a.x.numpy().copy()

    ends = {k: run(s)[2] for k, s in solvers.items()}  # warm-up (kernel load)
    wall: dict = {"A": [], "B": []}
    cpu: dict = {"A": [], "B": []}
    for r in range(args.rounds):
        for k in ("A", "B") if r % 2 == 0 else ("B", "A"):
            w, c, ends[k] = run(solvers[k])
            wall[k].append(w)
            cpu[k].append(c)
    n = model.particle_count * args.substeps
    out = {
        "particles": model.particle_count,
        "substeps": args.substeps,
        "threads": args.threads,
        "flag": args.flag,
        "rounds": args.rounds,
        "max_abs_x_diff": float(np.abs(ends["A"] - ends["B"]).max()),
    }
    for k in ("A", "B"):
        out[f"{k}_wall_ms_median"] = round(1e3 * statistics.median(wall[k]), 2)
        out[f"{k}_cpu_ms_median"] = round(1e3 * statistics.median(cpu[k]), 2)
        out[f"{k}_M_per_s_wall"] = round(n / statistics.median(wall[k]) / 1e6, 3)
    out["speedup_wall_median_of_rounds"] = round(
        statistics.median(x / y for x, y in zip(wall["A"], wall["B"], strict=True)), 3
    )
    out["speedup_cpu_median_of_rounds"] = round(
        statistics.median(x / y for x, y in zip(cpu["A"], cpu["B"], strict=True)), 3
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
