"""Sweeps of run configs (scenes x prompts x priors x seeds ...) as batches of runs.

``motionphysics batch SWEEP.yaml`` expands a sweep file into jobs
(:mod:`~motionphysics.batch.sweep`), runs each as an ordinary ``motionphysics run``
process whose run directory is ``OUT/jobs/<job-id>/`` (:mod:`~motionphysics.batch.jobs`),
on a local pool or a Ray cluster (:mod:`~motionphysics.batch.executors`), resumably
(:mod:`~motionphysics.batch.runner`), and keeps ``OUT/results.csv`` / ``results.html``
rebuilt from the job directories (:mod:`~motionphysics.batch.results`).

Nothing in this package imports torch, warp or ray at import time.
"""

from motionphysics.batch.executors import EXECUTORS, LocalExecutor, RayExecutor, make_executor
from motionphysics.batch.jobs import JobOutcome, JobSpec, execute_job, read_job_state
from motionphysics.batch.results import build_table, write_results
from motionphysics.batch.runner import BatchReport, Planned, plan_jobs, run_batch
from motionphysics.batch.sweep import Job, Sweep, job_id, load_sweep

__all__ = [
    "EXECUTORS",
    "BatchReport",
    "Job",
    "JobOutcome",
    "JobSpec",
    "LocalExecutor",
    "Planned",
    "RayExecutor",
    "Sweep",
    "build_table",
    "execute_job",
    "job_id",
    "load_sweep",
    "make_executor",
    "plan_jobs",
    "read_job_state",
    "run_batch",
    "write_results",
]
