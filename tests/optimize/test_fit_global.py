"""The fit's global stage and horizon curriculum: on the spring chain (a real tiny
differentiable simulator, brute-force twin of the scan) and, end to end through
``run_fit``, a non-spherical MPM drop recovered from a start 10x off."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from motionphysics.config import OptimizeConfig
from motionphysics.losses import get_loss
from motionphysics.optimize import optimize
from motionphysics.optimize.fit import global_search
from motionphysics.optimize.loop import horizon
from motionphysics.optimize.sysid import RECOVERIES, run_recovery

sys.path.insert(0, str(Path(__file__).parent))
from springchain import RANGES, TRUE, SpringChain, make_problem, reference  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_horizon_grows_from_a_quarter_to_all_frames():
    assert [horizon(i, 8, 24, 0.5) for i in range(8)] == [7, 11, 15, 19, 24, 24, 24, 24]
    assert all(horizon(i, 10, 24, 0.0) == 24 for i in range(10))
    # never fewer than 2 frames (frame 0 is the initial state, 1 the first supervised)
    assert horizon(0, 10, 3, 1.0) == 2
    assert horizon(9, 10, 3, 1.0) == 2 and horizon(10, 10, 3, 1.0) == 3


def _chain_problem(start_k):
    chain = SpringChain()
    loss = get_loss("trajectory_match")(reference(chain))
    return chain, make_problem(
        loss, start={"k": start_k, "c": TRUE["c"]}, names=("k",), chain=chain
    )


def test_global_scan_is_the_brute_force_minimum_of_its_grid(tmp_path):
    chain, problem = _chain_problem(900.0)  # far from the true k = 40 N/m, near the top
    opt = OptimizeConfig(
        loss="trajectory_match", global_points=9, global_refine=4, global_patience=0
    )
    found = global_search(problem, opt, tmp_path / "log.jsonl")
    recs = found.records
    assert len(recs) == 1 + 9 + 4
    log = [json.loads(x) for x in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [r["candidate"] for r in log] == list(range(14))
    assert all(r["stage"] == "global" for r in log) and log[-1]["iteration"] == -1
    assert log[0]["params"]["k"] == pytest.approx(900.0, rel=1e-5)
    # round 1: the centres of 9 equal strata of log k over the range
    lo, hi = RANGES["k"]
    want = [lo * (hi / lo) ** ((i + 0.5) / 9) for i in range(9)]
    # (theta is float32: the chain's k comes back within ~1e-3)
    assert [r["params"]["k"] for r in recs[1:10]] == pytest.approx(want, rel=2e-3)
    # each candidate's loss is the loss of an independent forward at its k (brute force)
    for r in recs[1:10]:
        xs = reference(chain, {"k": r["params"]["k"], "c": TRUE["c"]})
        brute = float(((xs[1:] - reference(chain)[1:]) ** 2).sum(-1).mean())
        assert r["loss"] == pytest.approx(brute, rel=1e-6)  # float32 loss
    best = min(range(14), key=lambda i: recs[i]["loss"])
    assert found.best == best and found.initial["k"] == pytest.approx(recs[best]["params"]["k"])
    # the true k lies within one grid spacing (a factor 10^(3/9)) of the best candidate
    assert abs(math.log(found.initial["k"] / TRUE["k"])) < math.log(hi / lo) / 9


def test_global_then_gradient_recovers_from_either_end(tmp_path):
    for start in (RANGES["k"][0] * 1.01, RANGES["k"][1] * 0.99):
        _chain, problem = _chain_problem(start)
        opt = OptimizeConfig(loss="trajectory_match", iterations=12, boost=2, lr=0.05)
        found = global_search(problem, opt)
        problem.initial = {**problem.initial, **found.initial}
        res = optimize(problem, opt, tmp_path / f"{start:.0f}", curriculum=0.25)
        assert res.params["k"] == pytest.approx(TRUE["k"], rel=0.05), start


def test_patience_stops_an_ascending_scan_past_the_minimum():
    _chain, problem = _chain_problem(1.5)
    opt = OptimizeConfig(loss="trajectory_match", global_points=12, global_refine=0)
    recs = global_search(problem, opt).records
    ks = [r["params"]["k"] for r in recs[1:]]
    assert len(ks) < 12 and ks == sorted(ks)
    best = min(r["loss"] for r in recs)
    assert all(r["loss"] > 10 * best for r in recs[-3:])


def test_fit_recovers_physical_E_from_10x_off_on_a_cube(tmp_path):
    # The hidden-test path at the smallest size: simulate the truth, then
    # run_fit (global + gradient stage, substeps auto) from 10x the true E; judged on
    # the physical E in params.json.
    (r,) = run_recovery("elastic_cube_frictional", tmp_path, size="tiny", starts=("x10",))
    assert r["ok"], r
    assert r["start_value"] == pytest.approx(10 * RECOVERIES["elastic_cube_frictional"].true["E"])
    params = json.loads((tmp_path / "fit_x10" / "params.json").read_text())
    assert params["fit"]["global"]["candidates"] >= 2
    stages = [h["stage"] for h in params["history"]]
    assert stages[0] == "global" and stages[-1] == "gradient"
    assert np.isfinite(r["seconds"])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RECOVERIES))
def test_recovery_table_full_size(name, tmp_path):
    for r in run_recovery(name, tmp_path, size="full"):
        assert r["ok"], r
