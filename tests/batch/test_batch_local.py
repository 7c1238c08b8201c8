"""A sweep of 4 tiny jobs through ``motionphysics batch`` on the local pool: it completes;
killed (SIGKILL to its process group) after the first jobs finish and started again it
finishes the rest without touching the finished ones; a changed axis value re-runs only
the jobs it changes; the same sweep on a local Ray instance gives the same table.

The jobs are real ``motionphysics run`` processes on a 300-particle ball (a few seconds
each, mostly process start-up), so the module shares one sweep folder between tests,
in the order they are written.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from conftest import TINY, batch_cmd, batch_env, job_records, read_table, run_batch_cli, snapshot

SWEEP = f"""\
base: {TINY}
axes:
  material.E: [2.0e+7, 8.0e+7]
  optimize.seed: [0, 1]
"""


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """Run the sweep with one worker, SIGKILL the whole batch once a job is complete,
    then run it again; returns what the tests below check."""
    root = tmp_path_factory.mktemp("batch")
    sweep = root / "sweep.yaml"
    sweep.write_text(SWEEP)
    out = root / "out"
    proc = subprocess.Popen(
        batch_cmd(sweep, out, "--workers", "1", "--quiet"),
        env=batch_env(),
        start_new_session=True,  # its own process group: killpg reaches the jobs too
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 300
    done: list[str] = []
    try:
        while time.monotonic() < deadline:
            done = [k for k, r in job_records(out).items() if r.get("status") == "complete"]
            if done:
                break
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.1)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        proc.stderr.close()
    assert done, "no job completed within 300 s"
    killed = job_records(out)
    before = {k: snapshot(out / "jobs" / k) for k in done}
    table_at_kill = read_table(out)
    second = run_batch_cli(sweep, out, "--workers", "2", "--verbose")
    return {
        "root": root,
        "sweep": sweep,
        "out": out,
        "done_at_kill": done,
        "records_at_kill": killed,
        "table_at_kill": table_at_kill,
        "before": before,
        "second": second,
        "table": read_table(out),
    }


def test_killed_batch_left_consistent_state(resumed):
    done = resumed["done_at_kill"]
    assert 1 <= len(done) < 4
    rows = {r["job"]: r for r in resumed["table_at_kill"]}
    assert len(rows) == 4
    # The table is rebuilt after each job; a kill between a job's own status file and
    # that rebuild leaves the table one job behind (the next batch rebuilds it).
    lagging = [k for k in done if rows[k]["status"] != "complete"]
    assert len(lagging) <= 1, lagging
    # The job in flight was killed with the batch: its directory says so.
    in_flight = [k for k, r in resumed["records_at_kill"].items() if r["status"] == "running"]
    assert len(in_flight) <= 1


def test_restart_finishes_the_rest_without_touching_finished_jobs(resumed):
    second, out = resumed["second"], resumed["out"]
    assert second.returncode == 0, second.stderr
    assert "4 jobs, 4 complete" in second.stdout
    for job, snap in resumed["before"].items():
        assert snapshot(out / "jobs" / job) == snap, f"{job} was touched"
        assert f"{job}: skip" not in second.stderr  # skipped jobs are not even planned
    planned = [ln for ln in second.stderr.splitlines() if ": run (new)" in ln or ": resume" in ln]
    assert len(planned) == 4 - len(resumed["done_at_kill"])
    for k, r in resumed["records_at_kill"].items():
        if r["status"] == "running":  # the interrupted job ran again in the same folder
            assert f"{k}: resume (interrupted)" in second.stderr
            assert (out / "jobs" / k / "job.log").read_text().count("=== attempt 1") == 2


def test_table_has_one_complete_row_per_job(resumed):
    rows = resumed["table"]
    assert len(rows) == 4
    assert {(float(r["material.E"]), int(r["optimize.seed"])) for r in rows} == {
        (e, s) for e in (2e7, 8e7) for s in (0, 1)
    }
    out = resumed["out"]
    for r in rows:
        assert r["status"] == "complete" and r["class"] == "elastic"
        assert float(r["param.E"]) == float(r["material.E"])  # the job ran its own value
        assert float(r["wall_time_s"]) > 0 and r["message"] == ""
        assert (out / r["video"]).is_file() and r["video"] == f"{r['dir']}/video.mp4"
        params = json.loads((out / r["dir"] / "params.json").read_text())
        metrics = json.loads((out / r["dir"] / "metrics.json").read_text())
        assert float(r["metric.max_speed"]) == metrics["max_speed"]
        assert params["partial"] is False
        run_yaml = (out / r["dir"] / "run.yaml").read_text()
        assert "grid: 8" in run_yaml  # an ordinary run directory of the tiny base
    # A stiffer ball deforms less: the two E values gave different simulations.
    by_e = {float(r["material.E"]): float(r["metric.volume_ratio.max_abs_deviation"]) for r in rows}
    assert by_e[8e7] < by_e[2e7]
    html = (out / "results.html").read_text()
    assert html.count("<tr>") == 5 and "video.mp4" in html


def test_eval_works_on_a_job_directory(resumed):
    from motionphysics.cli import main

    job = resumed["out"] / resumed["table"][0]["dir"]
    assert main(["eval", str(job), "--quiet"]) == 0


@pytest.mark.slow
def test_same_sweep_on_local_ray_gives_the_same_table(resumed):
    out = resumed["root"] / "ray"
    res = run_batch_cli(
        resumed["sweep"], out, "--executor", "ray", "--workers", "2", "--threads", "1", "--quiet"
    )
    assert res.returncode == 0, res.stderr
    ray_rows = read_table(out)
    local_rows = resumed["table"]
    varying = {"wall_time_s"}  # timings differ from run to run; nothing else may
    assert [r["job"] for r in ray_rows] == [r["job"] for r in local_rows]
    for a, b in zip(ray_rows, local_rows, strict=True):
        assert {k: v for k, v in a.items() if k not in varying} == {
            k: v for k, v in b.items() if k not in varying
        }


def test_changed_axis_value_reruns_only_the_affected_jobs(resumed):
    # Last in this module: it changes the shared folder.
    out, sweep = resumed["out"], resumed["sweep"]
    kept = {r["job"] for r in resumed["table"] if float(r["material.E"]) == 2e7}
    before = {k: snapshot(out / "jobs" / k) for k in kept}
    sweep.write_text(SWEEP.replace("8.0e+7", "4.0e+7"))
    res = run_batch_cli(sweep, out, "--workers", "2", "--verbose")
    assert res.returncode == 0, res.stderr
    assert "2 already, 2 run now" in res.stdout
    for k in kept:
        assert snapshot(out / "jobs" / k) == before[k]
    rows = read_table(out)
    assert sorted(float(r["material.E"]) for r in rows) == [2e7, 2e7, 4e7, 4e7]
    assert all(r["status"] == "complete" for r in rows)
    assert all(float(r["param.E"]) == float(r["material.E"]) for r in rows)
    # The old 8e7 jobs' folders stay on disk but are not part of the new table.
    assert len(list((out / "jobs").iterdir())) == 6
