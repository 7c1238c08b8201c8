"""One batch job on disk and its execution as a ``motionphysics run`` process.

A job directory ``OUT/jobs/<id>/`` is an ordinary run directory (what ``motionphysics
run`` writes, so ``eval``, ``view`` and ``compare`` work on it) plus three files of the
batch's own::

    job.yaml   the fully resolved config the job runs (the run's input)
    job.json   the job's status, written atomically: id, axis values, config_hash,
               status (running | complete | failed | interrupted), exit_code, message
               (the last line the run printed on stderr), attempts, wall_time_s
    job.log    everything the run printed on stderr, one block per attempt

Whether a job finished is decided by the run itself (``params.json``: ``status:
complete``, ``partial: false``) together with ``job.json``'s ``config_hash``: a job
killed after its run finished but before ``job.json`` said so still counts as
complete, and a directory whose hash differs holds another sweep's results.

:func:`execute_job` is what a worker (a local thread, a Ray task) calls; it runs
``python -m motionphysics.batch.child PARENT_PID run job.yaml --out DIR --quiet
(--force | --resume)`` -- the ``run`` command itself, in a process that dies with its
parent -- with its thread count capped through the environment, retries internal
failures (exit status 1) only, and writes ``job.json``. It imports neither torch nor
warp: the job's process does.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

__all__ = [
    "JOB_CONFIG",
    "JOB_LOG",
    "JOB_STATUS",
    "JobOutcome",
    "JobSpec",
    "JobState",
    "execute_job",
    "read_job_state",
    "thread_env",
]

JOB_CONFIG = "job.yaml"
JOB_STATUS = "job.json"
JOB_LOG = "job.log"
JOB_SCHEMA = "motionphysics.batch-job/1"

EXIT_USER = 2
EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130

_THREAD_VARS = (
    "MOTIONPHYSICS_THREADS",  # read by motionphysics.runtime.set_threads (torch)
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def thread_env(threads: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment of a job process: every thread pool capped at ``threads``.

    ``PYTHONPATH`` starts with the folder this ``motionphysics`` package was imported
    from, so a job runs the same code as the batch that started it.
    """
    import motionphysics

    env = dict(os.environ if base is None else base)
    for name in _THREAD_VARS:
        env[name] = str(int(threads))
    env["TOKENIZERS_PARALLELISM"] = "false"
    src = str(Path(motionphysics.__file__).resolve().parent.parent)
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    if src not in paths:
        env["PYTHONPATH"] = os.pathsep.join([src, *paths])
    return env


@dataclass(frozen=True)
class JobSpec:
    """What a worker needs to run one job (plain data: it travels to Ray workers)."""

    id: str
    dir: str
    """The job's run directory (absolute)."""
    values: dict[str, Any]
    config_text: str
    config_hash: str
    mode: Literal["force", "resume"]
    """How the first attempt opens the run directory: ``force`` starts afresh,
    ``resume`` continues an interrupted run (its checkpoint, if it optimised)."""
    optimised: bool = False
    threads: int = 1
    """Threads the job may use (its environment caps every thread pool; its CPU request)."""
    gpus: int = 0
    """GPUs the job needs (1 for ``device: cuda``; the Ray executor requests them)."""
    retries: int = 0
    """Extra attempts after an internal failure (exit status 1)."""
    python: str | None = None
    """Interpreter for the job process (default: the worker's ``sys.executable``)."""


@dataclass
class JobOutcome:
    """How a job ended (also what ``job.json`` holds)."""

    id: str
    status: Literal["complete", "failed", "interrupted"]
    exit_code: int | None
    message: str = ""
    attempts: int = 0
    wall_time_s: float = 0.0


@dataclass
class JobState:
    """What a job directory says about a job (read back by the runner and the table)."""

    dir: Path
    record: dict[str, Any] | None
    """``job.json`` (None when missing or unreadable)."""
    params: dict[str, Any] | None
    """``params.json`` of the run (None when missing or unreadable)."""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def config_hash(self) -> str | None:
        return (self.record or {}).get("config_hash")

    @property
    def run_complete(self) -> bool:
        p = self.params or {}
        return p.get("status") == "complete" and p.get("partial") is False

    def status_for(self, expected_hash: str) -> str:
        """``pending`` | ``complete`` | ``failed`` | ``interrupted`` for the job whose
        resolved config hashes to ``expected_hash``."""
        if self.record is None or self.config_hash != expected_hash:
            return "pending"
        if self.run_complete:
            return "complete"
        if self.record.get("status") == "failed":
            return "failed"
        return "interrupted"


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def read_job_state(job_dir: str | Path) -> JobState:
    d = Path(job_dir)
    return JobState(d, _read_json(d / JOB_STATUS), _read_json(d / "params.json"))


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _write_record(job_dir: Path, record: dict[str, Any]) -> None:
    from motionphysics.io.rundir import atomic_write, to_json_text

    with atomic_write(job_dir / JOB_STATUS, "wb") as f:
        f.write(to_json_text(record).encode())


def _write_text(path: Path, text: str) -> None:
    from motionphysics.io.rundir import atomic_write

    with atomic_write(path, "wb") as f:
        f.write(text.encode())


