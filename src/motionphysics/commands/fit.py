"""motionphysics fit CONFIG --reference VIDEO_OR_NPZ: system identification.

Recovers the material parameters that reproduce a reference (a video from the config's
camera, or a ``trajectory.npz`` of ``simulate``) in two stages: a forward-only global
search over the handbook range (``--no-global`` skips it), then differentiable
simulation from its best candidate (the config's material without it). The library is :mod:`motionphysics.optimize.fit`; this
module is argument handling only.
"""

from __future__ import annotations

from pathlib import Path

from motionphysics.errors import UserInputError


def _main(args) -> int:
    from motionphysics.commands.run import default_out, plan_output
    from motionphysics.io.writer import print_summary
    from motionphysics.optimize.fit import run_fit
    from motionphysics.progress import Progress
    from motionphysics.runconfig import load_run_config

    if args.iters is not None and args.iters < 0:
        raise UserInputError(f"--iters: expected a count >= 0, got {args.iters}")
    overrides = {"device": args.device}
    if args.no_global:
        overrides["optimize.global_search"] = False
    cfg = load_run_config(args.config, overrides)
    out = Path(args.out) if args.out else default_out(args.config, "fit")
    quiet = getattr(args, "quiet", False)
    total = cfg.optimize.iterations if args.iters is None else int(args.iters)
    expect = {"--iters": ("fit.iterations", total)}
    ref = Path(args.reference)
    if ref.is_file():
        # the same digest run_fit records (params.json: reference.sha256)
        from motionphysics.io.reference import _digest

        expect["--reference"] = ("reference.sha256", _digest(ref))
    mode = plan_output(args, out, cfg, "fit", expect=expect, iterations=total)
    if mode is None:
        return 0  # --resume of a complete fit: nothing to do, nothing rewritten
    resume, force = mode
    with Progress(quiet=quiet, verbose=getattr(args, "verbose", False)) as prog:
        result = run_fit(
            cfg,
            args.reference,
            out,
            resume=resume,
            force=force,
            iterations=args.iters,
            progress=prog,
            config_origin=args.config,
        )
    if not quiet:
        print_summary(result)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="system identification: fit the material to a reference",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "config", metavar="CONFIG", help="run config (YAML): scene, forces, camera, start material"
    )
    p.add_argument(
        "--reference",
        required=True,
        metavar="VIDEO_OR_NPZ",
        help=".mp4/.gif or .npz with 'frames' (video) or 'x' (trajectory.npz of simulate)",
    )
    p.add_argument("--out", metavar="DIR", help="run directory (default: runs/<config name>)")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue a killed fit of the same config and reference in --out",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite a run already in --out (with --resume: only when it differs)",
    )
    p.add_argument(
        "--iters", type=int, metavar="N", help="optimisation iterations (default: the config's)"
    )
    p.add_argument(
        "--no-global",
        action="store_true",
        help="skip the global stage (optimize.global_search: false): gradient stage only, "
        "from the config's material",
    )
    p.add_argument("--device", choices=["cpu", "cuda"], help="where to simulate and render")
    p.set_defaults(func=_main)
