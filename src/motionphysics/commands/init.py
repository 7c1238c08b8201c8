"""``motionphysics init``: estimate a material from a prompt and print it.

    motionphysics init "PROMPT" [--image PNG] [--backend kb|llm|median|naive] [--json]
    motionphysics init --from FILE [--backend ...]      one JSON line per prompt, in order

With ``--json`` one JSON object: ``material`` (``class``, ``density`` and the class's
parameters, SI), ``backend``, ``confidence``, ``clamped``, ``raw_answer`` (llm),
``matches`` (kb). Without it a short table. Bad input (empty or over-long prompt,
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
    p.add_argument("--class", dest="cls", metavar="CLASS", help="force the class (median backend)")
    p.add_argument(
        "--median",
        choices=["arithmetic", "geometric"],
        default="arithmetic",
        help="median of log-scaled ranges (median backend; paper: arithmetic)",
    )
    p.add_argument("--base-url", help="Chat Completions base URL (env MOTIONPHYSICS_LLM_BASE_URL)")
    p.add_argument("--model", help="model name (env MOTIONPHYSICS_LLM_MODEL; default gpt-4o)")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per LLM request")
    p.add_argument("--retries", type=int, default=2, help="LLM request retries with backoff")
    p.set_defaults(func=run)


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
    from motionphysics.materials.catalog import MATERIALS, spec

    mc = MATERIALS[est.cls]
    rows = [
        f"material  {mc.label} ({est.cls})",
        f"backend   {est.backend}"
        + (f"   confidence {est.confidence:.2f}" if est.confidence is not None else ""),
    ]
    rows.append(f"  {'density':<10} {est.density:>12.4g} {'kg/m^3':<6}")
    for name in mc.names:
        unit = spec(est.cls, name).unit
        rows.append(
            f"  {name:<10} {est.values[name]:>12.4g} {'' if unit == '1' else unit:<6}"
            f"   range {spec(est.cls, name).range_text()}"
        )
    for c in est.clamped:
        rows.append(f"  clamped {c.field}: {c.original:.4g} -> {c.clamped:.4g}")
    if est.matches:
        top = ", ".join(f"{m['name']} ({m['class']})" for m in est.matches[:3])
        rows.append(f"matches   {top}")
    if est.source:
        rows.append(f"source    {est.source}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    from motionphysics.init.estimate import EstimateOptions, check_prompt, estimate_many
    from motionphysics.init.llm import LLMOptions

    if (args.prompt is None) == (args.from_file is None):
        raise UserInputError("init: give either a PROMPT or --from FILE (exactly one)")
    if args.retries < 0:
        raise UserInputError("--retries: expected a count >= 0")
    prompts = read_prompt_file(args.from_file) if args.from_file else [check_prompt(args.prompt)]
    options = EstimateOptions(
        llm=LLMOptions(
            base_url=args.base_url, model=args.model, timeout=args.timeout, max_retries=args.retries
        ),
        median=args.median,
        cls=args.cls,
        announce=not args.quiet,
    )
    estimates = estimate_many(prompts, args.image, args.backend, options)
    try:
        if args.from_file:
            for est in estimates:
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