def _last_line(path: Path, offset: int) -> str:
    """Last non-empty line the job wrote on stderr from ``offset`` on (its message)."""
    try:
        with open(path, "rb") as f:
            f.seek(offset)
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1][:500] if lines else ""


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


class ProcessRegistry:
    """The job processes a worker pool has running, so an interrupt can reach them."""

    def __init__(self):
        self._lock = threading.Lock()
        self._procs: dict[str, subprocess.Popen] = {}
        self.stopping = threading.Event()

    def add(self, job: str, proc: subprocess.Popen) -> None:
        with self._lock:
            self._procs[job] = proc

    def remove(self, job: str) -> None:
        with self._lock:
            self._procs.pop(job, None)

    def running(self) -> list[str]:
        with self._lock:
            return list(self._procs)

    def interrupt_all(self, grace_s: float = 30.0) -> None:
        """SIGINT every job (the run marks its directory partial and exits 130); after
        ``grace_s`` a job still running is killed."""
        self.stopping.set()
        with self._lock:
            procs = list(self._procs.values())
        # A Ctrl-C on the terminal reached the jobs too (one process group): give them a
        # moment to stop on their own, so a second SIGINT does not cut their cleanup short.
        settle = time.monotonic() + 1.5
        while any(p.poll() is None for p in procs) and time.monotonic() < settle:
            time.sleep(0.05)
        for p in procs:
            if p.poll() is None:
                try:
                    p.send_signal(signal.SIGINT)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace_s
        for p in procs:
            try:
                p.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()


def execute_job(
    spec: JobSpec,
    *,
    registry: ProcessRegistry | None = None,
    on_start: Callable[[str], None] | None = None,
) -> JobOutcome:
    """Run one job to its end (with retries) and record it in ``job.json``.

    Never raises for a failing job: the failure is the outcome (status ``failed``, the
    exit status and the last stderr line). ``registry`` lets the caller interrupt the
    process; once ``registry.stopping`` is set no retry starts.
    """
    job_dir = Path(spec.dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    _write_text(job_dir / JOB_CONFIG, spec.config_text)
    record: dict[str, Any] = {
        "schema": JOB_SCHEMA,
        "id": spec.id,
        "values": spec.values,
        "config_hash": spec.config_hash,
        "status": "running",
        "exit_code": None,
        "message": "",
        "attempts": 0,
        "started_at": _now(),
        "host": os.uname().nodename,
    }
    _write_record(job_dir, record)
    if on_start is not None:
        on_start(spec.id)

    python = spec.python or sys.executable
    env = thread_env(spec.threads)
    mode = spec.mode
    outcome = JobOutcome(spec.id, "failed", None)
    log_path = job_dir / JOB_LOG
    for attempt in range(1, spec.retries + 2):
        from motionphysics.io.rundir import RunDirectory

        # --resume needs a run to continue; a directory killed before the run wrote
        # anything (only job.*) is started afresh.
        if mode == "resume" and not RunDirectory.holds_run(job_dir):
            mode = "force"
        cmd = [
            python,
            "-m",
            "motionphysics.batch.child",
            str(os.getpid()),
            "run",
            str(job_dir / JOB_CONFIG),
            "--out",
            str(job_dir),
            "--quiet",
            f"--{mode}",
        ]
        with open(log_path, "ab") as log:
            log.write(f"=== attempt {attempt} ({_now()}): {' '.join(cmd[4:])}\n".encode())
            log.flush()
            offset = log.tell()
            t0 = time.perf_counter()
            proc = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=env, cwd=os.getcwd()
            )
            if registry is not None:
                registry.add(spec.id, proc)
            try:
                code = proc.wait()
            except BaseException:
                # The worker itself is being torn down: do not leave the run behind.
                proc.kill()
                proc.wait()
                raise
            finally:
                if registry is not None:
                    registry.remove(spec.id)
            wall = time.perf_counter() - t0
        message = _last_line(log_path, offset)
        outcome.attempts = attempt
        outcome.wall_time_s = wall
        outcome.exit_code = code
        stopping = registry is not None and registry.stopping.is_set()
        complete = read_job_state(job_dir).run_complete
        if code == 0 and complete:
            outcome.status, outcome.message = "complete", ""
            break
        if code == 0:
            outcome.status = "failed"
            outcome.message = "the run exited 0 but params.json does not say complete"
            break
        if code == EXIT_INTERRUPTED or (code < 0 and stopping):
            outcome.status = "interrupted"
            outcome.message = message or "interrupted"
            break
        outcome.status = "failed"
        outcome.message = message or (
            f"killed by {_signal_name(code)}" if code < 0 else f"exit status {code}"
        )
        if code != EXIT_INTERNAL or stopping or attempt > spec.retries:
            break
        # An internal failure may be transient (memory, a flaky file system): retry,
        # continuing an optimisation from its checkpoint when there is one.
        mode = "resume" if spec.optimised else "force"
    record.update(
        {
            **{k: v for k, v in asdict(outcome).items() if k != "id"},
            "finished_at": _now(),
        }
    )
    _write_record(job_dir, record)
    return outcome
