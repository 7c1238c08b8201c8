"""``motionphysics init``: estimate a material from a prompt and print it.

    motionphysics init "PROMPT" [--image PNG] [--backend kb|llm|median|naive] [--json]
                       [--ranges extended|paper]
    motionphysics init --from FILE [--backend ...]      one JSON line per prompt, in order

With ``--json`` one JSON object: ``material`` (``class``, ``density`` and the class's
parameters, SI), ``backend``, ``confidence``, ``clamped``, ``raw_answer`` (llm),
``matches``, ``matched``, ``warnings`` and ``adjusted`` (kb: values moved by modifiers
such as "soft" or "runny"), ``ranges`` (the range table). Without it a short table.
``--ranges paper`` clamps into the paper's table (its ablation) instead of the extended
one (the default; a run config's ``init.ranges``). A prompt the kb understands too little
of to name a class (no material, object, class or motion word it knows, e.g. a prompt
in another language; ``init.kb.UNDERSTOOD_RULE``) exits with status 2 and one line
saying what it understood and how to go on; with ``--from`` it becomes an error record
``{"prompt", "error", "understood"}`` on its own line (and a line on stderr) and the
other prompts go on (exit status 0). Warnings
(a low-confidence kb match, a non-English prompt) go to stderr, also with ``--quiet``. Bad input (empty or over-long prompt,
non-UTF-8 ``--from`` file, unreadable image, unknown backend) exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from motionphysics.errors import UserInputError


def register(subparsers) -> None:
    from motionphysics.init import INIT_BACKENDS

    p = subparsers.add_parser(
        "init",
        help="estimate the material class and parameters of a prompt",
        description="Estimate a material (class, density, parameters in SI units) from a "
        "text prompt and an optional reference image.",
    )
    p.add_argument("prompt", nargs="?", help="the simulation prompt, e.g. 'A rubber duck bounces'")
    p.add_argument(
        "--from",
        dest="from_file",
        metavar="FILE",
        help="read one prompt per line (UTF-8); print one JSON line per prompt",
    )
    p.add_argument("--image", metavar="PNG", help="reference image (a render of the scene)")
    p.add_argument(
        "--backend",
        default="kb",
        choices=INIT_BACKENDS.names(),
        help="kb: offline knowledge base (default); llm: OpenAI-compatible chat "
        "model with ranges; median: range medians; naive: LLM without ranges",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--ranges",
        choices=["extended", "paper"],
        default="extended",
        help="range table estimates are clamped into: extended (default; gels to oozing "
        "fluids) or paper (the paper's table, for its ablation); a run config's init.ranges",
    )
    p.add_argument(
        "--class",
        dest="cls",
        metavar="CLASS",
        help="force the class (only with --backend median; the other backends estimate it)",
    )
    p.add_argument(
        "--median",
        choices=["arithmetic", "geometric"],
        default=None,
        help="median of log-scaled ranges (only with --backend median; default arithmetic, "
        "as in the paper)",
    )
    p.add_argument(
        "--base-url",
        help="Chat Completions base URL (llm and naive backends; env MOTIONPHYSICS_LLM_BASE_URL)",
    )
    p.add_argument(
        "--model",
        help="model name (llm and naive backends; env MOTIONPHYSICS_LLM_MODEL; default gpt-4o)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="seconds to wait for each LLM request (llm and naive backends; default 60)",
    )
    p.add_argument(
        "--retries",
        type=int,
        default=None,
        help="LLM request retries with backoff (llm and naive backends; default 2)",
    )
    p.set_defaults(func=run)


LLM_FLAGS = ("base_url", "model", "timeout", "retries")


def check_flag_combination(args: argparse.Namespace) -> None:
    """Refuse flags that would have no effect with the chosen backend (status 2, one line)."""
    if args.cls is not None and args.backend != "median":
        raise UserInputError(
            f"--class: has no effect with --backend {args.backend} (it estimates the class); "
            "use --backend median --class CLASS, or set material.class in a run config"
        )
    if args.median is not None and args.backend != "median":
        raise UserInputError(
            f"--median: has no effect with --backend {args.backend}; use it with --backend median"
        )
    if args.backend not in ("llm", "naive"):
        given = [f for f in LLM_FLAGS if getattr(args, f) is not None]
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise UserInputError(
                f"{flag}: has no effect with --backend {args.backend}; it applies to the llm "
                "and naive backends"
            )
    if args.retries is not None and args.retries < 0:
        raise UserInputError(f"--retries: got {args.retries}; expected a count >= 0")
    if args.timeout is not None and not (args.timeout > 0 and args.timeout < float("inf")):
        raise UserInputError(f"--timeout: got {args.timeout}; expected seconds > 0")


def read_prompt_file(path: str) -> list[str]:
    """Non-blank lines of a UTF-8 file, in order; errors name the file (and line)."""
    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"--from {path}: file not found")
    raw = p.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise UserInputError(
            f"--from {path}: line {line}: not UTF-8 text (byte 0x{raw[err.start]:02x})"
        ) from None
    from motionphysics.init.estimate import check_prompt

    prompts = []
    for i, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            prompts.append(check_prompt(line, where=f"--from {path}: line {i}"))
    if not prompts:
        raise UserInputError(f"--from {path}: no prompts (one prompt per line expected)")
    return prompts


def _table(est) -> str:
    from motionphysics.materials.catalog import ranges, spec

    table = getattr(est, "ranges", None)
    mc = ranges(est.cls, table)
    rows = [
        f"material  {mc.label} ({est.cls})",
        f"backend   {est.backend}"
        + (f"   confidence {est.confidence:.2f}" if est.confidence is not None else "")
        + (f"   matched '{est.matched}'" if est.matched else ""),
    ]
    rows.append(f"  {'density':<10} {est.density:>12.4g} {'kg/m^3':<6}")
    for name in mc.names:
        unit = spec(est.cls, name, table).unit
        rows.append(
            f"  {name:<10} {est.values[name]:>12.4g} {'' if unit == '1' else unit:<6}"
            f"   range {spec(est.cls, name, table).range_text()}"
        )
    for a in getattr(est, "adjusted", []):
        rows.append(
            f"  adjusted {a['field']}: {a['from']:.4g} -> {a['to']:.4g} ({', '.join(a['words'])})"
        )
    for c in est.clamped:
        rows.append(f"  {c.kind} {c.field}: {c.original:.4g} -> {c.clamped:.4g}")
    if est.matches:
        top = ", ".join(f"{m['name']} ({m['class']})" for m in est.matches[:3])
        rows.append(f"matches   {top}")
    if est.source:
        rows.append(f"source    {est.source}")
    rows.append(f"ranges    {table}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    from motionphysics.init.estimate import (
        EstimateOptions,
        check_prompt,
        estimate_many,
        not_understood,
    )
    from motionphysics.init.llm import LLMOptions

    if (args.prompt is None) == (args.from_file is None):
        raise UserInputError("init: give either a PROMPT or --from FILE (exactly one)")
    check_flag_combination(args)
    prompts = read_prompt_file(args.from_file) if args.from_file else [check_prompt(args.prompt)]
    options = EstimateOptions(
        llm=LLMOptions(
            base_url=args.base_url,
            model=args.model,
            timeout=60.0 if args.timeout is None else args.timeout,
            max_retries=2 if args.retries is None else args.retries,
        ),
        median=args.median or "arithmetic",
        cls=args.cls,
        # what is being loaded / waited for: on a terminal, or with --verbose (a captured
        # stderr keeps only warnings and errors)
        announce=not getattr(args, "quiet", False)
        and (sys.stderr.isatty() or bool(getattr(args, "verbose", False))),
        verbose=bool(getattr(args, "verbose", False)),
        ranges=args.ranges,
    )
    estimates = estimate_many(prompts, args.image, args.backend, options)
    # A prompt the kb understood too little of to name a class is no answer: one line and
    # exit status 2; with --from an error record in its place, and the others go on.
    errors = [
        not_understood(est.prompt, est.understood, "init") if est.error else None
        for est in estimates
    ]
    if not args.from_file and errors[0]:
        raise UserInputError(errors[0])
    # Warnings about the material are never hidden, --quiet included.
    for k, est in enumerate(estimates):
        where = f"--from {args.from_file}: line {k + 1}: " if args.from_file else ""
        if errors[k]:
            print(f"motionphysics: {where}error: {errors[k]}", file=sys.stderr)
            continue
        for w in est.warnings:
            print(f"motionphysics: {where}warning: {w}", file=sys.stderr)
        for n in est.notes:
            print(f"motionphysics: {where}note: {n}", file=sys.stderr)
    try:
        if args.from_file:
            for est, err in zip(estimates, errors, strict=True):
                if err:
                    record = {"prompt": est.prompt, "error": err, "understood": est.understood}
                    print(json.dumps(record))
                else:
                    print(json.dumps(est.to_dict()))
        elif args.json:
            print(json.dumps(estimates[0].to_dict(), indent=2))
        else:
            print(_table(estimates[0]))
        sys.stdout.flush()
    except BrokenPipeError:
        # `motionphysics init ... | head`: the reader left; not an error of ours.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0
