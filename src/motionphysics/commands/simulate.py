"""motionphysics simulate CONFIG: forward simulation only, no optimisation.

The material comes from ``--params FILE`` (a ``params.json`` of an earlier run, or a
plain ``{"class", "density", "params"}``) and the config's ``material:`` block (which
wins field by field); when neither names a complete material, the missing fields are
estimated from the prompt with the offline knowledge base (``kb``). Writes
trajectory.npz, video.mp4, params.json, run.yaml (and metrics, plots, report).
"""

from __future__ import annotations

from motionphysics.commands.run import add_run_options, execute


def _main(args) -> int:
    from motionphysics.pipeline import load_run_config

    cfg = load_run_config(
        args.config, {"device": args.device, "export_ply": True if args.export_ply else None}
    )
    return execute(
        args,
        cfg,
        optimise=False,
        init_backend="kb",
        params_file=args.params,
        command="simulate",
        config_origin=args.config,
    )


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="forward simulation with a given material",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("config", metavar="CONFIG", help="run config (YAML)")
    p.add_argument(
        "--params",
        metavar="JSON",
        help="material from a params.json (of a previous run) or {class, density, params}",
    )
    add_run_options(p)
    p.set_defaults(func=_main)
