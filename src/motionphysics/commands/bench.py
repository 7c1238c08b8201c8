"""``motionphysics bench TARGET ...``: speed benchmarks of the project's kernels.

Each target lives in a module listed in :data:`BENCH_TARGETS` that exposes
``register_target(subparsers)``; it adds its own sub-subcommand (``render``,
``mpm`` ...) and sets ``func``. Figures go to BENCHMARKS.md by hand, with the command.
"""

from __future__ import annotations

import importlib

BENCH_TARGETS = [
    "motionphysics.render.bench",
    "motionphysics.sim.bench",
    "motionphysics.optimize.bench",
    "motionphysics.optimize.bench_fit",
]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="speed benchmarks (render, mpm)",
        description="Speed benchmarks of the renderer and the simulator on standard scenes. "
        "Each target prints its timings (--json: one JSON object); BENCHMARKS.md lists the "
        "figures with the commands that produced them.",
    )
    sub = p.add_subparsers(dest="target", metavar="TARGET")
    sub.required = True
    for name in BENCH_TARGETS:
        importlib.import_module(name).register_target(sub)
