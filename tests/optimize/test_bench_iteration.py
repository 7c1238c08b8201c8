"""``motionphysics bench iteration --prior motion``: one refinement iteration with the
embedded motion prior (no render), split, against a forward simulate, through the CLI."""

import json

from motionphysics.cli import main

TINY = ["--grid", "12", "--frames", "4", "--particles", "300", "--substeps", "16"]


def test_bench_iteration_motion_prior_reports_the_split(capsys):
    rc = main(["bench", "iteration", "--prior", "motion", *TINY, "--repeats", "2", "--json"])
    assert rc == 0
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["prior"] == "motion" and r["loss"] == "lmd"
    assert r["substeps"] == 16 and r["frames_simulated"] == 4 and r["particles"] == 300
    assert r["repeats"] == 2
    assert len(r["iteration_runs_s"]) == 2 and len(r["forward_simulate_runs_s"]) == 2
    parts = ("simulate_s", "loss_s", "backward_s", "iteration_s", "forward_simulate_s")
    assert all(r[k] > 0 for k in parts)
    # the loss holds the prior's features and predictions; the backward its two halves
    assert 0 < r["features_s"] + r["predict_s"] <= r["loss_s"] + 1e-4
    assert abs(r["backward_prior_s"] + r["backward_sim_s"] - r["backward_s"]) < 1e-3
    # no render in the loop: the parts are (nearly all of) the iteration
    assert r["simulate_s"] + r["loss_s"] + r["backward_s"] <= r["iteration_s"] + 1e-3
    # the ratios are of the medians, and each round's
    assert (
        abs(r["ratio_to_forward"] - r["iteration_s"] / r["forward_simulate_s"])
        < 0.02 * r["ratio_to_forward"]
    )
    assert len(r["ratio_per_round"]) == 2 and r["ratio_median_of_rounds"] > 0
    assert r["taped_rollout_over_forward"] > 0 and r["backward_over_forward"] > 0


def test_bench_iteration_motion_prints_a_table(capsys):
    rc = main(["bench", "iteration", "--prior", "motion", *TINY, "--repeats", "1"])
    assert rc == 0
    lines = capsys.readouterr().out.splitlines()
    keys = {line.split(":", 1)[0].strip() for line in lines if ":" in line}
    assert {"simulate_s", "backward_sim_s", "forward_simulate_s", "ratio_to_forward"} <= keys


def test_bench_iteration_refuses_bad_sizes(capsys):
    assert main(["bench", "iteration", "--prior", "motion", "--substeps", "many"]) == 2
    assert "--substeps" in capsys.readouterr().err
    assert main(["bench", "iteration", "--prior", "motion", "--repeats", "0"]) == 2
    assert "--repeats" in capsys.readouterr().err
