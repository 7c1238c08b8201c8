"""The ``motionphysics`` command.

Each subcommand lives in ``motionphysics.commands.<name>`` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (a callable taking
the parsed namespace and returning an exit status). Command modules import heavy
packages inside their functions so ``motionphysics --help`` stays fast.

Exit status: 0 success, 2 bad input (one line on stderr), 1 internal error,
130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from motionphysics import __version__
from motionphysics.errors import RunInterrupted, SimulationError, UserInputError

# Order here is the order of `motionphysics --help`.
COMMANDS = [
    "scenes",
    "render",
    "bench",
    "demo",
    "run",
    "simulate",
    "fit",
    "eval",
    "init",
    "prior",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="motionphysics",
        description="Text-guided physical simulation of 3D Gaussian-splat scenes.",
    )
    parser.add_argument("--version", action="version", version=f"motionphysics {__version__}")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("--verbose", action="store_true", help="more detail on stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"motionphysics.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserInputError as err:
        print(f"motionphysics: error: {err}", file=sys.stderr)
        return 2
    except SimulationError as err:
        print(f"motionphysics: simulation failed: {err}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, RunInterrupted) as err:
        msg = str(err) or "interrupted"
        print(f"motionphysics: {msg}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
