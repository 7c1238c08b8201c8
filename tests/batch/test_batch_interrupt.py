"""Stopping a batch: SIGTERM (or Ctrl-C) stops the jobs in flight cleanly (exit 130,
their directories partial, the table rebuilt), and a batch killed outright leaves no
job process running on (the job dies with it), so the next batch owns the folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from conftest import TINY, batch_cmd, batch_env, job_records, read_table, run_batch_cli

pytestmark = pytest.mark.slow


def _start(tmp_path: Path, *flags: str) -> tuple[subprocess.Popen, Path, Path]:
    sweep = tmp_path / "sweep.yaml"
    # 150 frames: long enough (seconds) that the jobs are still simulating or rendering
    # when the test stops the batch, after they were seen in those stages.
    sweep.write_text(f"base: {TINY}\naxes: {{optimize.seed: [0, 1], sim.frames: [150]}}\n")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        batch_cmd(sweep, out, "--workers", "1", *flags),
        env=batch_env(),
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    return proc, sweep, out


def _wait_for_run(out: Path, proc: subprocess.Popen, timeout: float = 300) -> str:
    """Wait until the first job's run is simulating (it is mid-run)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for k, r in job_records(out).items():
            params = out / "jobs" / k / "params.json"
            if r.get("status") == "running" and params.is_file():
                try:
                    stage = json.loads(params.read_text()).get("stage")
                except ValueError:
                    continue
                if stage == "simulate":
                    return k
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("no job started")


def _job_processes(out: Path) -> list[int]:
    """Pids of live processes whose command line names the sweep folder."""
    pids = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            cmd = (p / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            state = (p / "stat").read_text().split()[2]
        except OSError:
            continue
        if str(out) in cmd and "motionphysics.batch.child" in cmd and state != "Z":
            pids.append(int(p.name))
    return pids


def test_sigterm_stops_jobs_cleanly_and_the_next_batch_resumes(tmp_path):
    proc, sweep, out = _start(tmp_path)
    job = _wait_for_run(out, proc)
    proc.send_signal(signal.SIGTERM)  # the batch only, not its group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1].startswith("motionphysics: batch interrupted")
    rec = job_records(out)[job]
    assert rec["status"] == "interrupted" and rec["exit_code"] == 130
    rows = {r["job"]: r for r in read_table(out)}
    assert rows[job]["status"] == "interrupted"
    assert sum(r["status"] == "pending" for r in rows.values()) == 1  # never started
    assert not _job_processes(out)
    res = run_batch_cli(sweep, out, "--workers", "2", "--verbose")
    assert res.returncode == 0, res.stderr
    assert f"{job}: resume (interrupted)" in res.stderr
    assert all(r["status"] == "complete" for r in read_table(out))


@pytest.mark.skipif(not os.path.exists("/proc/self/cmdline"), reason="needs Linux /proc")
def test_batch_killed_alone_takes_its_job_with_it(tmp_path):
    proc, _, out = _start(tmp_path, "--quiet")
    _wait_for_run(out, proc)
    assert _job_processes(out), "the job process should be running"
    os.kill(proc.pid, signal.SIGKILL)  # the batch process only: its jobs are not signalled
    proc.communicate()
    deadline = time.monotonic() + 10
    while _job_processes(out) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _job_processes(out), "an orphaned job kept running after its batch died"
