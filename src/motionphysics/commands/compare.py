"""motionphysics compare RUN_DIR... --out DIR: side-by-side videos and a metrics table.

Writes ``DIR/compare.mp4`` (every run's video in a labelled grid, same frame count:
shorter videos hold their last frame), ``DIR/compare.md`` and ``DIR/compare.html``
(the layout of the paper's Table 2: one column per run; rows: class, every parameter,
OC, CLIPSIM, ECMS with its terms, motion adherence, optimisation time) and
``DIR/compare.json``. Each run is evaluated from its files (``metrics.json`` when it
already holds ``ecms``, else computed now without writing into the run).
"""

from __future__ import annotations


def _main(args) -> int:
    from motionphysics.evaluation.compare import compare_runs

    out = compare_runs(args.run_dirs, args.out, labels=args.labels, force=args.force)
    if not args.quiet:
        for name in ("compare.mp4", "compare.md", "compare.html"):
            if (out / name).exists():
                print(f"{name:<13} {out / name}")
        print((out / "compare.md").read_text())
    return 0


def register(subparsers) -> None:
    from motionphysics.commands.run import add_display_options

    p = subparsers.add_parser(
        "compare",
        help="side-by-side videos and a metrics table of several runs",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run directories")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the comparison")
    p.add_argument(
        "--labels", nargs="+", default=None, help="one label per run (default: folder names)"
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing comparison in --out")
    add_display_options(p)
    p.set_defaults(func=_main)
