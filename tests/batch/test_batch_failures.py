"""Failing jobs: a bad scene is marked failed with its message and the others complete;
``--retries`` retries internal failures (exit status 1) only; the table is tolerant of
keys added to params.json / metrics.json."""

from __future__ import annotations

import json
import stat
from pathlib import Path

from conftest import TINY, read_table, run_batch_cli
from motionphysics.batch import load_sweep, write_results
from motionphysics.batch.jobs import JobSpec, execute_job, read_job_state


def test_failing_job_is_reported_and_the_others_complete(tmp_path):
    (tmp_path / "broken.ply").write_text("this is not a ply file\n")
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(f"base: {TINY}\naxes:\n  scene.source: [builtin:sphere, broken.ply]\n")
    out = tmp_path / "out"
    res = run_batch_cli(sweep, out, "--workers", "2", "--retries", "2")
    assert res.returncode == 1, res.stderr  # some job failed
    rows = {Path(r["scene.source"]).name: r for r in read_table(out)}
    good, bad = rows["builtin:sphere"], rows["broken.ply"]
    assert good["status"] == "complete" and (out / good["video"]).is_file()
    assert bad["status"] == "failed" and bad["exit_code"] == "2" and bad["video"] == ""
    assert "broken.ply" in bad["message"] and bad["message"].startswith("motionphysics: error:")
    assert bad["attempts"] == "1"  # bad input is never retried
    failed_lines = [ln for ln in res.stderr.splitlines() if "failed" in ln]
    assert len(failed_lines) == 1 and bad["job"] in failed_lines[0]
    assert "1 failed" in res.stdout
    # Run again: the complete job is skipped, the failed one is tried again (and fails).
    res2 = run_batch_cli(sweep, out, "--workers", "2", "--verbose")
    assert res2.returncode == 1
    assert f"{bad['job']}: rerun (failed before)" in res2.stderr
    assert good["job"] not in res2.stderr


def _fake_python(tmp_path: Path, body: str) -> str:
    """An interpreter stand-in for the job process: counts its starts, then ``body``."""
    script = tmp_path / "fakepython"
    script.write_text(
        "#!/bin/sh\n"
        f'echo start >> "{tmp_path}/starts"\n'
        "echo 'Warp CUDA warning: noise on stderr first' >&2\n" + body
    )
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return str(script)


def _spec(tmp_path: Path, python: str, retries: int) -> JobSpec:
    return JobSpec(
        id="j",
        dir=str(tmp_path / "job"),
        values={"optimize.seed": 0},
        config_text="{}\n",
        config_hash="abc",
        mode="force",
        retries=retries,
        python=python,
    )


def test_internal_failure_is_retried_then_reported(tmp_path):
    py = _fake_python(tmp_path, "echo 'RuntimeError: out of luck' >&2\nexit 1\n")
    o = execute_job(_spec(tmp_path, py, retries=2))
    assert (o.status, o.exit_code, o.attempts) == ("failed", 1, 3)
    assert o.message == "RuntimeError: out of luck"
    assert (tmp_path / "starts").read_text().count("start") == 3
    rec = json.loads((tmp_path / "job" / "job.json").read_text())
    assert rec["status"] == "failed" and rec["attempts"] == 3 and rec["config_hash"] == "abc"
    assert (tmp_path / "job" / "job.log").read_text().count("=== attempt") == 3


def test_bad_input_is_not_retried(tmp_path):
    py = _fake_python(tmp_path, "echo 'motionphysics: error: x.ply: not found' >&2\nexit 2\n")
    o = execute_job(_spec(tmp_path, py, retries=3))
    assert (o.status, o.exit_code, o.attempts) == ("failed", 2, 1)
    assert o.message == "motionphysics: error: x.ply: not found"


def test_exit_0_without_a_complete_run_is_a_failure(tmp_path):
    o = execute_job(_spec(tmp_path, _fake_python(tmp_path, "exit 0\n"), retries=0))
    assert o.status == "failed" and "params.json" in o.message


def test_interrupted_job_is_not_retried(tmp_path):
    py = _fake_python(tmp_path, "echo 'motionphysics: interrupted' >&2\nexit 130\n")
    o = execute_job(_spec(tmp_path, py, retries=2))
    assert (o.status, o.attempts) == ("interrupted", 1)
    assert read_job_state(tmp_path / "job").status_for("abc") == "interrupted"


def test_table_is_tolerant_of_added_keys(tmp_path):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"base: {TINY}\naxes: {{optimize.seed: [0, 1, 2]}}\n")
    sw = load_sweep(sweep, tmp_path / "out")
    a, b, c = sw.jobs
    for job, params, metrics in (
        (
            a,
            {"class": "elastic", "density": 1100.0, "params": {"E": 2e7, "nu": 0.3}},
            {"max_speed": 1.5, "clip": {"sim": 0.3, "frames": [0.1, 0.2]}, "new_flag": True},
        ),
        (
            b,
            {"class": "elastic", "density": 1100.0, "params": {"E": 2e7}, "later_key": {"x": 1}},
            {"max_speed": 2.5, "later_metric": 7},
        ),
    ):
        d = sw.job_dir(job)
        d.mkdir(parents=True)
        (d / "job.json").write_text(
            json.dumps({"config_hash": job.config_hash, "status": "complete", "wall_time_s": 3.0})
        )
        (d / "params.json").write_text(
            json.dumps({**params, "status": "complete", "partial": False})
        )
        (d / "metrics.json").write_text(
            json.dumps({"schema": "motionphysics.metrics/1", **metrics})
        )
    d = sw.job_dir(c)  # a directory of another sweep (different config): not this job's
    d.mkdir(parents=True)
    (d / "job.json").write_text(json.dumps({"config_hash": "other", "status": "complete"}))
    (d / "params.json").write_text(
        json.dumps({"status": "complete", "partial": False, "params": {"E": 1.0}})
    )
    rows = write_results(sw)
    table = read_table(sw.out)
    assert [r["status"] for r in table] == ["complete", "complete", "pending"]
    assert table[0]["metric.clip.sim"] == "0.3" and table[0]["metric.new_flag"] == "true"
    assert table[1]["metric.later_metric"] == "7" and table[1]["param.nu"] == ""
    assert "metric.clip.frames" not in table[0] and "metric.schema" not in table[0]
    assert table[2]["param.E"] == "" and table[2]["class"] == ""
    assert rows[0]["optimize.seed"] == 0
