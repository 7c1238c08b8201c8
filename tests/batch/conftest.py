"""Helpers of the batch tests: tiny sweeps run through the real command line."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import motionphysics

DATA = Path(__file__).parent / "data"
TINY = DATA / "tiny.yaml"
SRC = Path(motionphysics.__file__).resolve().parent.parent


def batch_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def batch_cmd(sweep: Path, out: Path, *flags: str) -> list[str]:
    return [sys.executable, "-m", "motionphysics", "batch", str(sweep), "--out", str(out), *flags]


def run_batch_cli(
    sweep: Path, out: Path, *flags: str, timeout: float = 600
) -> subprocess.CompletedProcess:
    return subprocess.run(
        batch_cmd(sweep, out, *flags),
        env=batch_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def read_table(out: Path) -> list[dict[str, str]]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def job_records(out: Path) -> dict[str, dict]:
    recs = {}
    for p in sorted((out / "jobs").glob("*/job.json")):
        try:
            recs[p.parent.name] = json.loads(p.read_text())
        except ValueError:  # being replaced right now: os.replace makes that rare, not impossible
            pass
    return recs


def snapshot(job_dir: Path) -> dict[str, tuple[int, int]]:
    """Every file under a job directory -> (mtime_ns, size)."""
    return {
        str(p.relative_to(job_dir)): (p.stat().st_mtime_ns, p.stat().st_size)
        for p in sorted(job_dir.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def tiny_base() -> Path:
    return TINY
