"""Run directory: atomic writes, refusal of foreign runs, --force/--resume, trajectories."""

from __future__ import annotations

import json

import numpy as np
import pytest

from motionphysics.errors import UserInputError
from motionphysics.io.rundir import (
    RunDirectory,
    atomic_write,
    read_trajectory,
    write_trajectory,
)


def test_atomic_write_keeps_old_content_on_error(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError), atomic_write(p, "w") as f:
        f.write("new, half written")
        raise RuntimeError("boom")
    assert p.read_text() == "old"
    assert [q.name for q in tmp_path.iterdir()] == ["a.txt"]  # no temporary left behind


def test_new_directory_and_json_roundtrip(tmp_path):
    rd = RunDirectory(tmp_path / "run" / "nested")
    rd.write_json(
        "params.json",
        {"a": np.float32(1.5), "b": np.arange(3), "c": float("nan"), "partial": False},
    )
    data = json.loads((rd.path / "params.json").read_text())
    assert data == {"a": 1.5, "b": [0, 1, 2], "c": None, "partial": False}
    assert RunDirectory.holds_run(rd.path)
    assert not RunDirectory.is_partial(rd.path)


def test_refuses_existing_run_without_flags(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.write_json("params.json", {"partial": True})
    with pytest.raises(UserInputError, match="partial run.*--resume.*--force"):
        RunDirectory(tmp_path / "r")


def test_refuses_foreign_nonempty_directory(tmp_path):
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(UserInputError, match="holds no run"):
        RunDirectory(tmp_path)
    RunDirectory(tmp_path, force=True)
    assert (tmp_path / "mine.txt").read_text() == "keep me"


def test_force_deletes_only_run_files(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.write_json("params.json", {"partial": False})
    rd.write_text("plots/loss.png", "x")
    (rd.path / "notes.txt").write_text("user file")
    rd2 = RunDirectory(tmp_path / "r", force=True)
    assert not rd2.exists("params.json") and not rd2.exists("plots")
    assert (rd2.path / "notes.txt").read_text() == "user file"


def test_resume_keeps_files(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.append_jsonl("log.jsonl", {"iteration": 0, "loss": 1.0})
    rd2 = RunDirectory(tmp_path / "r", resume=True)
    rd2.append_jsonl("log.jsonl", {"iteration": 1, "loss": float("inf")})
    assert rd2.read_jsonl("log.jsonl") == [
        {"iteration": 0, "loss": 1.0},
        {"iteration": 1, "loss": None},
    ]


def test_torn_jsonl_line_is_ignored(tmp_path):
    rd = RunDirectory(tmp_path / "r")
    rd.append_jsonl("log.jsonl", {"iteration": 0})
    with open(rd.path / "log.jsonl", "a") as f:
        f.write('{"iteration": 1, "lo')
    assert rd.read_jsonl("log.jsonl") == [{"iteration": 0}]


def test_open_existing_requires_run(tmp_path):
    with pytest.raises(UserInputError, match="not a run directory"):
        RunDirectory(tmp_path, create=False)


def test_path_that_is_a_file(tmp_path):
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(UserInputError, match="not a directory"):
        RunDirectory(f)


def test_trajectory_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 10, 3))
    F = np.tile(np.eye(3), (4, 10, 1, 1)) * 1.1
    write_trajectory(
        tmp_path / "trajectory.npz",
        x=x,
        t=np.arange(4) * 0.04,
        F=F,
        mass=np.ones(10),
        gravity=np.array([0, 0, -9.8]),
    )
    d = read_trajectory(tmp_path / "trajectory.npz")
    assert d["x"].dtype == np.float32 and d["x"].shape == (4, 10, 3)
    assert d["det_F"].shape == (4, 10)
    np.testing.assert_allclose(d["det_F"], 1.1**3, rtol=1e-5)
    np.testing.assert_allclose(d["t"], [0, 0.04, 0.08, 0.12], rtol=1e-6)
    assert d["mass"].shape == (10,)


def test_trajectory_shape_errors(tmp_path):
    with pytest.raises(ValueError, match="t must be"):
        write_trajectory(tmp_path / "t.npz", x=np.zeros((3, 2, 3)), t=np.zeros(2))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(UserInputError, match="bad.npz"):
        read_trajectory(tmp_path / "bad.npz")
