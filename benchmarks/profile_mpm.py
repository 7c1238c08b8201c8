"""Per-kernel profile of the MPM forward, the recorded (tape-keeping) forward and the full
backward, on the ``motionphysics bench mpm`` scene.

Each of the three is run ``--repeats`` times after a warm-up, alternated (plain forward,
``Rollout.forward(record_tapes=True)``, ``Rollout.backward`` of a random linear loss on
every frame's positions). Every ``wp.launch``, ``wp.copy``, ``wp.zeros`` / ``empty`` /
``clone`` and array ``zero_`` / ``numpy`` / ``assign`` on the main thread is timed (wall
and thread CPU time); the particle-chunked launches of the solver are timed as one
(``chunks:<kernel>``, wall and CPU of the caller's thread: with ``--threads 2`` the
worker thread's CPU time is not counted). Reported per substep: each phase's wall and
process CPU median, then the mean of each item over the repeats. ``(python / untimed)``
is the phase's mean wall time minus the timed items. Process CPU time is the measure to
compare on a shared machine (one thread): wall time there drifts with other load.

    MOTIONPHYSICS_CACHE=.cache .venv/bin/python benchmarks/profile_mpm.py \\
        --particles 20000 --substeps 50 --threads 1 --repeats 4

This script only measures; it patches Warp's functions in its own process.
"""

from __future__ import annotations

import argparse
import collections
import threading
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=50)
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1, choices=(1, 2))
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args()

    import warp

    from motionphysics.runtime import init_warp
    from motionphysics.sim import bench as B
    from motionphysics.sim import solver as SV
    from motionphysics.sim.rollout import Rollout

    init_warp()
    main_thread = threading.main_thread()
    wall: dict = collections.defaultdict(float)
    cpu: dict = collections.defaultdict(float)
    calls: dict = collections.defaultdict(int)
    phase = ["-"]
    inside: list = [None]  # name of the first launch inside a chunked call

    def timed(name_of, fn):
        def wrapper(*a, **k):
            if threading.current_thread() is not main_thread:
                return fn(*a, **k)
            if inside[0] is not None:
                if inside[0] == "":
                    inside[0] = name_of(a, k)
                return fn(*a, **k)
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                key = (phase[0], name_of(a, k))
                wall[key] += time.perf_counter() - t0
                cpu[key] += time.thread_time() - c0
                calls[key] += 1

        return wrapper

    def launch_name(a, k):
        kernel = k.get("kernel", a[0] if a else None)
        return kernel.key + (" [adj]" if k.get("adjoint") else "")

    warp.launch = timed(launch_name, warp.launch)
    for name in ("copy", "zeros", "empty", "clone"):
        setattr(warp, name, timed(lambda a, k, n=name: f"wp.{n}", getattr(warp, name)))
    for name in ("zero_", "numpy", "assign"):
        setattr(
            warp.array, name, timed(lambda a, k, n=name: f"array.{n}", getattr(warp.array, name))
        )
    chunked = SV.Solver._chunked

    def chunked_timed(self, fn):
        inside[0] = ""
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            return chunked(self, fn)
        finally:
            key = (phase[0], "chunks:" + (inside[0] or "?"))
            inside[0] = None
            wall[key] += time.perf_counter() - t0
            cpu[key] += time.thread_time() - c0
            calls[key] += 1

    SV.Solver._chunked = chunked_timed

    model, solver, x0 = B.build_scene(
        args.particles, args.grid, threads=args.threads, requires_grad=True
    )
    start = model.state(x0, B.INITIAL_VELOCITY)
    ping = [model.state(x0, B.INITIAL_VELOCITY), model.state(x0, B.INITIAL_VELOCITY)]
    S, frames = args.substeps, args.frames
    steps = S * frames
    rollout = Rollout(solver, S, S * B.DT)
    rng = np.random.default_rng(0)
    p = model.particle_count
    adjoints = {
        f: {"x": rng.standard_normal((p, 3)).astype(np.float32)} for f in range(1, frames + 1)
    }

    def forward():
        a, b = ping
        a.assign(start)
        for k in range(steps):
            solver.step(a, b, B.DT, t=k * B.DT, substep=k)
            a, b = b, a

    def recorded_forward():
        rollout.forward(start, frames + 1, keep_checkpoints=True, check=False, record_tapes=True)

    def backward():
        model.zero_grad()
        rollout.backward(adjoints, grad_mode="full")

    phases = (("forward", forward), ("recorded_fwd", recorded_forward), ("backward", backward))
    walls: dict = collections.defaultdict(list)
    cpus: dict = collections.defaultdict(list)
    for _name, fn in phases:  # warm-up: kernel loads, buffers
        fn()
    for _ in range(args.repeats):
        for name, fn in phases:
            phase[0] = name
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            walls[name].append(time.perf_counter() - t0)
            cpus[name].append(time.process_time() - c0)
            phase[0] = "-"
    solver.close()
    print(f"# particles {p} grid {args.grid} substeps {S} frames {frames} threads {solver.chunks}")
    print("grad_E_sum", float(model.params["E"].grad.numpy().sum()))
    R, ms = args.repeats, 1e3 / steps
    for name, _fn in phases:
        print(
            f"\n## {name}: wall median {np.median(walls[name]) * ms:.3f} ms/substep, "
            f"process CPU median {np.median(cpus[name]) * ms:.3f}"
        )
        items = sorted(
            ((k[1], v / R, cpu[k] / R, calls[k] / R) for k, v in wall.items() if k[0] == name),
            key=lambda t: -t[1],
        )
        for item, w, c, n in items:
            print(
                f"  {item:36s} {w * ms:7.3f} wall {c * ms:7.3f} cpu ms/substep {n / steps:5.1f} calls"
            )
        untimed = float(np.mean(walls[name])) - sum(t[1] for t in items)
        print(f"  {'(python / untimed)':36s} {untimed * ms:7.3f} wall ms/substep")


if __name__ == "__main__":
    main()
