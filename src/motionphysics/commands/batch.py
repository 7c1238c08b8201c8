"""motionphysics batch SWEEP.yaml: a sweep of runs (axes over config keys) on a local pool or Ray.

Every job is an ordinary run directory under ``OUT/jobs/<job-id>/``; ``OUT/results.csv``
and ``OUT/results.html`` hold one row per job. Running the same sweep again skips
complete jobs, resumes interrupted ones and re-runs jobs whose config changed. Exit
status: 0 when every job is complete, 1 when some job failed or was stopped (each
is listed on stderr and in the table), 2 for a bad sweep file or option (before anything runs),
130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys


def _positive(flag: str, value: int | None, minimum: int = 1) -> None:
    from motionphysics.errors import UserInputError

    if value is not None and value < minimum:
        raise UserInputError(f"{flag}: expected an integer >= {minimum}, got {value}")


def _print_plan(sweep, plan, stream) -> None:
    print(f"sweep {sweep.name} ({sweep.path}): {len(plan)} jobs -> {sweep.out}", file=stream)
    width = max((len(p.job.id) for p in plan), default=0)
    for p in plan:
        values = " ".join(
            f"{k}={json.dumps(v, ensure_ascii=False)}" for k, v in p.job.values.items()
        )
        print(f"  {p.action:<6}  {p.job.id:<{width}}  {p.dir}  {values}", file=stream)


def _main(args) -> int:
    from motionphysics.batch import load_sweep, make_executor, plan_jobs, run_batch
    from motionphysics.progress import Progress

    quiet = getattr(args, "quiet", False)
    verbose = getattr(args, "verbose", False)
    _positive("--workers", args.workers)
    _positive("--threads", args.threads)
    _positive("--retries", args.retries, 0)
    executor = make_executor(args.executor, args.workers, args.address)
    sweep = load_sweep(args.sweep, args.out)  # validates every job before anything runs

    if args.dry_run:
        _print_plan(sweep, plan_jobs(sweep), sys.stdout)
        return 0

    if args.threads is not None:
        threads = args.threads
    elif args.executor == "local":
        threads = max(1, (os.cpu_count() or 1) // executor.workers)
    else:
        threads = 1
    with Progress(quiet=quiet, verbose=verbose) as prog:
        report = run_batch(sweep, executor, threads=threads, retries=args.retries, progress=prog)

    for o in report.outcomes:
        if o.status == "complete":
            continue
        code = f"exit {o.exit_code}" if o.exit_code is not None else "no exit status"
        print(f"motionphysics: batch: job {o.id} {o.status} ({code}): {o.message}", file=sys.stderr)
    if not quiet:
        ran = len(report.outcomes)
        print(
            f"sweep {sweep.name}: {report.total} jobs, {report.complete} complete "
            f"({report.skipped} already, {ran - len(report.failed)} run now), "
            f"{len(report.failed)} failed"
        )
        print(f"results:   {sweep.out / 'results.csv'}  {sweep.out / 'results.html'}")
    return 0 if report.complete == report.total else 1


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "batch",
        help="a sweep of runs over config axes, on a local pool or a Ray cluster",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("sweep", metavar="SWEEP.yaml", help="sweep file: base, axes, zip, out")
    p.add_argument(
        "--out", metavar="DIR", help="sweep folder (default: the file's out:, or runs/<name>)"
    )
    p.add_argument(
        "--executor",
        choices=["local", "ray"],
        default="local",
        help="where jobs run (default: local)",
    )
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="jobs at a time (local default: half the cores; ray: as many as the cluster fits)",
    )
    p.add_argument(
        "--threads",
        type=int,
        metavar="T",
        help="threads per job (its CPU request on Ray; local default: cores / workers; ray: 1)",
    )
    p.add_argument(
        "--address", metavar="ADDR", help="Ray cluster address (default: a local Ray instance)"
    )
    p.add_argument(
        "--retries",
        type=int,
        default=0,
        metavar="K",
        help="retry a job up to K times after an internal failure (exit 1); bad input is never retried",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="list the jobs, their folders and actions"
    )
    # --quiet / --verbose after the subcommand too (they default to the global ones).
    p.add_argument(
        "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress, no summary"
    )
    p.add_argument(
        "--verbose",
        action="store_true",
        default=argparse.SUPPRESS,
        help="one line per job on stderr",
    )
    p.set_defaults(func=_main)
