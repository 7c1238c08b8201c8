"""Where batch jobs run: a local pool of job processes, or tasks on a Ray cluster.

An executor takes :class:`~motionphysics.batch.jobs.JobSpec` s and calls back as jobs
start and end; every job is :func:`~motionphysics.batch.jobs.execute_job`, which writes
its own results into its job directory, so the two executors differ only in where that
call happens:

- :class:`LocalExecutor`: N job processes at a time on this machine (N threads each
  wait on one ``motionphysics run`` process; the work is in the processes).
- :class:`RayExecutor`: ``ray.init(address=...)`` to an existing cluster, or a local
  instance when no address is given; one task per job with ``num_cpus`` = the job's
  threads and ``num_gpus`` = 1 for a ``device: cuda`` job. The output folder must be
  shared by the nodes. Ray is optional (``motionphysics[ray]``) and imported here only
  when this executor runs.

On Ctrl-C (or SIGTERM, which the runner turns into the same) jobs in flight get SIGINT
(their runs mark themselves partial), queued jobs never start, and
:class:`KeyboardInterrupt` propagates once the in-flight jobs have ended.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

from motionphysics.batch.jobs import JobOutcome, JobSpec, ProcessRegistry, execute_job
from motionphysics.errors import UserInputError

__all__ = ["EXECUTORS", "LocalExecutor", "RayExecutor", "make_executor"]

EXECUTORS = ("local", "ray")

OnStart = Callable[[str], None]
OnDone = Callable[[JobOutcome], None]


class LocalExecutor:
    """``workers`` jobs at a time on this machine."""

    name = "local"

    def __init__(self, workers: int):
        self.workers = int(workers)

    def run(self, specs: Sequence[JobSpec], on_start: OnStart, on_done: OnDone) -> None:
        registry = ProcessRegistry()
        pool = ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="batch-job")
        pending = set()
        try:
            for spec in specs:
                pending.add(pool.submit(self._one, spec, registry, on_start))
            while pending:
                done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for fut in done:
                    on_done(fut.result())
        except KeyboardInterrupt:
            for fut in pending:
                fut.cancel()  # queued jobs never start
            registry.interrupt_all()
            for fut in pending:
                if not fut.cancelled():
                    try:
                        on_done(fut.result())
                    except Exception:  # the interrupt matters more than one late result
                        pass
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    @staticmethod
    def _one(spec: JobSpec, registry: ProcessRegistry, on_start: OnStart) -> JobOutcome:
        if registry.stopping.is_set():
            return JobOutcome(spec.id, "interrupted", None, "not started: batch interrupted")
        return execute_job(spec, registry=registry, on_start=on_start)


def _ray_execute(spec: JobSpec) -> JobOutcome:
    """The Ray task: one job, run by the worker that holds the task's resources."""
    return execute_job(spec)


class RayExecutor:
    """One Ray task per job; ``workers`` (optional) caps the tasks in flight."""

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None):
        self.address = address
        self.workers = workers

    def _init(self):
        try:
            import ray
        except ImportError:
            raise UserInputError(
                "--executor ray: the ray package is not installed "
                "(pip install 'motionphysics[ray]')"
            ) from None
        import logging

        if ray.is_initialized():
            return ray, False
        kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        try:
            if self.address:
                ray.init(address=self.address, **kwargs)
            else:
                ray.init(**kwargs)
        except Exception as err:  # ConnectionError, RuntimeError, grpc errors ...
            where = f"--address {self.address}" if self.address else "--executor ray"
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise UserInputError(
                f"{where}: cannot start or reach a Ray cluster ({first})"
            ) from None
        return ray, True

    def run(self, specs: Sequence[JobSpec], on_start: OnStart, on_done: OnDone) -> None:
        if not specs:
            return
        ray, started = self._init()
        try:
            gpus = float(ray.cluster_resources().get("GPU", 0))
            needs = [s for s in specs if s.gpus > 0]
            if needs and gpus < 1:
                raise UserInputError(
                    f"job {needs[0].id}: device: cuda needs a GPU, but the Ray cluster has none"
                )
            task = ray.remote(_ray_execute)
            queue = list(specs)
            refs: dict = {}
            cap = self.workers or len(queue)
            try:
                while queue or refs:
                    while queue and len(refs) < cap:
                        spec = queue.pop(0)
                        ref = task.options(
                            num_cpus=spec.threads,
                            num_gpus=spec.gpus,
                            max_retries=0,  # retries are the job's own (internal failures only)
                            name=f"motionphysics-job-{spec.id}",
                        ).remote(spec)
                        refs[ref] = spec
                        on_start(spec.id)
                    done, _ = ray.wait(list(refs), num_returns=1, timeout=0.5)
                    for ref in done:
                        spec = refs.pop(ref)
                        on_done(self._result(ray, ref, spec))
            except KeyboardInterrupt:
                for ref in refs:
                    ray.cancel(ref, force=True)  # the job process dies with its worker
                raise
        finally:
            if started:
                ray.shutdown()

    @staticmethod
    def _result(ray, ref, spec: JobSpec) -> JobOutcome:
        try:
            return ray.get(ref)
        except Exception as err:  # the task itself died (worker lost, node down)
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            return JobOutcome(spec.id, "failed", None, f"ray task failed: {first}")


def default_workers() -> int:
    """Local jobs at a time by default: half the cores (each job gets two threads)."""
    return max(1, (os.cpu_count() or 1) // 2)


def make_executor(name: str, workers: int | None, address: str | None):
    if name == "local":
        if address:
            raise UserInputError("--address: only with --executor ray")
        return LocalExecutor(workers or default_workers())
    if name == "ray":
        return RayExecutor(address=address, workers=workers)
    raise UserInputError(f"--executor: expected one of {', '.join(EXECUTORS)}, got {name!r}")
