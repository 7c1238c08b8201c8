"""``run --prior motion``: the refinement observes the simulated states (no render for the
loss), and recolouring the scene leaves the loss bit-identical."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import yaml

from motionphysics.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "priors"))
from motion_helpers import write_shards  # noqa: E402


def _config(source: str) -> dict:
    return {
        "scene": {"source": source, "scale": 0.3, "translate": [0, 0, 0.25], "max_particles": 300},
        "prompt": "A rubber bird bounces high.",
        "material": {"class": "elastic", "density": 1000.0, "E": 1.0e5, "nu": 0.3},
        "sim": {"grid": 12, "frames": 9, "frame_dt": 0.04, "substeps": "auto"},
        "camera": {"width": 32, "height": 32},
        "optimize": {"iterations": 2, "boost": 1},
    }


@pytest.mark.slow
def test_recolouring_the_scene_leaves_the_motion_prior_loss_bit_identical(tmp_path):
    from motionphysics.priors.motion_train import MotionTrainOptions, train

    data = write_shards(tmp_path / "data", ["bounces_high", "splashes", "keeps_shape"] * 3)
    ck = tmp_path / "m.pt"
    train(data, ck, MotionTrainOptions(max_steps=2, batch=4, size="test"), log=lambda _: None)
    logs = {}
    for source in ("builtin:bird_plain", "builtin:bird_red"):  # same splats, other colours
        cfg = tmp_path / f"{source[8:]}.yaml"
        cfg.write_text(yaml.safe_dump(_config(source)))
        out = tmp_path / source[8:]
        args = ["--quiet", "run", str(cfg), "--prior", "motion", "--prior-path", str(ck)]
        assert main([*args, "--loss", "lmd", "--iters", "2", "--out", str(out)]) == 0
        logs[source] = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
        params = json.loads((out / "params.json").read_text())
        assert params["optimise"]["prior"] == "motion"
        assert "observed particle positions" in params["optimise"]["perturbation"]["applies_to"]
    a, b = logs.values()
    assert len(a) == len(b) == 2
    for ra, rb in zip(a, b, strict=True):
        assert ra["loss"] == rb["loss"] and ra["params"] == rb["params"]
        assert ra["grad_norm"] == rb["grad_norm"]
        assert ra["time"]["render"] < 0.01  # nothing was rendered for the loss


def test_the_summary_params_and_report_show_the_motion_asked_and_simulated(tmp_path, capsys):
    """``run --prior motion`` (the shipped weights) through a config file: the summary,
    ``params.json`` and the report put the motion group the prompt asks for beside the
    groups of the initial and the refined trajectory."""
    data = _config("builtin:sphere")
    data["optimize"] = {"iterations": 1, "boost": 1, "prior": "motion", "loss": "lmd"}
    cfg = tmp_path / "ball.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    summary = capsys.readouterr().out
    motion = json.loads((out / "params.json").read_text())["optimise"]["motion"]
    assert motion["asked"] == "bounces_high"  # "A rubber bird bounces high."
    for when in ("before", "after"):
        m = motion[when]["measures"]
        assert set(m) >= {"rebound", "max_deform", "max_spread"}
        assert motion[when]["group"] is None or isinstance(motion[when]["group"], str)
    assert motion["lines"][0] == "motion asked: bounces high (the prompt's motion words)"
    for line in motion["lines"]:
        assert line in summary
    report = (out / "report.html").read_text()
    assert "Motion asked for and simulated" in report and "before refinement:" in report
    # eval's motion adherence of both trajectories: the refined one is the number
    # metrics.json holds (float32 trajectory.npz against the float64 states: 1e-4)
    a0, a1 = motion["before"]["adherence"]["score"], motion["after"]["adherence"]["score"]
    assert 0.0 <= a0 <= 1.0 and 0.0 <= a1 <= 1.0
    assert main(["--quiet", "eval", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert a1 == pytest.approx(metrics["motion_adherence"]["score"], abs=1e-4)
    assert f"motion adherence (eval, 0..1): {a0:.2f} before, {a1:.2f} after" in summary


def test_a_refined_run_reads_the_motion_asked_for_what_its_material_can_show(tmp_path, capsys):
    """Through a config file: a refined water run whose prompt says "collapses" asks for a
    splash ("crumbles" is sand's word), as the same run without refinement reads it."""
    data = _config("builtin:cube")
    data["prompt"] = "A block of water collapses and splashes across the floor of a tank."
    data["material"] = {"class": "newtonian", "density": 1000.0, "mu": 1.0, "kappa": 1.0e5}
    data["optimize"] = {"iterations": 1, "boost": 1, "prior": "motion", "loss": "lmd"}
    cfg = tmp_path / "water.yaml"
    cfg.write_text(yaml.safe_dump(data))
    asked = {}
    for refine in (True, False):
        out = tmp_path / f"run{refine}"
        args = ["run", str(cfg), "--out", str(out)] + ([] if refine else ["--iters", "0"])
        assert main(args) == 0
        params = json.loads((out / "params.json").read_text())
        rec = params["optimise"]["motion"] if refine else params["metrics"]["motion"]
        asked[refine] = rec["asked"]
    assert asked == {True: "splashes", False: "splashes"}
    assert "motion asked: splashes" in capsys.readouterr().out
