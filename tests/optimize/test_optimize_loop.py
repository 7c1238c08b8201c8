"""The optimisation loop on a real tiny differentiable simulator (a damped spring chain,
``springchain.py``): gradients, recovery, logging, NaN stop, convergence, resume."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from motionphysics.config import OptimizeConfig
from motionphysics.errors import UserInputError
from motionphysics.losses import get_loss
from motionphysics.optimize import optimize
from motionphysics.optimize.checkpoint import load_checkpoint

sys.path.insert(0, str(Path(__file__).parent))
from springchain import TRUE, SpringChain, blob_camera, make_problem, reference  # noqa: E402

HERE = Path(__file__).parent


@pytest.fixture(autouse=True)
def _one_thread():
    # The chain's tensors are tiny: torch's thread pool only adds contention.
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _loss_of(chain, problem, theta, frames, grad_mode, window=1):
    pred = problem.forward(theta, frames, grad_mode, window, {})
    return problem.loss(pred, None)


def test_full_gradient_matches_finite_differences():
    chain = SpringChain(num_frames=6)
    loss = get_loss("trajectory_match")(reference(chain))
    problem = make_problem(loss, chain=chain)
    theta = problem.initial_theta()
    frames = (2, 5)
    _loss_of(chain, problem, theta, frames, "full").backward()
    for name in ("k", "c"):
        h = 1e-3
        vals = []
        for s in (1, -1):
            t = {n: v.detach().clone() for n, v in theta.items()}
            t[name] = t[name] + s * h
            with torch.no_grad():
                vals.append(float(_loss_of(chain, problem, t, frames, "full")))
        fd = (vals[0] - vals[1]) / (2 * h)
        # float32 positions: central differences with h=1e-3 agree to ~1 % here.
        assert float(theta[name].grad) == pytest.approx(fd, rel=0.02), name


def test_grad_modes_differ_and_window_covering_all_equals_full():
    chain = SpringChain(num_frames=4)
    problem = make_problem(get_loss("trajectory_match")(reference(chain)), chain=chain)
    grads = {}
    for mode, window in (("full", 1), ("window", 10_000), ("last_substep", 1)):
        theta = problem.initial_theta()
        _loss_of(chain, problem, theta, (1, 3), mode, window).backward()
        grads[mode] = torch.stack([theta["k"].grad, theta["c"].grad])
    # Same operations in the same order: equal up to float32 rounding of recomputation.
    torch.testing.assert_close(grads["window"], grads["full"], rtol=1e-5, atol=1e-9)
    assert not torch.allclose(grads["last_substep"], grads["full"], rtol=0.1)


def test_recovers_stiffness_and_damping_from_a_factor_5(tmp_path):
    chain = SpringChain()
    loss = get_loss("trajectory_match")(reference(chain))
    cfg = OptimizeConfig(loss="trajectory_match", iterations=80, boost=4, lr=0.1, seed=0)
    res = optimize(make_problem(loss, chain=chain), cfg, tmp_path)
    # The chain's trajectory determines k and c well; 80 Adam steps from a factor 5
    # land within a few per cent (measured: k 0.5 %, c 5 %).
    assert res.params["k"] == pytest.approx(TRUE["k"], rel=0.05)
    assert res.params["c"] == pytest.approx(TRUE["c"], rel=0.15)
    lines = [json.loads(x) for x in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert len(lines) == res.iterations == 80
    rec = lines[5]
    assert rec["iteration"] == 5 and rec["frames"] == [2, 6, 10, 14]
    assert set(rec["params"]) == {"k", "c"} and set(rec["grad_norm"]) == {"k", "c", "total"}
    assert set(rec["time"]) >= {"simulate", "render", "loss", "backward", "total"}
    assert lines[-1]["loss"] < 0.02 * lines[0]["loss"]
    ck = load_checkpoint(tmp_path / "checkpoint.pt")
    assert ck.next_iteration == 80 and ck.stop_reason == "iterations"
    torch.testing.assert_close(ck.theta["k"], res.theta["k"])


def test_recovers_stiffness_from_video(tmp_path):
    chain = SpringChain(num_frames=10)
    cam = blob_camera()
    with torch.no_grad():
        ref_frames = cam(reference(chain), None)
    loss = get_loss("video_match")(ref_frames)
    problem = make_problem(loss, names=("k",), chain=chain, renderer=cam)
    cfg = OptimizeConfig(loss="video_match", iterations=40, boost=3, lr=0.1, seed=0)
    res = optimize(problem, cfg, tmp_path)
    # Pixels of 24x24 blobs pin k less tightly than positions do.
    assert res.params["k"] == pytest.approx(TRUE["k"], rel=0.1)


def test_optimises_initial_velocity_and_per_particle_fields(tmp_path):
    chain = SpringChain(num_frames=8)
    loss = get_loss("trajectory_match")(reference(chain))
    problem = make_problem(
        loss, names=("k",), start={"k": TRUE["k"]}, chain=chain, per_particle=("k",)
    )
    problem.initial_velocity = (0.2, 0.1, 0.0)
    cfg = OptimizeConfig(
        loss="trajectory_match", iterations=80, boost=2, lr=0.05, seed=0, lr_per_param={"k": 1e-6}
    )
    res = optimize(problem, cfg, tmp_path)
    assert res.theta["k"].shape == (chain.num_particles,)
    assert set(res.params["k"]) == {"mean", "min", "max"}
    # k's rate is negligible, so only the velocity moves: back to the true (0.6, 0, 0).
    assert res.params["k"]["max"] == pytest.approx(TRUE["k"], rel=1e-3)
    v = res.params["initial_velocity"]
    assert v == pytest.approx([0.6, 0.0, 0.0], abs=0.03)
    with pytest.raises(UserInputError, match="lr_per_param: E not optimised"):
        optimize(problem, cfg.model_copy(update={"lr_per_param": {"E": 0.1}}), tmp_path)


def test_stops_cleanly_on_nan(tmp_path):
    chain = SpringChain(num_frames=6)
    loss = get_loss("trajectory_match")(reference(chain))
    # Starting too soft, an absurd rate makes k jump by e^20 in one step: explicit Euler
    # blows up at the next iteration.
    cfg = OptimizeConfig(loss="trajectory_match", iterations=10, boost=1, lr=20.0, warmup=0, seed=0)
    problem = make_problem(loss, chain=chain, start={"k": TRUE["k"] / 5, "c": TRUE["c"]})
    res = optimize(problem, cfg, tmp_path)
    assert res.stop_reason == "nan"
    assert "not finite" in res.message and "iteration 1" in res.message
    assert res.iterations == 1
    assert torch.isfinite(res.theta["k"]) and res.params["k"] > 1e3
    lines = [json.loads(x) for x in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert lines[-1]["stopped"] == "nan" and lines[-1]["loss"] is None


def test_stops_early_on_convergence(tmp_path):
    chain = SpringChain(num_frames=4)
    loss = get_loss("trajectory_match")(reference(chain))
    cfg = OptimizeConfig(
        loss="trajectory_match", iterations=50, boost=1, lr=1e-4, warmup=1, tolerance=1e-3, seed=0
    )
    res = optimize(make_problem(loss, chain=chain), cfg, tmp_path)
    assert res.stop_reason == "converged" and res.iterations == 4  # warm-up 1, then 3 calm


def _interrupt_after(n):
    def cb(rec):
        if rec["iteration"] == n - 1:
            raise KeyboardInterrupt

    return cb


def test_resume_in_process_reproduces_uninterrupted(tmp_path):
    chain = SpringChain(num_frames=6)
    loss = get_loss("trajectory_match")(reference(chain))
    cfg = OptimizeConfig(loss="trajectory_match", iterations=12, boost=3, lr=0.1, seed=1)
    full = optimize(make_problem(loss, chain=chain), cfg, tmp_path / "a")
    with pytest.raises(KeyboardInterrupt):
        optimize(make_problem(loss, chain=chain), cfg, tmp_path / "b", progress=_interrupt_after(5))
    # A torn extra log line (killed between log append and checkpoint) is dropped on resume.
    with open(tmp_path / "b" / "log.jsonl", "a") as fh:
        fh.write('{"iteration": 5, "loss": 1.0}\n{"iter')
    resumed = optimize(make_problem(loss, chain=chain), cfg, tmp_path / "b", resume=True)
    for n in ("k", "c"):
        assert torch.equal(resumed.theta[n], full.theta[n])
    a = (tmp_path / "a" / "log.jsonl").read_text().splitlines()
    b = (tmp_path / "b" / "log.jsonl").read_text().splitlines()
    assert [json.loads(x)["loss"] for x in a] == [json.loads(x)["loss"] for x in b]
    with pytest.raises(UserInputError, match="different config"):
        optimize(
            make_problem(loss, chain=chain),
            cfg,
            tmp_path / "b",
            resume=True,
            fingerprint="other",
            iterations=20,
        )


def test_sigkill_and_resume_gives_the_same_parameters(tmp_path):
    script = HERE / "springchain.py"
    env = {**os.environ, "PYTHONPATH": str(HERE.parents[1] / "src")}
    ref_dir, run_dir = tmp_path / "ref", tmp_path / "run"
    iters = 16
    subprocess.run(
        [sys.executable, str(script), str(ref_dir), str(iters)], check=True, env=env, timeout=300
    )
    proc = subprocess.Popen([sys.executable, str(script), str(run_dir), str(iters)], env=env)
    log = run_dir / "log.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if log.exists() and len(log.read_text().splitlines()) >= 4:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the run finished before it could be killed; make it longer"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = len(log.read_text().splitlines())
    assert 4 <= done < iters
    subprocess.run(
        [sys.executable, str(script), str(run_dir), str(iters), "--resume"],
        check=True,
        env=env,
        timeout=300,
    )
    a = torch.load(ref_dir / "final_theta.pt")
    b = torch.load(run_dir / "final_theta.pt")
    for n in a:
        # Same float ops in the same order after restoring theta, Adam state and RNG.
        assert torch.equal(a[n], b[n]), n
    assert len(log.read_text().splitlines()) == iters
