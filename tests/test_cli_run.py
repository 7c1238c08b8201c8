"""Command-line behaviour of run / simulate / eval / demo: exit codes and one-line errors."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.conftest import restore_sigint  # noqa: E402

from motionphysics.cli import main

DATA = Path(__file__).parent / "data"
TINY = DATA / "pipeline_tiny.yaml"


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    return err


def test_unknown_key_is_exit_2(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("scene: {source: 'builtin:sphere'}\nsim: {grids: 32}\n")
    assert main(["run", str(cfg), "--out", str(tmp_path / "o")]) == 2
    err = _one_line_error(capsys)
    assert "bad.yaml" in err and "sim.grids" in err and "unknown key" in err
    assert not (tmp_path / "o").exists()


def test_bad_value_names_field(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("sim: {frames: -3}\n")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "o")]) == 2
    err = _one_line_error(capsys)
    assert "bad.yaml" in err and "sim.frames" in err


def test_missing_config_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    assert "config file not found" in _one_line_error(capsys)


def test_not_yaml_mapping(tmp_path, capsys):
    cfg = tmp_path / "list.yaml"
    cfg.write_text("- 1\n- 2\n")
    assert main(["run", str(cfg)]) == 2
    assert "mapping" in _one_line_error(capsys)


def test_embedded_prior_refines_without_a_path(tmp_path):
    # The embedded motion prior ships with the package: --prior motion needs no --prior-path.
    out = tmp_path / "o"
    argv = [
        "run",
        str(TINY),
        "--prior",
        "motion",
        "--loss",
        "lmd",
        "--iters",
        "1",
        "--out",
        str(out),
    ]
    assert main([*argv, "--quiet"]) == 0
    recs = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert len(recs) == 1 and math.isfinite(recs[0]["loss"])
    p = json.loads((out / "params.json").read_text())
    assert p["optimise"]["prior"] == "motion" and len(p["history"]) == 1
    # 8 frames and the default boost 8 would show the 16-frame prior one frame at a time:
    # the boost is capped to 1, every frame after the initial state is supervised
    assert p["optimise"]["boost_requested"] == 8 and p["optimise"]["boost"] == 1
    assert "boost" in p["optimise"]["boost_note"]
    assert recs[0]["frames"] == list(range(1, 8))
    # the motion prior's own lmd defaults (MotionPrior.loss_defaults), the negative prompt
    # derived from the prompt ("... bounces back" -> the opposite motion)
    lo = p["optimise"]["loss_options"]["lmd"]
    assert (lo["form"], lo["guidance"], lo["samples"], lo["negative_prompt"]) == (
        "classifier_score",
        5.0,
        8,
        "auto",
    )
    assert lo["negative_prompt_used"] == "A rubber ball squashes and stays flat"
    assert recs[0]["loss_samples"] == 8.0 and recs[0]["guidance"] == 5.0


def test_an_event_clause_does_not_decide_the_contrast(tmp_path):
    """A user's prompt through a config file: "hits the ground" is an event, not a motion;
    the contrast is read from "leaps back up" (a high bounce), so the run is pushed away
    from squashing flat, and params.json says what was asked."""
    import yaml

    data = yaml.safe_load(TINY.read_text())
    data["prompt"] = "A super ball hits the ground and leaps back up"
    data["optimize"] = {"prior": "motion", "loss": "lmd", "iterations": 1, "boost": 1}
    cfg = tmp_path / "super.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "o"
    assert main(["run", str(cfg), "--out", str(out), "--quiet"]) == 0
    opt = json.loads((out / "params.json").read_text())["optimise"]
    assert opt["loss_options"]["lmd"]["negative_prompt_used"] == (
        "A super ball squashes and stays flat"
    )
    assert opt["motion"]["asked"] == "bounces_high"
    assert opt["prior_limits"] == []  # an elastic ball: nothing the words cannot set


def test_sand_under_the_motion_prior_says_the_words_do_not_set_its_friction(tmp_path, capsys):
    """The motion prior cannot tell a steep heap from a flat spread: a sand run through a
    config file says so in one warning, which params.json keeps; an elastic run does not."""
    import yaml

    data = yaml.safe_load(TINY.read_text())
    data["prompt"] = "A ball of coarse gravel is dropped and stays a tall, steep heap"
    data["material"] = {"class": "sand", "density": 1600, "theta_fric": 35.0}
    data["optimize"] = {"prior": "motion", "loss": "lmd", "iterations": 1, "boost": 1}
    cfg = tmp_path / "gravel.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "o"
    assert main(["run", str(cfg), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if "cannot tell a steep heap" in x]
    assert len(lines) == 1 and "material.theta_fric" in lines[0]
    opt = json.loads((out / "params.json").read_text())["optimise"]
    assert len(opt["prior_limits"]) == 1 and "theta_fric" in opt["optimised"]


def test_config_options_win_over_the_priors_loss_defaults(tmp_path):
    import yaml

    data = yaml.safe_load(TINY.read_text())
    data["optimize"] = {
        "losses": [{"type": "lmd", "form": "absolute", "samples": 2, "negative_prompt": ""}]
    }
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "o"
    argv = [
        "run",
        str(cfg),
        "--prior",
        "motion",
        "--iters",
        "1",
        "--guidance",
        "7",
        "--out",
        str(out),
    ]
    assert main([*argv, "--quiet"]) == 0
    lo = json.loads((out / "params.json").read_text())["optimise"]["loss_options"]["lmd"]
    # every option the config or --guidance sets is taken over the prior's default
    assert (lo["form"], lo["samples"], lo["negative_prompt_used"]) == ("absolute", 2, "")
    assert lo["guidance"] == 7.0


REMOVED_TINY = (
    "the embedded pixel prior was removed (it could not tell motions apart: 20 % held-out "
    "caption discrimination)"
)


def test_prior_tiny_on_the_command_line_is_refused_in_one_line(tmp_path, capsys):
    """The pixel prior (--prior tiny) was removed: the flag is refused with the reason and
    the way out, before anything is simulated or written."""
    out = tmp_path / "o"
    rc = main(["run", str(TINY), "--prior", "tiny", "--iters", "1", "--out", str(out)])
    assert rc == 2
    assert _one_line_error(capsys) == (
        f"motionphysics: error: --prior tiny: {REMOVED_TINY}; use --prior motion (the "
        "embedded default) or --prior cogvideox/modelscope with a local model path "
        "(--prior-path DIR)"
    )
    assert not out.exists()
    # and the usage no longer offers it
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "tiny" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["run", "simulate"])
def test_a_config_asking_for_the_tiny_prior_is_refused_in_one_line(tmp_path, capsys, command):
    import yaml

    data = yaml.safe_load(TINY.read_text())
    data["optimize"] = {"prior": "tiny", "iterations": 1}
    cfg = tmp_path / "old.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "o"
    assert main([command, str(cfg), "--out", str(out)]) == 2
    assert _one_line_error(capsys) == (
        f"motionphysics: error: {cfg}: optimize.prior: 'tiny': {REMOVED_TINY}; use "
        "optimize.prior: motion (the embedded default) or cogvideox/modelscope with a local "
        "model path (optimize.prior_path: DIR)"
    )
    assert not out.exists()
    # --prior on the command line overrides the config's prior: then the run is accepted
    if command == "run":
        rc = main(["--quiet", "run", str(cfg), "--prior", "none", "--out", str(out)])
        assert rc == 0 and (out / "params.json").is_file()


def test_bad_params_file(tmp_path, capsys):
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"class": "elastic", "density": 1000, "params": {"E": 1e7, "mu": 1.0}}))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "scene: {source: 'builtin:sphere', scale: 0.3, translate: [0, 0, 0.3], max_particles: 500}\n"
        "sim: {grid: 12, frames: 2}\n"
    )
    assert main(["simulate", str(cfg), "--params", str(p), "--out", str(tmp_path / "o")]) == 2
    err = _one_line_error(capsys)
    assert "mu" in err
    p.write_text("{not json")
    assert main(["simulate", str(cfg), "--params", str(p), "--out", str(tmp_path / "o2")]) == 2
    assert "p.json" in _one_line_error(capsys)


def test_eval_on_non_run(tmp_path, capsys):
    assert main(["eval", str(tmp_path)]) == 2
    assert "not a run directory" in _one_line_error(capsys)


def test_ctrl_c_leaves_consistent_partial_run(tmp_path):
    """A real SIGINT to a running `motionphysics run`: exit 130, partial run marked."""
    cfg = tmp_path / "long.yaml"
    # A complete material (no estimate stage: a quicker start) and a long simulation.
    short = TINY.read_text().replace(
        "material: {nu: 0.4}", "material: {class: elastic, density: 1100, E: 2.0e7, nu: 0.4}"
    )
    assert "E: 2.0e7" in short
    text = short.replace(
        "frames: 8, frame_dt: 0.04, substeps: auto", "frames: 200, frame_dt: 0.04, substeps: 100"
    )
    assert "substeps: 100" in text  # tens of seconds of simulation: the signal lands inside it
    cfg.write_text(text)
    (tmp_path / "short.yaml").write_text(short)
    out = tmp_path / "run"
    env = dict(os.environ)
    env.setdefault("MOTIONPHYSICS_CACHE", str(Path(__file__).resolve().parents[1] / ".cache"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionphysics", "run", str(cfg), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=restore_sigint,
    )
    try:
        deadline = time.time() + 240
        stage = None
        while time.time() < deadline and proc.poll() is None:
            try:
                stage = json.loads((out / "params.json").read_text()).get("stage")
            except (OSError, ValueError):
                stage = None
            if stage == "simulate":
                break
            time.sleep(0.2)
        assert stage == "simulate", f"never reached the simulate stage (last: {stage})"
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted" in err and "partial" in err and "Traceback" not in err
    p = json.loads((out / "params.json").read_text())
    assert p["partial"] is True and p["status"] == "interrupted" and p["stage"] == "simulate"
    assert p["class"] == "elastic"  # what was known before the interruption is kept
    assert not (out / "trajectory.npz").exists()
    assert not [q.name for q in out.iterdir() if q.name.startswith(".")]  # no temporaries
    assert (out / "report.html").is_file() and "did not finish" in (out / "report.html").read_text()
    # the partial run is refused without --resume / --force, and --force replaces it
    proc2 = subprocess.run(
        [sys.executable, "-m", "motionphysics", "run", str(cfg), "--out", str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc2.returncode == 2 and "partial run" in proc2.stderr
    # --force replaces the partial run with a complete one
    assert main(["--quiet", "run", str(tmp_path / "short.yaml"), "--out", str(out), "--force"]) == 0
    p = json.loads((out / "params.json").read_text())
    assert p["partial"] is False and p["status"] == "complete"
    assert (out / "trajectory.npz").is_file()
