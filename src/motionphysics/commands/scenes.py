"""motionphysics scenes: list the bundled (builtin) scenes, one per line.

Each line is builtin:NAME then a one-line description; use the first column as
scene.source in a run config or as the SCENE of motionphysics render.
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "scenes",
        help="list the bundled scenes (builtin:NAME)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from motionphysics.scene.builtin import list_builtins

    items = list_builtins()
    width = max(len("builtin:" + name) for name, _ in items)
    for name, desc in items:
        print(f"{'builtin:' + name:<{width}}  {desc}")
    return 0
