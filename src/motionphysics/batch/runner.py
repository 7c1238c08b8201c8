"""Running a sweep: plan against what the job directories hold, execute, keep the table.

For every job of a (validated) :class:`~motionphysics.batch.sweep.Sweep` the plan reads
its directory ``OUT/jobs/<id>/``:

========================================  ==========  ===========================
directory says                            action      the run is opened with
========================================  ==========  ===========================
nothing (new job)                         run         ``--force``
another config (``config_hash`` differs)  rerun       ``--force``
this config, failed                       rerun       ``--force``
this config, interrupted / killed         resume      ``--resume``
this config, complete                     skip        (its files are not touched)
========================================  ==========  ===========================

So running the same sweep again continues where it stopped, and a job whose config
changed never keeps results of the old one. One batch at a time may work on a folder
(an advisory lock on ``OUT/.batch.lock``, released by the kernel if the batch dies).
``OUT/sweep.json`` records the sweep's jobs; ``OUT/results.csv|html`` are rebuilt from
the job directories as jobs end and when the batch stops for any reason.

This module orchestrates; it knows nothing about simulation (the jobs are ``motionphysics
run`` processes) and imports neither torch nor warp.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from motionphysics.batch.jobs import JobOutcome, JobSpec, read_job_state
from motionphysics.batch.results import write_results
from motionphysics.batch.sweep import Job, Sweep
from motionphysics.errors import RunInterrupted, UserInputError
from motionphysics.progress import Progress

__all__ = ["BatchReport", "Planned", "plan_jobs", "run_batch"]

SWEEP_RECORD = "sweep.json"
LOCK_FILE = ".batch.lock"

Action = Literal["skip", "run", "rerun", "resume"]


@dataclass(frozen=True)
class Planned:
    job: Job
    dir: Path
    action: Action
    reason: str

    @property
    def mode(self) -> Literal["force", "resume"]:
        return "resume" if self.action == "resume" else "force"


def plan_jobs(sweep: Sweep) -> list[Planned]:
    """What each job needs, from its directory (reads only)."""
    out = []
    for job in sweep.jobs:
        d = sweep.job_dir(job)
        st = read_job_state(d)
        status = st.status_for(job.config_hash)
        if status == "complete":
            out.append(Planned(job, d, "skip", "complete"))
        elif status == "failed":
            out.append(Planned(job, d, "rerun", "failed before"))
        elif status == "interrupted":
            out.append(Planned(job, d, "resume", "interrupted"))
        elif st.record is not None:
            out.append(Planned(job, d, "rerun", "config changed"))
        else:
            out.append(Planned(job, d, "run", "new"))
    return out


@dataclass
class BatchReport:
    """What a batch did (the table holds the per-job detail)."""

    total: int
    skipped: int
    outcomes: list[JobOutcome] = field(default_factory=list)
    interrupted: bool = False

    def count(self, status: str) -> int:
        return sum(1 for o in self.outcomes if o.status == status)

    @property
    def complete(self) -> int:
        return self.skipped + self.count("complete")

    @property
    def failed(self) -> list[JobOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]


@contextmanager
def _folder_lock(out: Path) -> Iterator[None]:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserInputError(f"{out}: cannot create the sweep folder ({err.strerror})") from None
    if not os.access(out, os.W_OK):
        raise UserInputError(f"{out}: the sweep folder is not writable")
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock, one batch per folder is then the user's care
        yield
        return
    path = out / LOCK_FILE
    f = open(path, "a+")  # noqa: SIM115 - held for the whole batch, closed below
    try:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "?"
            raise UserInputError(
                f"{out}: another motionphysics batch is running on this folder (pid {holder}); "
                "wait for it or choose another --out"
            ) from None
        f.seek(0)
        f.truncate()
        f.write(f"{os.getpid()}\n")
        f.flush()
        yield
    finally:
        f.close()  # releases the lock


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM stops a batch the way Ctrl-C does (jobs end partial, table rebuilt)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _write_sweep_record(sweep: Sweep) -> None:
    from motionphysics.io.rundir import atomic_write, to_json_text

    record = {
        "schema": "motionphysics.sweep/1",
        "sweep": str(sweep.path.resolve()),
        "name": sweep.name,
        "base": sweep.base,
        "axes": sweep.axes,
        "zip": [list(g) for g in sweep.zip],
        "jobs": [
            {"id": j.id, "values": j.values, "config_hash": j.config_hash} for j in sweep.jobs
        ],
    }
    with atomic_write(sweep.out / SWEEP_RECORD, "wb") as f:
        f.write(to_json_text(record).encode())


def job_spec(p: Planned, threads: int, retries: int) -> JobSpec:
    return JobSpec(
        id=p.job.id,
        dir=str(p.dir.resolve()),
        values=p.job.values,
        config_text=p.job.config_text,
        config_hash=p.job.config_hash,
        mode=p.mode,
        optimised=p.job.optimised,
        threads=threads,
        gpus=1 if p.job.needs_gpu else 0,
        retries=retries,
    )


def run_batch(
    sweep: Sweep,
    executor,
    *,
    threads: int,
    retries: int = 0,
    progress: Progress | None = None,
    table_every_s: float = 1.0,
) -> BatchReport:
    """Run the jobs of ``sweep`` that are not complete; rebuild the table as they end.

    Raises :class:`~motionphysics.errors.RunInterrupted` on Ctrl-C / SIGTERM once the
    jobs in flight have stopped (their directories say interrupted; the table is
    written). A failing job is an outcome, not an exception.
    """
    progress = progress or Progress(quiet=True)
    with _folder_lock(sweep.out), _sigterm_as_interrupt():
        _write_sweep_record(sweep)
        plan = plan_jobs(sweep)
        todo = [p for p in plan if p.action != "skip"]
        report = BatchReport(total=len(plan), skipped=len(plan) - len(todo))
        for p in plan:
            if p.action != "skip":
                progress.log(f"{p.job.id}: {p.action} ({p.reason})")
        write_results(sweep)

        running: set[str] = set()
        lock = threading.Lock()
        last_table = [float("-inf")]  # the first job to end writes the table

        def on_start(job_id: str) -> None:  # called from worker threads
            with lock:
                running.add(job_id)

        def table() -> None:
            if time.monotonic() - last_table[0] >= table_every_s:
                with lock:
                    now_running = set(running)
                write_results(sweep, now_running)
                last_table[0] = time.monotonic()

        try:
            with progress.stage("jobs", total=len(todo)) as st:

                def on_done(outcome: JobOutcome) -> None:
                    with lock:
                        running.discard(outcome.id)
                    report.outcomes.append(outcome)
                    st.advance()
                    nfail = len(report.failed)
                    st.note(
                        f"jobs ({len(report.outcomes)}/{len(todo)}"
                        + (f", {nfail} failed" if nfail else "")
                        + ")"
                    )
                    tail = f": {outcome.message}" if outcome.message else ""
                    progress.log(
                        f"{outcome.id}: {outcome.status} in {outcome.wall_time_s:.1f} s{tail}"
                    )
                    table()

                specs = [job_spec(p, threads, retries) for p in todo]
                executor.run(specs, on_start, on_done)
        except KeyboardInterrupt:
            report.interrupted = True
            with lock:
                running.clear()
            write_results(sweep)
            raise RunInterrupted(
                f"batch interrupted: {report.complete} of {report.total} jobs complete; "
                f"run the same command again to continue ({sweep.out})"
            ) from None
        with lock:
            running.clear()
        write_results(sweep)
        return report
