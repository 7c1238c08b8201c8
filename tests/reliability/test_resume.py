"""``--resume`` through the command line: only the same config, "already complete"
without rewriting a byte, and one line saying from where an interrupted run goes on.

The comparison itself (:func:`motionphysics.io.resume.config_difference`) is checked on
plain data first; the command-line cases share one tiny ``simulate`` run."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from motionphysics.cli import main
from motionphysics.io.resume import config_difference

TINY = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.2],
        "max_particles": 100,
    },
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "sim": {"grid": 8, "frames": 3, "frame_dt": 0.03, "substeps": 8},
    "boundary_conditions": [
        {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "sticky"},
        {"type": "bounding_box"},
    ],
    "camera": {"width": 16, "height": 16},
}


def snapshot(run_dir: Path) -> dict[str, tuple[int, int]]:
    """Every file below ``run_dir`` with its (mtime_ns, size)."""
    out = {}
    for p in sorted(run_dir.rglob("*")):
        if p.is_file():
            st = p.stat()
            out[str(p.relative_to(run_dir))] = (st.st_mtime_ns, st.st_size)
    return out


# -- the comparison ----------------------------------------------------------------------
def test_difference_names_the_first_differing_key_in_request_order():
    rec = {"sim": {"frames": 4, "grid": 10}, "camera": {"radius": 0.8}, "material": {"E": 1e7}}
    assert config_difference({"sim": {"frames": 4, "grid": 10}}, rec) is None
    assert config_difference({"sim": {"grid": 12, "frames": 5}}, rec) == ("sim.grid", 12, 10)
    # null in the request: resolved by the run (an estimated material), matches anything
    assert config_difference({"material": None, "sim": {"frames": 4}}, rec) is None
    assert config_difference({"material": {"E": None}}, rec) is None
    assert config_difference({"material": {"E": 2e7}}, rec) == ("material.E", 2e7, 1e7)
    # a default the run replaces (auto-framed camera) only when declared open
    assert config_difference({"camera": {"radius": 2.5}}, rec) == ("camera.radius", 2.5, 0.8)
    assert config_difference({"camera": {"radius": 2.5}}, rec, open_keys={"camera.radius"}) is None
    # list items by index; a value the run never recorded differs
    bc = {"bc": [{"mode": "sticky"}, {"mode": "slip"}]}
    assert config_difference({"bc": [{"mode": "sticky"}, {"mode": "slip"}]}, bc) is None
    assert config_difference({"bc": [{"mode": "sticky"}, {"mode": "sep"}]}, bc) == (
        "bc[1].mode",
        "sep",
        "slip",
    )
    assert config_difference({"bc": [{"mode": "sticky"}]}, bc)[0] == "bc"
    assert config_difference({"new": 1}, rec) == ("new", 1, None)
    # booleans are not numbers here: True is not 1
    assert config_difference({"f": True}, {"f": 1}) == ("f", True, 1)


# -- the command line ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """A complete ``simulate`` run of :data:`TINY`."""
    d = tmp_path_factory.mktemp("resume")
    (d / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    assert main(["--quiet", "simulate", str(d / "tiny.yaml"), "--out", str(d / "run")]) == 0
    return d


def _err_lines(capsys) -> list[str]:
    # (the resume messages; the warnings about the physics of this tiny scene -- a 0.3 m
    # ball on an 8-cell grid: hollow, touching the domain walls -- are not what is checked)
    return [
        ln
        for ln in capsys.readouterr().err.splitlines()
        if ln.strip() and not ln.startswith("warning:")
    ]


def test_resume_of_a_complete_run_rewrites_nothing(done, capsys):
    run = done / "run"
    before = snapshot(run)
    rc = main(["--quiet", "simulate", str(done / "tiny.yaml"), "--out", str(run), "--resume"])
    lines = _err_lines(capsys)
    assert rc == 0
    assert len(lines) == 1 and "already complete" in lines[0] and str(run) in lines[0]
    assert snapshot(run) == before
    # the resolved run.yaml (material, camera filled in) is the same config too
    rc = main(["--quiet", "simulate", str(run / "run.yaml"), "--out", str(run), "--resume"])
    assert rc == 0 and "already complete" in _err_lines(capsys)[0]
    assert snapshot(run) == before
    # not quiet: the summary of the finished run, read back from its files
    rc = main(["simulate", str(done / "tiny.yaml"), "--out", str(run), "--resume"])
    captured = capsys.readouterr()
    assert rc == 0 and "material:" in captured.out and "elastic" in captured.out
    assert snapshot(run) == before


@pytest.mark.parametrize(
    ("change", "key", "old", "new"),
    [
        (lambda c: c["sim"].update(frames=4), "sim.frames", "3", "4"),
        (
            lambda c: c["boundary_conditions"][0].update(mode="slip"),
            "boundary_conditions[0].mode",
            "'sticky'",
            "'slip'",
        ),
        (lambda c: c.update(material={"class": "plasticine"}), "material.class", "'elastic'", ""),
    ],
)
def test_resume_with_a_different_config_is_refused(done, tmp_path, capsys, change, key, old, new):
    run = done / "run"
    before = snapshot(run)
    cfg = json.loads(json.dumps(TINY))
    change(cfg)
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(cfg))
    rc = main(["--quiet", "simulate", str(tmp_path / "other.yaml"), "--out", str(run), "--resume"])
    lines = _err_lines(capsys)
    assert rc == 2 and len(lines) == 1, lines
    assert key in lines[0] and old in lines[0] and new in lines[0] and "--force" in lines[0]
    assert "Traceback" not in lines[0]
    assert snapshot(run) == before
    assert yaml.safe_load((run / "run.yaml").read_text())["sim"]["frames"] == 3


def test_resume_of_another_command_is_refused(done, capsys):
    run = done / "run"
    before = snapshot(run)
    rc = main(["--quiet", "run", str(done / "tiny.yaml"), "--out", str(run), "--resume"])
    lines = _err_lines(capsys)
    assert rc == 2 and len(lines) == 1 and "command" in lines[0] and "simulate" in lines[0]
    assert snapshot(run) == before


def test_interrupted_simulate_says_it_restarts_and_ends_as_uninterrupted(
    done, tmp_path, capsys, monkeypatch
):
    """Ctrl-C in 'render': the run says it stopped there and restarts from 'simulate'
    at frame 0; the finished trajectory equals the uninterrupted one bit for bit."""
    import motionphysics.assembly as assembly

    run = tmp_path / "run"
    real = assembly.Assembly.render

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(assembly.Assembly, "render", interrupted)
    rc = main(["--quiet", "simulate", str(done / "tiny.yaml"), "--out", str(run)])
    assert rc == 130
    p = json.loads((run / "params.json").read_text())
    assert p["partial"] is True and p["stage"] == "render" and p["status"] == "interrupted"
    capsys.readouterr()
    monkeypatch.setattr(assembly.Assembly, "render", real)
    rc = main(["--quiet", "simulate", str(done / "tiny.yaml"), "--out", str(run), "--resume"])
    lines = _err_lines(capsys)
    assert rc == 0 and len(lines) == 1
    assert "resuming" in lines[0] and "'render'" in lines[0]
    assert "restarting from 'simulate' at frame 0" in lines[0]
    p = json.loads((run / "params.json").read_text())
    assert p["partial"] is False and p["status"] == "complete"
    with np.load(run / "trajectory.npz") as a, np.load(done / "run" / "trajectory.npz") as b:
        assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["F"], b["F"])
    assert not [f for f in os.listdir(run) if f.startswith(".")]


def test_resume_where_there_is_no_run_starts_one_and_says_so(done, tmp_path, capsys):
    run = tmp_path / "fresh"
    rc = main(["--quiet", "simulate", str(done / "tiny.yaml"), "--out", str(run), "--resume"])
    lines = _err_lines(capsys)
    assert rc == 0 and len(lines) == 1 and "nothing to resume" in lines[0]
    assert json.loads((run / "params.json").read_text())["partial"] is False


def test_resume_with_force_and_a_different_config_starts_over(done, tmp_path, capsys):
    import shutil

    run = tmp_path / "copy"
    shutil.copytree(done / "run", run)
    cfg = json.loads(json.dumps(TINY))
    cfg["sim"]["frames"] = 2
    (tmp_path / "two.yaml").write_text(yaml.safe_dump(cfg))
    rc = main(
        [
            "--quiet",
            "simulate",
            str(tmp_path / "two.yaml"),
            "--out",
            str(run),
            "--resume",
            "--force",
        ]
    )
    lines = _err_lines(capsys)
    assert rc == 0 and len(lines) == 1 and "sim.frames" in lines[0] and "starting over" in lines[0]
    with np.load(run / "trajectory.npz") as z:
        assert z["x"].shape[0] == 2
