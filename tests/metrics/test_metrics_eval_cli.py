"""``motionphysics eval`` and ``compare`` through the command line on tiny real runs and on
a run directory written by hand (only trajectory.npz x/t, video.mp4 and a prompt)."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from motionphysics.cli import main


def _eval(run, *extra):
    assert main(["--quiet", "eval", str(run), *extra]) == 0
    return json.loads((run / "metrics.json").read_text())


def test_eval_writes_every_metric(tiny_runs):
    m = _eval(tiny_runs["ball"])
    assert math.isfinite(m["ecms"]) and m["ecms"] > 0
    assert set(m["ecms_terms"]) == {"motion", "temporal", "spatial"}
    assert all(math.isfinite(v) and v >= 0 for v in m["ecms_terms"].values())
    assert m["ecms_details"]["flow"] == "dis" and m["ecms_details"]["flow_size"][0] == 256
    assert m["clipsim"] is None and m["clipsim_reason"] == "no CLIP weights: pass --clip DIR"
    assert m["oc"] is None and "--viclip" in m["oc_reason"]
    ma = m["motion_adherence"]
    assert ma["prompt"].startswith("A rubber ball") and 0 <= ma["score"] <= 1
    assert {b["name"] for b in ma["behaviours"]} >= {"rebound", "fall"}
    # physical: the stored elastic energy is in the total; the floor is the run's collider
    assert m["total_energy_terms"] == ["kinetic", "potential", "elastic"]
    assert max(m["elastic_energy"]) > 0 and m["floor_height"] == 0.0
    ke, pe, el = (np.array(m[k]) for k in ("kinetic_energy", "potential_energy", "elastic_energy"))
    np.testing.assert_allclose(np.array(m["total_energy"]), ke + pe + el, rtol=1e-9, atol=1e-12)
    assert "final_extent_ratio" in m and "final_height_ratio" in m  # new name and old name


def test_eval_prompt_ranks_the_right_run(tiny_runs):
    ball, drop = tiny_runs["ball"], tiny_runs["drop"]
    pb, pd = "A rubber ball bounces on the floor.", "Water splashes and spreads over the floor."
    s = {
        (p, r): _eval(run, "--prompt", text)["motion_adherence"]["score"]
        for p, text in (("ball", pb), ("drop", pd))
        for r, run in (("ball", ball), ("drop", drop))
    }
    assert s[("ball", "ball")] > s[("drop", "ball")]  # on the ball run, the ball prompt wins
    assert s[("drop", "drop")] > s[("ball", "drop")]
    assert s[("ball", "ball")] > s[("ball", "drop")] and s[("drop", "drop")] > s[("drop", "ball")]
    m = json.loads((drop / "metrics.json").read_text())
    assert m["prompt_source"] == "--prompt"
    assert _eval(drop)["prompt_source"] == "run.yaml"


def test_eval_on_a_run_made_elsewhere(tiny_runs, tmp_path):
    src = tiny_runs["drop"]
    with np.load(src / "trajectory.npz") as z:
        np.savez(tmp_path / "trajectory.npz", x=z["x"], t=z["t"])  # nothing else
    shutil.copy(src / "video.mp4", tmp_path / "video.mp4")
    (tmp_path / "run.yaml").write_text("prompt: A drop of water falls and splashes.\n")
    m = _eval(tmp_path)
    assert math.isfinite(m["ecms"]) and m["clipsim"] is None and m["oc"] is None
    assert m["motion_adherence"]["score"] > 0.6
    assert m["total_energy_terms"] == ["kinetic", "potential"] and m["elastic_energy"] is None
    assert m["elastic_energy_reason"]


def test_eval_bad_input_is_one_line(tiny_runs, tmp_path, capsys):
    assert main(["eval", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "trajectory.npz" in err and "\n" not in err
    assert main(["eval", str(tiny_runs["ball"]), "--flow", "raft"]) == 2
    assert "--raft" in capsys.readouterr().err
    assert main(["eval", str(tiny_runs["ball"]), "--clip", str(tmp_path / "nope")]) == 2
    assert "--clip" in capsys.readouterr().err


def test_compare_writes_grid_and_table(tiny_runs, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert (
        main(
            [
                "--quiet",
                "compare",
                str(tiny_runs["ball"]),
                str(tiny_runs["drop"]),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    md = (out / "compare.md").read_text()
    assert "| | ball | drop |" in md and "ECMS" in md and "CLIPSIM" in md and "OC" in md
    assert "elastic" in md and "newtonian" in md and "optimisation time" in md
    assert "<table>" in (out / "compare.html").read_text()
    from motionphysics.io.video import read_video

    grid = read_video(out / "compare.mp4")
    single = read_video(tiny_runs["ball"] / "video.mp4")
    assert grid.shape[0] == max(
        single.shape[0], read_video(tiny_runs["drop"] / "video.mp4").shape[0]
    )
    assert grid.shape[2] >= 2 * single.shape[2]
    assert main(["compare", str(tiny_runs["ball"]), "--out", str(out)]) == 2  # exists, no --force


def test_eval_ignores_an_unasked_jiggle_too_small_to_see(tiny_runs, tmp_path):
    """``motionphysics eval`` on two hand-written run directories of the same bounce: one
    jiggles by a strain of 1.2 % after landing, one wobbles by 5 %. The unasked oscillation counts
    against "bounces" only where it is visible (metrics.adherence.VISIBLE_SWING)."""
    from tests.metrics.test_metrics_adherence import bounce, bounce_with_jiggle

    scores = {}
    for name, traj in (
        ("still", bounce()),
        ("jiggle", bounce_with_jiggle(0.012)),
        ("wobble", bounce_with_jiggle(0.05)),
    ):
        run = tmp_path / name
        run.mkdir()
        np.savez(run / "trajectory.npz", x=traj["x"], t=traj["t"])
        shutil.copy(tiny_runs["ball"] / "video.mp4", run / "video.mp4")
        (run / "run.yaml").write_text("prompt: A rubber ball bounces on the floor.\n")
        scores[name] = _eval(run)["motion_adherence"]
    assert scores["jiggle"]["score"] == pytest.approx(scores["still"]["score"], abs=0.02)
    assert scores["wobble"]["score"] < 0.8 * scores["still"]["score"]
    (row,) = [r for r in scores["jiggle"]["behaviours"] if r["name"] == "oscillate"]
    assert row["explain"].startswith("not asked to oscillate: 0 visible swings")
