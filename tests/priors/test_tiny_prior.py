"""TinyPrior satisfies the VideoPrior interface (layouts, differentiable encode, guidance,
sampling) and loads checkpoints written by the trainer; errors are user errors."""

from __future__ import annotations

import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.priors import PRIORS, load_prior
from motionphysics.priors.tiny import TinyPrior, TinyVideoUNet, model_config


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    """A seeded random tiny network saved in the trainer's on-disk layout."""
    torch.manual_seed(0)
    cfg = {"net": model_config("test"), "num_frames": 8, "height": 16, "width": 16,
           "max_tokens": 24}  # fmt: skip
    net = TinyVideoUNet(**cfg["net"])
    for p in net.parameters():  # non-zero output layers, so the text changes the output
        torch.nn.init.normal_(p, std=0.05)
    path = tmp_path_factory.mktemp("tiny") / "tiny_prior.pt"
    torch.save({"config": cfg, "ema": net.state_dict(), "meta": {"steps": 0}}, path)
    return path


@pytest.fixture(scope="module")
def prior(tiny_ckpt):
    return load_prior("tiny", str(tiny_ckpt))


def test_registry_resolves_tiny():
    assert PRIORS.get("tiny") is TinyPrior


def test_attributes_and_schedule(prior):
    assert prior.prediction_type == "epsilon"
    assert (prior.num_frames, prior.height, prior.width) == (8, 16, 16)
    ac = prior.alphas_cumprod
    assert ac.shape == (1000,) and ac.dtype == torch.float32
    assert bool((ac[1:] < ac[:-1]).all()) and 0.004 < float(ac[-1]) < 0.006


def test_encode_layout_inverse_and_gradient(prior):
    frames = torch.rand(8, 16, 16, 3, dtype=torch.float32)
    z = prior.encode(frames)
    assert z.shape == (1, 8, 3, 16, 16)
    assert torch.allclose(prior.decode(z), frames, atol=1e-6)  # same size: exact inverse
    assert float(z.min()) >= -1 and float(z.max()) <= 1
    # resampling: 12 frames at 24 x 20 -> 8 x 16 x 16, differentiable
    src = torch.rand(12, 24, 20, 3, requires_grad=True)
    w = torch.randn(1, 8, 3, 16, 16)
    (prior.encode(src) * w).sum().backward()
    g = src.grad
    assert g is not None and float(g.abs().sum()) > 0
    # central finite differences on a few entries (encode is linear: exact up to rounding)
    with torch.no_grad():
        for idx in [(0, 0, 0, 0), (5, 7, 3, 1), (11, 23, 19, 2)]:
            e = torch.zeros_like(src)
            e[idx] = 1e-2
            fd = ((prior.encode(src + e) * w).sum() - (prior.encode(src - e) * w).sum()) / 2e-2
            assert abs(float(fd) - float(g[idx])) < 1e-3 * max(1.0, abs(float(g[idx])))
    # time resampling keeps the first and last frames
    const = torch.stack([torch.full((24, 20, 3), i / 11.0) for i in range(12)])
    zc = prior.encode(const)
    assert torch.allclose(zc[0, 0], torch.full_like(zc[0, 0], -1.0), atol=1e-5)
    assert torch.allclose(zc[0, -1], torch.full_like(zc[0, -1], 1.0), atol=1e-5)


def test_bad_frames_shape_is_rejected(prior):
    with pytest.raises(ValueError, match=r"\[T, H, W, 3\]"):
        prior.encode(torch.rand(8, 3, 16, 16))


def test_text_tokens_and_guided_prediction(prior):
    text = prior.set_prompt("a rubber ball bounces high")
    assert text.cond.shape == text.uncond.shape == (1, 24, 384)
    assert float(text.cond.abs().sum()) > 0
    # padding rows are zero; real tokens are unit length
    norms = text.cond[0].norm(dim=-1)
    assert bool(((norms - 1).abs() < 1e-4).logical_or(norms == 0).all())
    z0 = prior.encode(torch.rand(8, 16, 16, 3))
    noise = torch.randn_like(z0)
    t = torch.tensor([400])
    zt = prior.add_noise(z0, noise, t)
    p1 = prior.predict(zt, t, guidance=1.0)
    p5 = prior.predict(zt, t, guidance=5.0)
    for field in ("x0", "eps", "eps_cond", "eps_uncond"):
        assert getattr(p1, field).shape == z0.shape
    assert torch.allclose(p1.eps, p1.eps_cond, atol=1e-6)  # g = 1 is the conditional
    assert not torch.allclose(p1.eps_cond, p1.eps_uncond)  # the text matters
    assert torch.allclose(p5.eps, p5.eps_uncond + 5 * (p5.eps_cond - p5.eps_uncond), atol=1e-5)
    a = prior.alphas_cumprod[400]
    assert torch.allclose(a.sqrt() * p5.x0 + (1 - a).sqrt() * p5.eps, zt, atol=1e-4)


def test_model_output_carries_gradients_to_the_input(prior):
    text = prior.set_prompt("a clay cube squashes and stays flat")
    z = torch.randn(1, 8, 3, 16, 16, requires_grad=True)
    out = prior.model_output(z, torch.tensor([100]), text.cond)
    out.square().sum().backward()
    assert z.grad is not None and float(z.grad.abs().sum()) > 0
    assert all(p.grad is None for p in prior.net.parameters())  # the network stays frozen


def test_sample_runs(prior):
    prior.set_prompt("water splashes and spreads")
    clip = prior.sample(steps=3, guidance=3.0, generator=torch.Generator().manual_seed(0))
    assert clip.shape == (8, 16, 16, 3)
    assert float(clip.min()) >= 0 and float(clip.max()) <= 1 and torch.isfinite(clip).all()


def test_missing_or_bad_weights_are_user_errors(tmp_path):
    with pytest.raises(UserInputError, match="not found"):
        TinyPrior.from_pretrained(str(tmp_path / "nope.pt"))
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(UserInputError, match="not a tiny prior checkpoint"):
        TinyPrior.from_pretrained(str(bad))
    torch.save({"foo": 1}, tmp_path / "other.pt")
    with pytest.raises(UserInputError, match="not a tiny prior checkpoint"):
        TinyPrior.from_pretrained(str(tmp_path / "other.pt"))


def test_unknown_option_is_a_user_error(tiny_ckpt):
    with pytest.raises(UserInputError, match="unknown option"):
        TinyPrior.from_pretrained(str(tiny_ckpt), guidance=3)


def test_directory_path_loads_its_checkpoint(tiny_ckpt):
    p = TinyPrior.from_pretrained(str(tiny_ckpt.parent))
    assert p.num_frames == 8
