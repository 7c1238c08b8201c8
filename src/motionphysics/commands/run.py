"""motionphysics run CONFIG: the main job (scene -> material from the prompt -> simulate -> render).

Writes the run directory (README, "Run directory"). With ``--prior none`` (the
default) and no ``optimize.losses`` no optimisation happens; otherwise the refinement
stage (:mod:`motionphysics.optimize.refine`) optimises the estimated material against
the configured losses before the final simulation. Choices of ``--init``, ``--prior``
and ``--loss`` come from the registries.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def default_out(config: str | None, name: str = "run") -> Path:
    """``runs/<config stem>`` (or ``runs/<name>``), the default ``--out``."""
    stem = Path(config).stem if config else name
    return Path("runs") / stem


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``run`` and ``simulate`` (``--out``, ``--device``, ``--resume`` ...)."""
    p.add_argument("--out", metavar="DIR", help="run directory (default: runs/<config name>)")
    p.add_argument("--device", choices=["cpu", "cuda"], help="where to simulate and render")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted run of the same config in --out (a complete one: "
        "nothing to do)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite a run already in --out (with --resume: only when its config differs)",
    )
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


def plan_output(
    args, out: Path, cfg, command: str, *, expect=None, iterations: int | None = None
) -> tuple[bool, bool] | None:
    """``--resume`` / ``--force`` for ``out``: ``(resume, force)`` for the writer, or
    ``None`` when ``--resume`` finds the run complete (the caller then writes nothing).

    With ``--resume`` one line on stderr says what happens (see
    :func:`motionphysics.io.resume.plan_resume`); a run of a different config is refused
    (UserInputError naming the first differing key) unless ``--force`` is given too.
    """
    import sys

    from motionphysics.io.resume import plan_resume

    if not getattr(args, "resume", False):
        return False, bool(getattr(args, "force", False))
    plan = plan_resume(
        out,
        cfg,
        command=command,
        force=bool(getattr(args, "force", False)),
        expect=expect,
        iterations=iterations,
    )
    print(f"motionphysics: {plan.message}", file=sys.stderr, flush=True)
    if plan.action == "complete":
        if not getattr(args, "quiet", False):
            from motionphysics.io.resume import completed_result
            from motionphysics.io.writer import print_summary

            print_summary(completed_result(out))
        return None
    if plan.action == "continue":
        return True, False
    if plan.action == "restart":
        return False, True
    return False, bool(getattr(args, "force", False))


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
    from motionphysics.pipeline import print_summary, run_pipeline, wants_refinement
    from motionphysics.progress import Progress

    out = Path(args.out) if args.out else default_out(getattr(args, "config", None), command)
    refine = optimise and wants_refinement(cfg)
    mode = plan_output(
        args, out, cfg, command, iterations=cfg.optimize.iterations if refine else None
    )
    if mode is None:
        return 0  # --resume of a complete run: nothing to do, nothing rewritten
    resume, force = mode
    with Progress(
        quiet=getattr(args, "quiet", False), verbose=getattr(args, "verbose", False)
    ) as prog:
        result = run_pipeline(
            cfg,
            out,
            init_backend=init_backend,
            params_file=params_file,
            optimise=optimise,
            resume=resume,
            force=force,
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
        "optimize.prior_path": args.prior_path,
        "optimize.loss": args.loss,
        "optimize.iterations": args.iters,
        "optimize.guidance": args.guidance,
        "device": args.device,
        "export_ply": True if args.export_ply else None,
    }


def _main(args) -> int:
    from motionphysics.errors import UserInputError
    from motionphysics.flags import check_run_flags
    from motionphysics.priors import removed_prior
    from motionphysics.runconfig import load_run_config

    refused = removed_prior(args.prior) if args.prior else None
    if refused:  # refused here, in the flag's terms (the config's check would name the field)
        raise UserInputError(refused)
    cfg = load_run_config(args.config, _overrides(args))
    if args.loss is not None and cfg.optimize.prior == "none":
        raise UserInputError(
            f"--loss {args.loss}: a loss given on the command line drives the refinement by a "
            "video prior, but the prior is none; add --prior NAME (or list prior-free losses "
            "in the config's optimize.losses)"
        )
    if args.iters is not None and args.iters < 0:
        raise UserInputError(f"--iters: expected a count >= 0, got {args.iters}")
    for flag, value in (("--prior-path", args.prior_path), ("--guidance", args.guidance)):
        if value is not None and cfg.optimize.prior == "none":
            raise UserInputError(
                f"{flag} {value}: it applies to a video prior, but the prior is none; "
                "add --prior NAME"
            )
    if cfg.optimize.per_particle and cfg.optimize.prior != "none":
        # The refinement could optimise [P] fields, but the final simulation resolves
        # scene-wide values (assembly.resolve_simulation): refuse rather than drop them.
        raise UserInputError(
            f"optimize.per_particle: {', '.join(cfg.optimize.per_particle)} per particle is "
            "not supported by run's refinement in this build (the final simulation takes "
            "scene-wide values); remove optimize.per_particle"
        )
    if cfg.optimize.prior != "none" and cfg.optimize.iterations > 0:
        from motionphysics.optimize.refine import check_prior_path

        check_prior_path(cfg)  # the model directory, before the run directory is written
    given = {"loss": args.loss, "iters": args.iters, "prior": args.prior, "init": args.init}
    for line in check_run_flags(cfg, given, command="run"):
        print(line, file=sys.stderr)
    return execute(
        args,
        cfg,
        optimise=True,
        init_backend=args.init or "kb",
        command="run",
        config_origin=args.config,
    )


def register(subparsers) -> None:
    from motionphysics.init import INIT_BACKENDS
    from motionphysics.losses import LOSSES
    from motionphysics.priors import PRIORS

    p = subparsers.add_parser(
        "run",
        help="main job: estimate the material from the prompt, simulate, render",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("config", metavar="CONFIG", help="run config (YAML); see examples/")
    p.add_argument("--prompt", help="text prompt (overrides the config's prompt)")
    p.add_argument(
        "--init",
        choices=INIT_BACKENDS.names(),
        default=None,
        help="material estimation backend (default: kb, offline)",
    )
    p.add_argument(
        "--prior",
        choices=PRIORS.choices("none"),
        help="video prior for the refinement (default: the config's, none)",
    )
    p.add_argument(
        "--prior-path", metavar="DIR", help="model directory of the prior (save_pretrained layout)"
    )
    p.add_argument("--loss", choices=LOSSES.names(), help="refinement loss (needs --prior)")
    p.add_argument("--iters", type=int, metavar="N", help="optimisation iterations")
    p.add_argument("--guidance", type=float, metavar="W", help="classifier-free guidance scale")
    add_run_options(p)
    p.set_defaults(func=_main)
