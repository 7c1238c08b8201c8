"""Genesis MPM on the standard benchmark scene (peer for ``motionphysics bench mpm``).

Runs in the SEPARATE peers environment (``benchmarks/setup_peers.sh``), with Genesis'
own PyPI package on its CPU backend. The scene is the one of ``taichi_mpm.py`` and of
``motionphysics bench mpm``: unit domain, ``grid`` cells per unit length, an elastic
cube of side 0.25 centred in x, y with its lower face at z = 0.15, ``n_side``^3
particles placed on the same lattice (we overwrite Genesis' sampled positions with
ours, so the particle count and layout are identical), fixed corotated elasticity
(Genesis' ``model='corotation'``) E = 1e5, nu = 0.3, rho = 1000, gravity 9.8 along -z,
initial velocity 2 m/s along -z, one MPM substep per step with dt = 1e-4, float32.

Differences we cannot remove (Genesis' design): its boundary is imposed on particle
positions and velocities 3 cells inside the domain rather than on grid velocities, and
it keeps a per-substep particle history for differentiability. Thread count is
``QD_NUM_THREADS`` (Genesis defaults to 1 CPU thread).

Prints one JSON object with ``particle_substeps_per_s`` (median of ``--repeats`` timed
runs after one untimed warm-up that includes kernel compilation).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    os.environ.setdefault("QD_NUM_THREADS", str(args.threads))

    import genesis as gs
    import numpy as np

    gs.init(backend=gs.cpu, precision="32", logging_level="warning")

    n_side = max(1, round(args.particles ** (1.0 / 3.0)))
    side, lower_z = 0.25, 0.15
    h = side / n_side
    dt = 1e-4
    scene = gs.Scene(
        sim_options=gs.options.SimOptions(dt=dt, substeps=1, gravity=(0.0, 0.0, -9.8)),
        mpm_options=gs.options.MPMOptions(
            lower_bound=(0.0, 0.0, 0.0),
            upper_bound=(1.0, 1.0, 1.0),
            grid_density=args.grid,
            particle_size=h,
        ),
        show_viewer=False,
    )
    cube = scene.add_entity(
        material=gs.materials.MPM.Elastic(
            E=1e5, nu=0.3, rho=1000.0, model="corotation", sampler="regular"
        ),
        morph=gs.morphs.Box(pos=(0.5, 0.5, lower_z + side / 2), size=(side, side, side)),
    )
    scene.build()

    idx = (np.arange(n_side) + 0.5) * h
    gx, gy, gz = np.meshgrid(idx, idx, idx, indexing="ij")
    lattice = np.stack(
        [gx.ravel() + 0.5 - side / 2, gy.ravel() + 0.5 - side / 2, gz.ravel() + lower_z], axis=1
    ).astype(np.float32)
    n_particles = cube.n_particles
    same_layout = n_particles == lattice.shape[0]

    def reset():
        scene.reset()
        if same_layout:
            cube.set_position(lattice)
        cube.set_velocity(np.tile(np.array([0.0, 0.0, -2.0], np.float32), (n_particles, 1)))

    def run_once() -> float:
        reset()
        t0 = time.perf_counter()
        for _ in range(args.substeps):
            scene.step()
        pos = cube.get_particles_pos()  # forces a device sync
        _ = float(pos[..., 2].mean())
        return time.perf_counter() - t0

    warmup = run_once()
    times = [run_once() for _ in range(args.repeats)]
    med = statistics.median(times)
    pos = np.asarray(cube.get_particles_pos()).reshape(-1, 3)
    vel = np.asarray(cube.get_particles_vel()).reshape(-1, 3)
    print(
        json.dumps(
            {
                "engine": "genesis",
                "version": gs.__version__,
                "arch": "cpu",
                "threads": int(os.environ["QD_NUM_THREADS"]),
                "particles": int(n_particles),
                "same_lattice": bool(same_layout),
                "grid": args.grid,
                "substeps": args.substeps,
                "dt": dt,
                "warmup_s": warmup,
                "times_s": times,
                "particle_substeps_per_s": n_particles * args.substeps / med,
                "com_z_end": float(pos[:, 2].mean()),
                "vz_mean_end": float(vel[:, 2].mean()),
            }
        )
    )


if __name__ == "__main__":
    main()
