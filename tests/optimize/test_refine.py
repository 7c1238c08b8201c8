"""The refinement stage of ``run`` end to end, through the generic code path (registry
-> Loss.build -> WeightedLoss -> optimisation loop -> writer), with a real loss that
needs no prior: ``video_match`` against a reference video made by ``simulate``."""

from __future__ import annotations

import json

import pytest
import torch
import yaml

from motionphysics.cli import main

BASE = {
    "scene": {
        "source": "builtin:sphere",
        "scale": 0.3,
        "translate": [0, 0, 0.2],
        "max_particles": 150,
    },
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "sim": {"grid": 10, "frames": 4, "frame_dt": 0.03, "substeps": 12},
    "boundary_conditions": [
        {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "sticky"},
        {"type": "bounding_box"},
    ],
    "camera": {"width": 32, "height": 32},
}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("refine")
    true = {**BASE, "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3}}
    (d / "true.yaml").write_text(yaml.safe_dump(true))
    assert main(["--quiet", "simulate", str(d / "true.yaml"), "--out", str(d / "ref")]) == 0
    start = {
        **BASE,
        "material": {"class": "elastic", "density": 1000.0, "E": 2.0e9, "nu": 0.3},
        "optimize": {
            "losses": [
                {"type": "video_match", "weight": 1.0, "reference": str(d / "ref" / "video.mp4")}
            ],
            "params": ["E"],
            "iterations": 3,
            "boost": 1,
            "lr": 0.3,
            "warmup": 0,
        },
    }
    (d / "start.yaml").write_text(yaml.safe_dump(start))
    return d


def test_run_refines_the_material_through_the_registry(setup):
    d = setup
    out = d / "run"
    assert main(["--quiet", "run", str(d / "start.yaml"), "--out", str(out)]) == 0
    p = json.loads((out / "params.json").read_text())
    assert p["command"] == "run" and p["partial"] is False
    opt = p["optimise"]
    assert opt["iterations_run"] == 3 and opt["loss"] == "video_match" and opt["prior"] == "none"
    assert len(p["history"]) == 3
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in log] == [0, 1, 2]
    for r in log:
        assert r["loss"] > 0 and r["grad_norm"]["total"] > 0 and r["substeps"] == 12
        assert {"l1", "dssim"} <= {k.removeprefix("loss_") for k in r}
    # initial and final side by side; the stiffness moved from 2e9 towards the true 2e7
    assert p["initial"]["params"]["E"] == 2.0e9
    assert p["params"]["E"] < 2.0e9 and log[-1]["params"]["E"] < log[0]["params"]["E"]
    for f in ("plots/loss.png", "plots/params.png", "video.mp4", "checkpoint.pt", "scene.ply"):
        assert (out / f).is_file(), f
    ck = torch.load(out / "checkpoint.pt", weights_only=False)
    assert len(ck["loss_states"]) == 1
    # run.yaml records the material the run started from; re-reading it works
    y = yaml.safe_load((out / "run.yaml").read_text())
    assert (
        y["optimize"]["losses"][0]["type"] == "video_match"
        and y["optimize"]["loss"] == "video_match"
    )


def test_resume_continues_the_refinement_exactly(setup, tmp_path, monkeypatch):
    """Killed and resumed = uninterrupted, bit for bit. With trajectory_match: the
    renderer's threaded backward sums tiles in varying order (ulp-level differences in
    video_match gradients between two fresh runs), the simulator's does not."""
    import motionphysics.optimize.loop as loop

    d = setup
    cfg = yaml.safe_load((d / "start.yaml").read_text())
    ref = str(d / "ref" / "trajectory.npz")
    cfg["optimize"]["losses"] = [{"type": "trajectory_match", "reference": ref}]
    (tmp_path / "start.yaml").write_text(yaml.safe_dump(cfg))
    d = tmp_path
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["--quiet", "run", str(d / "start.yaml"), "--out", str(a), "--iters", "3"]) == 0
    # Ctrl-C right after the first iteration's checkpoint: the run stops, marked partial
    real = loop.save_checkpoint
    calls = []

    def save_then_interrupt(ckpt, path):
        real(ckpt, path)
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(loop, "save_checkpoint", save_then_interrupt)
    assert main(["--quiet", "run", str(d / "start.yaml"), "--out", str(b), "--iters", "3"]) == 130
    assert json.loads((b / "params.json").read_text())["partial"] is True
    monkeypatch.setattr(loop, "save_checkpoint", real)
    assert (
        main(["--quiet", "run", str(d / "start.yaml"), "--out", str(b), "--iters", "3", "--resume"])
        == 0
    )
    ta = torch.load(a / "checkpoint.pt", weights_only=False)["theta"]
    tb = torch.load(b / "checkpoint.pt", weights_only=False)["theta"]
    assert all(torch.equal(ta[n], tb[n]) for n in ta)
    pa = json.loads((a / "params.json").read_text())
    pb = json.loads((b / "params.json").read_text())
    assert pa["params"] == pb["params"] and len(pb["history"]) == 3


def test_loss_flag_without_a_prior_is_a_user_error(setup, capsys):
    d = setup
    rc = main(["run", str(d / "start.yaml"), "--out", str(d / "nope"), "--loss", "video_match"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "--prior" in err and "--loss" in err


def test_unknown_loss_in_the_config_names_the_choices(setup, tmp_path, capsys):
    d = setup
    bad = yaml.safe_load((d / "start.yaml").read_text())
    bad["optimize"]["losses"][0]["type"] = "video_mtch"
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    rc = main(["run", str(tmp_path / "bad.yaml"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "optimize.losses[0]" in err and "video_match" in err
