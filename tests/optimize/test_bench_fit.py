"""``motionphysics bench fit``: the split of one fit iteration adds up, through the CLI."""

import json

from motionphysics.cli import main


def test_bench_fit_reports_the_split_of_an_iteration(capsys):
    rc = main(
        [
            "bench",
            "fit",
            "--particles",
            "150",
            "--grid",
            "8",
            "--frames",
            "3",
            "--substeps",
            "4",
            "--iterations",
            "1",
            "--source",
            "builtin:cube",
            "--json",
        ]
    )
    assert rc == 0
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["target"] == "fit" and r["loss"] == "trajectory_match"
    assert r["substeps"] == 4 and r["frames"] == 3
    split = r["split_s"]
    assert set(split) == {"simulate", "backward", "render", "loss", "step", "bookkeeping"}
    assert split["simulate"] > 0 and split["backward"] > 0
    # the parts are the iteration: their sum is its wall time (bookkeeping the rest)
    assert abs(sum(split.values()) - r["iteration_s"]) < 1e-6 + 1e-3 * r["iteration_s"]
    assert r["iteration_over_simulate"] > 0 and r["simulate_cpu_s"] > 0


def test_bench_fit_refuses_bad_sizes(capsys):
    assert main(["bench", "fit", "--frames", "1"]) == 2
    assert "--frames >= 2" in capsys.readouterr().err
    assert main(["bench", "fit", "--substeps", "many"]) == 2
    assert "--substeps" in capsys.readouterr().err
