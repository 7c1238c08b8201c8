"""The ``motionphysics`` command.

Each subcommand lives in ``motionphysics.commands.<name>`` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (a callable taking
the parsed namespace and returning an exit status). Command modules import heavy
packages inside their functions so ``motionphysics --help`` stays fast.

Exit status: 0 success, 2 bad input (one line on stderr), 1 an output that could not
be written (one line) or an internal error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from motionphysics import __version__
from motionphysics.errors import OutputError, RunInterrupted, SimulationError, UserInputError

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
    "compare",
    "init",
    "view",
    "batch",
    "prior",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="motionphysics",
        description="Text-guided physical simulation of 3D Gaussian-splat scenes.",
    )
    parser.add_argument("--version", action="version", version=f"motionphysics {__version__}")
    for flag, text in GLOBAL_OPTIONS:
        parser.add_argument(flag, action="store_true", help=text)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"motionphysics.commands.{name}").register(sub)
    for sp in sub.choices.values():
        add_global_options(sp)
    return parser


GLOBAL_OPTIONS = (
    ("--quiet", "no progress display (warnings about the material are still printed)"),
    ("--verbose", "more detail on stderr"),
)
"""Options accepted before or after every command (``motionphysics --quiet run`` and
``motionphysics run --quiet`` mean the same)."""


def add_global_options(p: argparse.ArgumentParser) -> None:
    """Add :data:`GLOBAL_OPTIONS` to a subcommand parser that does not define them itself.

    ``default=SUPPRESS`` so the value given before the command is not reset after it.
    """
    for flag, text in GLOBAL_OPTIONS:
        if flag not in p._option_string_actions:
            p.add_argument(flag, action="store_true", default=argparse.SUPPRESS, help=text)


def parse_args(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse; an unknown argument is reported with the usage of the command it followed."""
    args, extra = parser.parse_known_args(argv)
    if extra:
        sub = _subparser(parser, getattr(args, "command", None))
        (sub or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def _subparser(parser: argparse.ArgumentParser, name: str | None):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name in action.choices:
            return action.choices[name]
    return None


def one_line(err: BaseException) -> str:
    """The message of ``err`` on one line: a value quoted from a file may hold line breaks
    or other control characters; they are shown escaped, never printed."""
    text = str(err)
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parse_args(parser, argv)
    try:
        return int(args.func(args) or 0)
    except UserInputError as err:
        print(f"motionphysics: error: {one_line(err)}", file=sys.stderr)
        return 2
    except SimulationError as err:
        print(f"motionphysics: simulation failed: {err}", file=sys.stderr)
        return 2
    except OutputError as err:
        print(f"motionphysics: error: {one_line(err)}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, RunInterrupted) as err:
        msg = str(err) or "interrupted"
        print(f"motionphysics: {msg}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
