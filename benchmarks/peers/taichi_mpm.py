"""Taichi CPU MLS-MPM on the standard benchmark scene (peer for ``motionphysics bench mpm``).

Runs in the SEPARATE peers environment (``benchmarks/setup_peers.sh``), never in the
project's venv. Written here from the MLS-MPM formulation (Hu et al. 2018, "A moving
least squares material point method with displacement discontinuity and two-way rigid
body coupling", SIGGRAPH) so that it integrates exactly the scene our Warp solver does:

- unit domain [0, 1]^3, ``grid`` cells per side (dx = 1 / grid), nodes 0..grid, and
  ``bound`` = 3 boundary cells on every face where the velocity component pointing
  into the wall is zeroed (slip walls);
- an elastic cube of side 0.25 centred in x and y with its lower face at z = 0.15,
  ``n_side``^3 particles on a lattice (cell-centred in the cube), volume (0.25/n_side)^3;
- fixed corotated elasticity, E = 1e5 Pa, nu = 0.3, rho = 1000 kg/m^3;
- quadratic B-spline weights, APIC transfers (affine C), F <- (I + dt C) F;
- gravity 9.8 m/s^2 along -z, initial velocity 2 m/s along -z, dt = 1e-4 s, float32.

Prints one JSON object: particle_substeps_per_s is the median over ``--repeats`` timed
runs of ``--substeps`` substeps each, after one untimed warm-up run (JIT compile).
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
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    import numpy as np
    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=args.threads, default_fp=ti.f32, log_level=ti.WARN)

    n_side = max(1, round(args.particles ** (1.0 / 3.0)))
    n_particles = n_side**3
    n_grid = args.grid
    dx = 1.0 / n_grid
    inv_dx = float(n_grid)
    dt = 1e-4
    bound = 3
    side, lower_z = 0.25, 0.15
    p_vol = (side / n_side) ** 3
    rho, E, nu = 1000.0, 1e5, 0.3
    p_mass = rho * p_vol
    mu0 = E / (2 * (1 + nu))
    la0 = E * nu / ((1 + nu) * (1 - 2 * nu))
    gravity = 9.8

    x = ti.Vector.field(3, dtype=ti.f32, shape=n_particles)
    v = ti.Vector.field(3, dtype=ti.f32, shape=n_particles)
    C = ti.Matrix.field(3, 3, dtype=ti.f32, shape=n_particles)
    F = ti.Matrix.field(3, 3, dtype=ti.f32, shape=n_particles)
    grid_v = ti.Vector.field(3, dtype=ti.f32, shape=(n_grid + 1,) * 3)
    grid_m = ti.field(dtype=ti.f32, shape=(n_grid + 1,) * 3)

    @ti.kernel
    def substep():
        for I in ti.grouped(grid_m):
            grid_v[I] = ti.Vector.zero(ti.f32, 3)
            grid_m[I] = 0.0
        for p in x:
            base = (x[p] * inv_dx - 0.5).cast(int)
            fx = x[p] * inv_dx - base.cast(ti.f32)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            U, sig, V = ti.svd(F[p])
            R = U @ V.transpose()
            J = sig[0, 0] * sig[1, 1] * sig[2, 2]
            # Kirchhoff stress of fixed corotated: tau = P F^T.
            tau = 2.0 * mu0 * (F[p] - R) @ F[p].transpose() + ti.Matrix.identity(
                ti.f32, 3
            ) * la0 * J * (J - 1.0)
            affine = -dt * p_vol * 4.0 * inv_dx * inv_dx * tau + p_mass * C[p]
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                offset = ti.Vector([i, j, k])
                dpos = (offset.cast(ti.f32) - fx) * dx
                weight = w[i][0] * w[j][1] * w[k][2]
                grid_v[base + offset] += weight * (p_mass * v[p] + affine @ dpos)
                grid_m[base + offset] += weight * p_mass
        for I in ti.grouped(grid_m):
            if grid_m[I] > 0:
                vi = grid_v[I] / grid_m[I]
                vi[2] -= dt * gravity
                for d in ti.static(range(3)):
                    if I[d] < bound and vi[d] < 0:
                        vi[d] = 0.0
                    if I[d] > n_grid - bound and vi[d] > 0:
                        vi[d] = 0.0
                grid_v[I] = vi
        for p in x:
            base = (x[p] * inv_dx - 0.5).cast(int)
            fx = x[p] * inv_dx - base.cast(ti.f32)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            new_v = ti.Vector.zero(ti.f32, 3)
            new_C = ti.Matrix.zero(ti.f32, 3, 3)
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                offset = ti.Vector([i, j, k])
                dpos = offset.cast(ti.f32) - fx
                g_v = grid_v[base + offset]
                weight = w[i][0] * w[j][1] * w[k][2]
                new_v += weight * g_v
                new_C += 4.0 * inv_dx * weight * g_v.outer_product(dpos)
            v[p] = new_v
            C[p] = new_C
            F[p] = (ti.Matrix.identity(ti.f32, 3) + dt * new_C) @ F[p]
            x[p] += dt * new_v

    h = side / n_side
    idx = (np.arange(n_side) + 0.5) * h
    gx, gy, gz = np.meshgrid(idx, idx, idx, indexing="ij")
    x0 = np.stack(
        [gx.ravel() + 0.5 - side / 2, gy.ravel() + 0.5 - side / 2, gz.ravel() + lower_z], axis=1
    ).astype(np.float32)

    def reset():
        x.from_numpy(x0)
        v.from_numpy(np.tile(np.array([0.0, 0.0, -2.0], np.float32), (n_particles, 1)))
        C.from_numpy(np.zeros((n_particles, 3, 3), np.float32))
        F.from_numpy(np.tile(np.eye(3, dtype=np.float32), (n_particles, 1, 1)))

    def run_once() -> float:
        reset()
        ti.sync()
        t0 = time.perf_counter()
        for _ in range(args.substeps):
            substep()
        ti.sync()
        return time.perf_counter() - t0

    warmup = run_once()  # includes JIT compile
    times = [run_once() for _ in range(args.repeats)]
    med = statistics.median(times)
    xs = x.to_numpy()
    vs = v.to_numpy()
    print(
        json.dumps(
            {
                "engine": "taichi",
                "version": ".".join(str(p) for p in ti.__version__),
                "arch": "cpu",
                "threads": args.threads,
                "particles": n_particles,
                "grid": n_grid,
                "substeps": args.substeps,
                "dt": dt,
                "warmup_s": warmup,
                "times_s": times,
                "particle_substeps_per_s": n_particles * args.substeps / med,
                "com_z_end": float(xs[:, 2].mean()),
                "vz_mean_end": float(vs[:, 2].mean()),
            }
        )
    )


if __name__ == "__main__":
    main()
