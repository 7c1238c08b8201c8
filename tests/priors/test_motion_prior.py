"""The motion prior behind the one prior interface: it observes the simulated states, the
losses run on it unchanged, training is resumable and deterministic, and its measures."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from motion_helpers import K, clip, write_shards

from motionphysics.errors import UserInputError
from motionphysics.losses.base import LossContext, Prediction
from motionphysics.losses.lmd import LmdLoss
from motionphysics.losses.sds import SdsLoss
from motionphysics.priors import PRIORS
from motionphysics.priors.base import SceneContext
from motionphysics.priors.motion import MotionDenoiser, MotionPrior, net_config
from motionphysics.priors.motion_features import NUM_FEATURES
from motionphysics.priors.motion_text import MotionText
from motionphysics.priors.motion_train import (
    MotionTrainOptions,
    discrimination,
    feature_classifier,
    prepare,
    prior_from_checkpoint,
    train,
)

GROUPS3 = ["bounces_high", "splashes", "keeps_shape"] * 4


def _prior(seed: int = 0) -> MotionPrior:
    torch.manual_seed(seed)
    net = MotionDenoiser(**net_config("test"))
    for p in net.out.parameters():  # a non-zero output, so the guided difference is not 0
        torch.nn.init.normal_(p, std=0.3)
    return MotionPrior(
        net,
        mean=torch.zeros(NUM_FEATURES),
        std=torch.ones(NUM_FEATURES),
        text=MotionText.default().config(),
    )


def _scene_and_prediction(rng_seed: int = 0):
    x, F, t = clip("splashes", np.random.default_rng(rng_seed))
    scene = SceneContext(
        rest=torch.from_numpy(x[0]), ground=0.0, gravity=(0.0, 0.0, -9.8), frame_dt=0.05
    )
    frames = (3, 7, 11, 15)
    xs = torch.from_numpy(x[list(frames)]).requires_grad_()
    Fs = torch.from_numpy(F[list(frames)]).requires_grad_()
    return scene, Prediction(frame_indices=frames, xs=xs, Fs=Fs)


def test_the_motion_prior_is_registered_and_observes_states():
    assert PRIORS.get("motion") is MotionPrior
    assert MotionPrior.observes == "states"
    prior = _prior()
    with pytest.raises(UserInputError, match="observes the simulated states"):
        prior.encode(torch.zeros(4, 8, 8, 3))
    scene, pred = _scene_and_prediction()
    prior.set_scene(scene)
    z = prior.encode_states(pred.xs, pred.Fs, pred.frame_indices)
    assert tuple(z.shape) == prior.latent_shape() == (1, 16, NUM_FEATURES, 1, 1)


@pytest.mark.parametrize("loss_cls", [LmdLoss, SdsLoss])
def test_lmd_and_sds_run_unchanged_on_the_states_and_need_no_render(loss_cls):
    prior = _prior()
    scene, pred = _scene_and_prediction()
    prior.set_scene(scene)
    loss = loss_cls(prior, "a rubber ball bounces high")
    assert loss.needs_render is False and loss.needs_states is True
    ctx = LossContext(iteration=0, num_frames=16, rng=torch.Generator().manual_seed(0))
    value = loss(pred, ctx)
    assert torch.isfinite(value)
    value.backward()
    for g in (pred.xs.grad, pred.Fs.grad):
        assert g is not None and torch.isfinite(g).all() and g.abs().sum() > 0


def test_appearance_cannot_change_the_loss():
    """The loss reads only the states: any rendered frames beside them (another colour)
    leave it bit-identical, with the same generator state."""
    prior = _prior()
    scene, pred = _scene_and_prediction()
    prior.set_scene(scene)
    out = []
    for colour in (0.1, 0.9):
        loss = LmdLoss(prior, "a ball splashes")
        rgb = torch.full((4, 8, 8, 3), colour)
        p = Prediction(frame_indices=pred.frame_indices, xs=pred.xs, Fs=pred.Fs, rgb=rgb)
        ctx = LossContext(iteration=0, num_frames=16, rng=torch.Generator().manual_seed(3))
        out.append(loss(p, ctx).detach())
    assert torch.equal(out[0], out[1])


def test_pixel_losses_refuse_a_states_prior():
    from motionphysics.losses.flow import FlowLoss

    prior = _prior()
    with pytest.raises(UserInputError, match="observes simulated states"):
        FlowLoss(prior, "a ball", FlowLoss.Options())


def test_lmd_perturbs_the_observed_geometry_for_a_states_prior():
    prior = _prior()
    scene, pred = _scene_and_prediction()
    prior.set_scene(scene)
    loss = LmdLoss(prior, "a ball splashes", LmdLoss.Options(perturbation=0.05))
    g = torch.Generator().manual_seed(0)
    off = loss._state_offset(LossContext(iteration=0, num_frames=16, rng=g))
    assert off.shape == (K, 3)
    size = float((scene.rest.max(0).values - scene.rest.min(0).values).max())
    assert 0.02 * size < float(off.std()) < 0.08 * size
    none = LmdLoss(prior, "a ball splashes", LmdLoss.Options(perturbation=0.0))
    assert none._state_offset(LossContext(iteration=0, num_frames=16, rng=g)) is None


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_shards(tmp_path_factory.mktemp("motion-data"), GROUPS3)


def _opts(**kw):
    base = dict(batch=4, size="test", log_every=1, save_every=2, warmup=2, threads=1)
    return MotionTrainOptions(**{**base, **kw})


def test_training_resumes_to_the_same_weights(data, tmp_path):
    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    logs: list[str] = []
    train(data, a, _opts(max_steps=4), log=logs.append)
    train(data, b, _opts(max_steps=2), log=logs.append)
    train(data, b, _opts(max_steps=4), resume=True, log=logs.append)
    ka = torch.load(a, weights_only=False)
    kb = torch.load(b, weights_only=False)
    assert ka["state"]["step"] == kb["state"]["step"] == 4
    for name in ka["ema"]:
        assert torch.equal(ka["ema"][name], kb["ema"][name]), name
        assert torch.equal(ka["model"][name], kb["model"][name]), name
    with pytest.raises(UserInputError, match="exists"):
        train(data, a, _opts(max_steps=5), log=logs.append)


def test_a_checkpoint_loads_as_the_prior_and_is_measured(data, tmp_path):
    ck = tmp_path / "m.pt"
    train(data, ck, _opts(max_steps=3), log=lambda _: None)
    prior = MotionPrior.from_pretrained(str(ck))
    assert prior.meta["steps"] == 3
    ds = prepare(data)
    assert ds["features"].shape == (len(GROUPS3), 5, 16, NUM_FEATURES)
    res = discrimination(prior, ds, timesteps=(300,), noise_draws=1)
    assert res["clips"] == len(GROUPS3) and 0.0 <= res["accuracy"] <= 1.0
    assert sum(res["per_group"].values()) == len(GROUPS3)
    # the features separate these hand-made motions without any text
    fc = feature_classifier(ds, ds, steps=200)
    assert fc["accuracy"] == 1.0
    same = prior_from_checkpoint(ck)
    for k, v in prior.net.state_dict().items():
        assert torch.equal(v, same.net.state_dict()[k])


def test_weights_that_are_not_a_motion_prior_are_a_user_error(tmp_path):
    bad = tmp_path / "x.pt"
    torch.save({"config": {}, "ema": {}}, bad)
    with pytest.raises(UserInputError, match="not a motion prior"):
        MotionPrior.from_pretrained(str(bad))
    with pytest.raises(UserInputError, match="not found"):
        MotionPrior.from_pretrained(str(tmp_path / "missing.pt"))


def test_prior_cli_trains_and_exports(data, tmp_path, capsys):
    from motionphysics.cli import main

    ck = tmp_path / "c.pt"
    assert main(["--quiet", "prior", "train", str(data), "--out", str(ck), "--steps", "2",
                 "--batch", "4", "--threads", "1", "--sentence-dropout", "0.25",
                 "--subject-swap", "0.5"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["step"] == 2
    saved = torch.load(ck, weights_only=True)
    assert saved["meta"]["options"]["sentence_dropout"] == 0.25
    assert saved["meta"]["options"]["subject_swap"] == 0.5
    # the checkpoint reads prompts the way it was trained: its anchors travel with it
    assert saved["config"]["text"] == MotionText.default().config()
    dst = tmp_path / "w.pt"
    assert main(["prior", "export", str(ck), str(dst)]) == 0
    w = torch.load(dst, weights_only=True)
    assert w["kind"] == "motion" and "opt" not in w
    MotionPrior.from_pretrained(str(dst))
