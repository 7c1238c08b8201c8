"""Time-step dependence: the same config and physical parameters at several substep counts.

For a few material classes (a cube dropped at 2 m/s on a frictional floor), simulates
the config with ``sim.substeps`` = each of ``--counts`` (and ``auto``) and reports the
mean squared distance [m^2] of every trajectory to the one with the most substeps
(over all frames and particles), next to the difference a factor ``--factor`` in the
class's stiffness / viscosity makes at the auto count. The simulation values are
listed too: under a fixed count the sim map's time step is ``frame_dt / n``, so the
count also moves the compressed stiffness (``materials.simmap``) — the count is part of
the model.

    .venv/bin/python benchmarks/bench_substeps.py [--particles 1000] [--grid 16]
        [--frames 12] [--counts 16,32,64,128,256] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys

CASES = {
    "elastic": ({"class": "elastic", "density": 1000.0, "E": 5e7, "nu": 0.3}, "E"),
    "plasticine": (
        {"class": "plasticine", "density": 1500.0, "E": 3e6, "nu": 0.3, "tau_Y": 1e4},
        "E",
    ),
    "newtonian": ({"class": "newtonian", "density": 1000.0, "mu": 2.0, "kappa": 2e9}, "mu"),
}


def _config(material, particles, grid, frames, substeps):
    return {
        "scene": {
            "source": "builtin:cube",
            "scale": 0.6,
            "translate": [0, 0, 0.45],
            "max_particles": particles,
        },
        "material": dict(material),
        "sim": {
            "grid": grid,
            "frames": frames,
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
    }


def main(argv: list[str] | None = None) -> int:
    import time

    import numpy as np

    from motionphysics.assembly import assemble
    from motionphysics.config import config_from_dict
    from motionphysics.runtime import set_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--grid", type=int, default=16)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--counts", default="16,32,64,128,256")
    ap.add_argument("--factor", type=float, default=10.0)
    ap.add_argument("--classes", default=",".join(CASES))
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    set_threads()
    counts = [int(c) for c in a.counts.split(",")]
    rows = []

    def run(material, substeps):
        cfg = config_from_dict(
            _config(material, a.particles, a.grid, a.frames, substeps), "bench_substeps"
        )
        parts = assemble(cfg, estimate=False, reference_image=False)
        t0 = time.perf_counter()
        xs, _F, _v, n = parts.simulate()
        return xs.astype(np.float64), n, parts.resolution.values, time.perf_counter() - t0

    for cls in a.classes.split(","):
        material, knob = CASES[cls]
        runs = {str(c): run(material, c) for c in counts}
        runs["auto"] = run(material, "auto")
        finest = runs[str(max(counts))][0]
        other = dict(material)
        other[knob] = material[knob] * a.factor
        x_f, _, _, _ = run(other, runs["auto"][1])
        x_a = run(material, runs["auto"][1])[0]
        knob_msd = float(((x_f - x_a) ** 2).sum(-1).mean())
        for label, (xs, n, values, seconds) in runs.items():
            rows.append(
                {
                    "class": cls,
                    "substeps": label,
                    "resolved": int(n),
                    f"sim_{knob}": float(values[knob]),
                    "msd_to_finest": float(((xs - finest) ** 2).sum(-1).mean()),
                    f"msd_{knob}_x{a.factor:g}": knob_msd,
                    "seconds": seconds,
                }
            )
    print(
        "| class | substeps | per frame | sim value | MSD to finest [m²] | "
        f"MSD of {a.factor:g}x knob [m²] | s |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        knob = CASES[r["class"]][1]
        print(
            f"| {r['class']} | {r['substeps']} | {r['resolved']} | {knob}={r[f'sim_{knob}']:.3g} | "
            f"{r['msd_to_finest']:.2e} | {r[f'msd_{knob}_x{a.factor:g}']:.2e} | "
            f"{r['seconds']:.1f} |"
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
