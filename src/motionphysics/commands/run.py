"""``motionphysics run CONFIG``: the main job (scene -> material from the prompt -> simulate -> render).

Writes the run directory of DESIGN.md. With ``--prior none`` (the default in this
build) no optimisation happens; a prior other than ``none`` goes through the
optimiser plug-in of :mod:`motionphysics.pipeline` and fails with exit status 2 when
this build has no such prior.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def default_out(config: str | None, name: str = "run") -> Path:
    """``runs/<config stem>`` (or ``runs/<name>``), the default ``--out``."""
    stem = Path(config).stem if config else name
    return Path("runs") / stem


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``run`` and ``simulate`` (``--out``, ``--device``, ``--resume`` ...)."""
    p.add_argument("--out", metavar="DIR", help="run directory (default: runs/<config name>)")
    p.add_argument("--device", choices=["cpu", "cuda"], help="where to simulate and render")
    p.add_argument("--resume", action="store_true", help="continue a partial run in --out")
    p.add_argument("--force", action="store_true", help="overwrite a run already in --out")
    p.add_argument(
        "--export-ply",
        action="store_true",
        default=None,
        help="also write INRIA-format splats per frame to splats/",
    )
    add_display_options(p)


def add_display_options(p: argparse.ArgumentParser) -> None:
    """``--quiet`` / ``--verbose`` after the subcommand too (they default to the global ones)."""
    p.add_argument(
        "--quiet",
        action="store_true",
        default=argparse.SUPPRESS,
        help="no progress display and no summary",
    )
    p.add_argument(
        "--verbose",
        action="store_true",
        default=argparse.SUPPRESS,
        help="one line per stage on stderr, even in a pipe",
    )


def execute(
    args,
    cfg,
    *,
    optimise: bool,
    init_backend: str = "kb",
    params_file=None,
    command: str = "run",
    config_origin: str = "<config>",
) -> int:
    """Run the pipeline with a progress display and print the summary."""
    from motionphysics.pipeline import print_summary, run_pipeline
    from motionphysics.progress import Progress

    out = Path(args.out) if args.out else default_out(getattr(args, "config", None), command)
    with Progress(
        quiet=getattr(args, "quiet", False), verbose=getattr(args, "verbose", False)
    ) as prog:
        result = run_pipeline(
            cfg,
            out,
            init_backend=init_backend,
            params_file=params_file,
            optimise=optimise,
            resume=args.resume,
            force=args.force,
            progress=prog,
            config_origin=config_origin,
            command=command,
        )
    if not getattr(args, "quiet", False):
        print_summary(result)
    return 0


def _overrides(args) -> dict:
    return {
        "prompt": args.prompt,
        "optimize.prior": args.prior,
        "optimize.loss": args.loss,
        "optimize.iterations": args.iters,
        "device": args.device,
        "export_ply": True if args.export_ply else None,
    }


def _main(args) -> int:
    from motionphysics.pipeline import load_run_config

    cfg = load_run_config(args.config, _overrides(args))
    return execute(
        args, cfg, optimise=True, init_backend=args.init, command="run", config_origin=args.config
    )


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="main job: estimate the material from the prompt, simulate, render",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("config", metavar="CONFIG", help="run config (YAML); see examples/")
    p.add_argument("--prompt", help="text prompt (overrides the config's prompt)")
    p.add_argument(
        "--init",
        choices=["kb", "llm", "median", "naive"],
        default="kb",
        help="material estimation backend (default: kb, offline)",
    )
    p.add_argument(
        "--prior",
        choices=["none", "tiny", "cogvideox", "modelscope"],
        help="video prior for optimisation (default: the config's, none)",
    )
    p.add_argument("--loss", choices=["lmd", "sds", "flow"], help="optimisation loss")
    p.add_argument("--iters", type=int, metavar="N", help="optimisation iterations")
    add_run_options(p)
    p.set_defaults(func=_main)
