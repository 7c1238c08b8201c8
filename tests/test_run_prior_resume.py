"""The prior path of ``run``: the LMD perturbation reaches the loss render only, and a
refinement killed with SIGKILL resumes (``--resume``) to the same parameters, with the
LMD extractor, its EMA and the perturbation sequence restored from the checkpoint."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from tests.priors.tiny_pipelines import tiny_dir
from tests.test_run_prior import write_config

from motionphysics.cli import main


# ---------------------------------------------------------------- the perturbation
def _renderers(tiny_assembly, eps=0.1):
    from motionphysics.losses.lmd import RenderPerturbation
    from motionphysics.optimize.refine import PerturbedRenderer

    base = tiny_assembly.renderer()
    return base, PerturbedRenderer(base, RenderPerturbation(eps, 2 * eps), seed=7)


def test_perturbation_is_scaled_to_the_scene_and_drawn_once_per_iteration(tiny_assembly):
    base, pert = _renderers(tiny_assembly)
    scene = tiny_assembly.sim_scene
    P = tiny_assembly.num_particles
    xs = scene.particles.expand(2, P, 3).clone()  # two identical frames
    Fs = torch.eye(3).expand(2, P, 3, 3).clone()
    plain = base(xs, Fs)
    rgb = pert(xs, Fs)
    # one draw per call: both frames see the same noise
    assert torch.equal(rgb[0], rgb[1])
    assert not torch.allclose(rgb, plain, atol=1e-3)  # the loss render is perturbed
    d_pos, d_sh = pert.last_noise
    side = float((scene.particles.max(0).values - scene.particles.min(0).values).max())
    assert pert.length == pytest.approx(side)
    # std of N(0, 1) draws over N splats: within 5 standard errors of the target
    n = d_pos.numel()
    assert float(d_pos.std()) == pytest.approx(0.1 * side, rel=5 / np.sqrt(2 * n))
    assert float(d_sh.std()) == pytest.approx(0.2, rel=5 / np.sqrt(2 * d_sh.numel()))
    # the scene itself is untouched: the plain render is the same after the call
    assert torch.equal(base(xs, Fs), plain)
    # a new iteration draws new noise; a restored state draws the same again
    state = pert.state_dict()
    second = pert(xs, Fs)
    assert not torch.equal(second, rgb)
    _, again = _renderers(tiny_assembly)
    again.load_state_dict(state)
    assert torch.equal(again(xs, Fs), second)


def test_gradient_flows_through_the_perturbed_render(tiny_assembly):
    _, pert = _renderers(tiny_assembly)
    P = tiny_assembly.num_particles
    xs = tiny_assembly.sim_scene.particles.expand(1, P, 3).clone().requires_grad_(True)
    Fs = torch.eye(3).expand(1, P, 3, 3).clone().requires_grad_(True)
    pert(xs, Fs).sum().backward()
    assert torch.isfinite(xs.grad).all() and xs.grad.abs().sum() > 0
    assert torch.isfinite(Fs.grad).all() and Fs.grad.abs().sum() > 0


def test_outputs_do_not_depend_on_the_perturbation(tmp_path):
    """The run's video and trajectory are the forward simulation of its final
    parameters from the unperturbed scene: ``simulate --params`` reproduces them."""
    from motionphysics.io.video import read_video

    cfg = write_config(tmp_path / "c.yaml", params=["E"])
    out = tmp_path / "run"
    rc = main(["--quiet", "run", str(cfg), "--prior", "cogvideox", "--prior-path",
               str(tiny_dir("cogvideox")), "--iters", "2", "--out", str(out)])  # fmt: skip
    assert rc == 0
    p = json.loads((out / "params.json").read_text())
    assert p["optimise"]["perturbation"]["applies_to"] == "the loss render only"
    # the same config with the refined material as its material block (a config's
    # material: block wins over --params, so the block itself is replaced)
    data = yaml.safe_load(cfg.read_text())
    data["material"] = {"class": p["class"], "density": p["density"], **p["params"]}
    (tmp_path / "final.yaml").write_text(yaml.safe_dump(data))
    fwd = tmp_path / "fwd"
    rc = main(["--quiet", "simulate", str(tmp_path / "final.yaml"), "--out", str(fwd)])
    assert rc == 0
    a, b = np.load(out / "trajectory.npz"), np.load(fwd / "trajectory.npz")
    np.testing.assert_array_equal(a["x"], b["x"])
    np.testing.assert_array_equal(read_video(out / "video.mp4"), read_video(fwd / "video.mp4"))


# ---------------------------------------------------------------------- resume
def _final(out: Path) -> tuple[dict, list]:
    from motionphysics.optimize.checkpoint import load_checkpoint

    p = json.loads((out / "params.json").read_text())
    ck = load_checkpoint(out / "checkpoint.pt")
    return p, ck.loss_states


@pytest.mark.slow
def test_sigkill_then_resume_gives_the_same_parameters_extractor_and_ema(tmp_path, monkeypatch):
    # One render band: the CPU rasteriser's band-parallel backward sums bands in an order
    # that differs at the ulp level between two fresh runs (tests/optimize/test_refine.py);
    # with one thread, killed + resumed must equal uninterrupted bit for bit.
    monkeypatch.setenv("MOTIONPHYSICS_THREADS", "1")
    iters = 5
    cfg = write_config(tmp_path / "c.yaml", params=["E"])
    prior = ["--prior", "cogvideox", "--prior-path", str(tiny_dir("cogvideox"))]
    ref = tmp_path / "ref"
    assert main(["--quiet", "run", str(cfg), *prior, "--iters", str(iters), "--out",
                 str(ref)]) == 0  # fmt: skip

    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "motionphysics", "--quiet", "run", str(cfg), *prior,
           "--iters", str(iters), "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, env=dict(os.environ), start_new_session=True)
    log = out / "log.jsonl"
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and proc.poll() is None:
        if log.is_file() and len(log.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    p = json.loads((out / "params.json").read_text())
    assert p["status"] != "complete"
    assert main(["--quiet", "run", str(cfg), *prior, "--iters", str(iters), "--out", str(out),
                 "--resume"]) == 0  # fmt: skip

    (pa, sa), (pb, sb) = _final(ref), _final(out)
    assert pa["params"] == pb["params"]
    assert [r["loss"] for r in pa["history"]] == [r["loss"] for r in pb["history"]]
    assert [r["params"] for r in pa["history"]] == [r["params"] for r in pb["history"]]
    lmd_a, lmd_b = sa[0], sb[0]
    assert lmd_a["steps"] == lmd_b["steps"] == iters
    for part in ("extractor", "ema"):
        for k, v in lmd_a[part].items():
            assert torch.equal(v, lmd_b[part][k]), (part, k)
    assert sa[1] == sb[1] == {"perturbation_calls": iters}
    np.testing.assert_array_equal(
        np.load(ref / "trajectory.npz")["x"], np.load(out / "trajectory.npz")["x"]
    )
