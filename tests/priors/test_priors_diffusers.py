"""CogVideoX and ModelScope priors on tiny seeded random pipelines written with
``save_pretrained`` and loaded through the real loading code; twins are diffusers' own
pipelines and schedulers."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

pytest.importorskip("diffusers")
pytest.importorskip("sentencepiece")

from tiny_pipelines import load_tiny, tiny_dir  # noqa: E402

from motionphysics.errors import UserInputError  # noqa: E402
from motionphysics.priors import load_prior  # noqa: E402
from motionphysics.priors.base import resample_frames  # noqa: E402
from motionphysics.priors.loading import resolve_dtype  # noqa: E402

KINDS = ["cogvideox", "cogvideox-rope", "cogvideox-eps", "modelscope"]


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def priors():
    cache = {}

    def get(kind, **options):
        key = (kind, tuple(sorted(options.items())))
        if key not in cache:
            cache[key] = load_tiny(kind, **options)
        return cache[key]

    return get


def _frames(t=9, h=16, w=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(t, h, w, 3, generator=g)


# --- loading ------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
def test_load_reads_configs(kind, priors):
    p = priors(kind)
    root = tiny_dir(kind)
    sched = json.loads((root / "scheduler" / "scheduler_config.json").read_text())
    vae = json.loads((root / "vae" / "config.json").read_text())
    assert p.prediction_type == sched["prediction_type"]
    assert p.scaling_factor == pytest.approx(vae["scaling_factor"])
    assert p.dtype == torch.float32 and p.device.type == "cpu"
    assert p.alphas_cumprod.shape == (1000,)
    z = p.encode(_frames(p.num_frames))
    assert tuple(z.shape) == p.latent_shape()


@pytest.mark.parametrize("kind", ["cogvideox", "cogvideox-rope"])
def test_cogvideox_text_matches_pipeline_and_encoder_is_released(kind):
    from diffusers import CogVideoXPipeline

    p = load_tiny(kind)
    text = p.set_prompt("a rubber ball bounces on the floor")
    assert p.text_encoder is None and p.tokenizer is None  # released after encoding
    assert text.cond.shape == (1, 16, 32)  # max_text_seq_length of the transformer config
    pipe = CogVideoXPipeline.from_pretrained(tiny_dir(kind))
    pos, neg = pipe.encode_prompt(
        "a rubber ball bounces on the floor",
        negative_prompt="",
        max_sequence_length=16,
        device="cpu",
    )
    torch.testing.assert_close(text.cond, pos, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(text.uncond, neg, rtol=1e-5, atol=1e-5)
    # a new prompt reloads the encoder from the directory
    other = p.set_prompt("sand flows down")
    assert not torch.equal(other.cond, text.cond)


def test_modelscope_text_matches_pipeline():
    from diffusers import TextToVideoSDPipeline

    p = load_tiny("modelscope")
    text = p.set_prompt("honey drips slowly")
    pipe = TextToVideoSDPipeline.from_pretrained(tiny_dir("modelscope"))
    pos, neg = pipe.encode_prompt("honey drips slowly", "cpu", 1, True, negative_prompt="")
    torch.testing.assert_close(text.cond, pos, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(text.uncond, neg, rtol=1e-5, atol=1e-5)


def test_cogvideox_encode_decode_pipeline_layout(priors):
    p = load_tiny("cogvideox", posterior="mode")
    fr = _frames(9)
    z = p.encode(fr)
    video = (fr * 2 - 1).permute(3, 0, 1, 2).unsqueeze(0)  # [1, 3, F, H, W]
    ref = p.vae.encode(video).latent_dist.mode() * p.vae.config.scaling_factor
    torch.testing.assert_close(z, ref.permute(0, 2, 1, 3, 4))
    assert z.shape == (1, 3, 4, 2, 2)
    out = p.decode(z)
    assert out.shape == (9, 16, 16, 3)


def test_modelscope_encode_per_frame(priors):
    p = load_tiny("modelscope", posterior="mode")
    fr = _frames(4)
    z = p.encode(fr)
    ref = p.vae.encode(fr.permute(0, 3, 1, 2) * 2 - 1).latent_dist.mode() * 0.18215
    torch.testing.assert_close(z[0], ref)
    assert p.decode(z).shape == (4, 16, 16, 3)


def test_encode_resamples_and_is_differentiable(priors):
    p = priors("cogvideox")
    fr = _frames(5, 20, 12).requires_grad_(True)
    z = p.encode(fr, generator=torch.Generator().manual_seed(0))
    assert tuple(z.shape) == p.latent_shape()
    z.sum().backward()
    assert torch.isfinite(fr.grad).all() and fr.grad.abs().sum() > 0


def test_posterior_sample_uses_generator(priors):
    p = priors("modelscope")
    fr = _frames(4)
    a = p.encode(fr, generator=torch.Generator().manual_seed(3))
    b = p.encode(fr, generator=torch.Generator().manual_seed(3))
    c = p.encode(fr, generator=torch.Generator().manual_seed(4))
    assert torch.equal(a, b) and not torch.equal(a, c)


# --- x̂0 / ε̂ against the schedulers ---------------------------------------------------------
@pytest.mark.parametrize("kind", ["cogvideox", "cogvideox-eps", "modelscope"])
def test_x0_eps_match_scheduler_step(kind, priors):
    from diffusers import DDIMScheduler

    p = priors(kind)
    # The priors never clip x̂0 (it is a latent); diffusers' DDIM default clips to [-1, 1].
    sched = type(p.scheduler).from_config(p.scheduler.config, clip_sample=False)
    sched.set_timesteps(50)
    g = torch.Generator().manual_seed(1)
    shape = p.latent_shape()
    for t in sched.timesteps[[0, 10, 25, 49]]:
        x = torch.randn(shape, generator=g)
        out = torch.randn(shape, generator=g)
        tt = torch.tensor([int(t)])
        x0, eps = p.to_x0_eps(out, x, tt)
        ref = sched.step(out, int(t), x).pred_original_sample
        torch.testing.assert_close(x0, ref.float(), rtol=1e-5, atol=1e-5)
        # ε̂ through a plain DDIM step (η = 0) on the same ᾱ:
        # prev = √ᾱ_prev x̂0 + √(1−ᾱ_prev) ε̂
        ddim = DDIMScheduler(
            prediction_type=p.prediction_type, set_alpha_to_one=True, clip_sample=False
        )
        ddim.alphas_cumprod = p.alphas_cumprod.double().clone()
        ddim.set_timesteps(50)
        prev_t = int(t) - 1000 // 50
        a_prev = ddim.alphas_cumprod[prev_t] if prev_t >= 0 else torch.tensor(1.0)
        step = ddim.step(out, int(t), x)
        torch.testing.assert_close(
            step.prev_sample.float(),
            (a_prev.sqrt() * x0 + (1 - a_prev).sqrt() * eps).float(),
            rtol=1e-4,
            atol=1e-5,
        )
        # and the forward process is recovered: x_t = √ᾱ x̂0 + √(1−ᾱ) ε̂
        a = p.alphas_cumprod[int(t)]
        torch.testing.assert_close(a.sqrt() * x0 + (1 - a).sqrt() * eps, x, rtol=1e-4, atol=1e-5)


def test_v_prediction_is_finite_at_zero_snr(priors):
    p = priors("cogvideox")
    assert float(p.alphas_cumprod[999]) < 1e-6  # zero terminal SNR
    x, v = torch.randn(p.latent_shape()), torch.randn(p.latent_shape())
    x0, eps = p.to_x0_eps(v, x, torch.tensor([999]))
    torch.testing.assert_close(x0, -v, atol=1e-3, rtol=0)
    torch.testing.assert_close(eps, x, atol=1e-3, rtol=0)


@pytest.mark.parametrize("kind", ["cogvideox", "cogvideox-rope", "modelscope"])
def test_cfg_matches_pipeline_formula(kind, priors):
    p = priors(kind)
    p.set_prompt("a plush toy squashes")
    g = torch.Generator().manual_seed(2)
    z = torch.randn(p.latent_shape(), generator=g)
    t = torch.tensor([400])
    w = 7.5
    pred = p.predict(z, t, w)
    with torch.no_grad():
        out_u = p.model_output(z, t, p.text.uncond)
        out_c = p.model_output(z, t, p.text.cond)
    out = out_u + w * (out_c - out_u)
    x0, eps = p.to_x0_eps(out, z, t)
    torch.testing.assert_close(pred.x0, x0, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(pred.eps, eps, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(
        pred.x0 - pred.x0_uncond, w * (pred.x0_cond - pred.x0_uncond), rtol=1e-4, atol=1e-4
    )
    assert not torch.allclose(out_u, out_c)  # the prompt matters


def test_rope_built_with_pipeline_function(priors):
    from diffusers import CogVideoXPipeline

    p = priors("cogvideox-rope")
    assert p.use_rope
    pipe = CogVideoXPipeline.from_pretrained(tiny_dir("cogvideox-rope"))
    cos, sin = pipe._prepare_rotary_positional_embeddings(16, 16, 3, torch.device("cpu"))
    ours = p._rope(3, 2, 2)
    torch.testing.assert_close(ours[0], cos)
    torch.testing.assert_close(ours[1], sin)
    p.set_prompt("metal bends")
    z = torch.randn(p.latent_shape(), generator=torch.Generator().manual_seed(0))
    t = torch.tensor([300])
    with torch.no_grad():
        with_rope = p.model_output(z, t, p.text.cond)
        no_rope = p.transformer(
            hidden_states=z,
            encoder_hidden_states=p.text.cond,
            timestep=t,
            image_rotary_emb=None,
            return_dict=False,
        )[0]
    assert not torch.allclose(with_rope, no_rope)
    assert not priors("cogvideox").use_rope


@pytest.mark.parametrize("kind", ["cogvideox", "modelscope"])
def test_sample_shape_range_and_determinism(kind, priors):
    p = priors(kind)
    p.set_prompt("a soft jelly wobbles")
    a = p.sample(steps=2, guidance=6.0, generator=torch.Generator().manual_seed(0))
    b = p.sample(steps=2, guidance=6.0, generator=torch.Generator().manual_seed(0))
    assert a.shape == (p.num_frames, p.height, p.width, 3)
    assert float(a.min()) >= 0.0 and float(a.max()) <= 1.0
    assert torch.equal(a, b)


# --- memory options ---------------------------------------------------------------------------
def test_vae_gradient_checkpointing_backward_matches():
    fr = _frames(9)
    grads = []
    for ckpt in (False, True):
        p = load_tiny("cogvideox", posterior="mode", vae_checkpointing=ckpt)
        assert p.vae.encoder.gradient_checkpointing is ckpt
        x = fr.clone().requires_grad_(True)
        z = p.encode(x)
        r = torch.linspace(-1, 1, z.numel()).view_as(z)
        (z * r).sum().backward()
        grads.append(x.grad)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-5, atol=1e-7)
    assert grads[0].abs().sum() > 0


def test_vae_tiling_option():
    p = load_tiny("cogvideox", vae_tiling=True, vae_tile_size=16)
    assert p.vae.use_tiling and p.vae.tile_sample_min_height == 16
    q = load_tiny("modelscope", vae_tiling=True)
    assert q.vae.use_tiling


def test_dtype_resolution():
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert resolve_dtype(cpu, None, torch.bfloat16) == torch.float32
    assert resolve_dtype(cuda, None, torch.bfloat16) == torch.bfloat16
    assert resolve_dtype(cuda, "fp16", torch.bfloat16) == torch.float16
    with pytest.raises(UserInputError, match="prior dtype"):
        resolve_dtype(cpu, "int8", torch.float32)


# --- errors ---------------------------------------------------------------------------------------
def _one_line(err) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_missing_directory(tmp_path):
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(tmp_path / "nope"))
    assert "huggingface-cli download THUDM/CogVideoX-2b --local-dir DIR" in _one_line(err)
    with pytest.raises(UserInputError) as err:
        load_prior("modelscope", None)
    assert "--prior-path" in _one_line(err)


def test_not_a_pipeline_directory(tmp_path):
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(tmp_path))
    assert "model_index.json" in _one_line(err)


def test_missing_component(tmp_path):
    root = tmp_path / "cog"
    shutil.copytree(tiny_dir("cogvideox"), root)
    shutil.rmtree(root / "vae")
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(root))
    msg = _one_line(err)
    assert "vae" in msg and "huggingface-cli download" in msg
    root = tmp_path / "cog2"
    shutil.copytree(tiny_dir("cogvideox"), root)
    index = json.loads((root / "model_index.json").read_text())
    del index["transformer"]
    (root / "model_index.json").write_text(json.dumps(index))
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(root))
    assert "'transformer' is missing" in _one_line(err)


def test_missing_weights(tmp_path):
    root = tmp_path / "ms"
    shutil.copytree(tiny_dir("modelscope"), root)
    for f in (root / "unet").glob("*.safetensors"):
        f.unlink()
    with pytest.raises(UserInputError) as err:
        load_prior("modelscope", str(root))
    assert "unet" in _one_line(err) and "ali-vilab/text-to-video-ms-1.7b" in str(err.value)


def test_wrong_class():
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(tiny_dir("modelscope")))
    msg = _one_line(err)
    assert "CLIPTextModel" in msg and "expected T5EncoderModel" in msg
    with pytest.raises(UserInputError) as err:
        load_prior("modelscope", str(tiny_dir("cogvideox")))
    assert "expected" in _one_line(err)


def test_unsupported_prediction_type(tmp_path):
    root = tmp_path / "cog"
    shutil.copytree(tiny_dir("cogvideox"), root)
    f = root / "scheduler" / "scheduler_config.json"
    cfg = json.loads(f.read_text())
    cfg["prediction_type"] = "sample"
    f.write_text(json.dumps(cfg))
    with pytest.raises(UserInputError) as err:
        load_prior("cogvideox", str(root))
    assert "prediction_type" in _one_line(err)


@pytest.mark.parametrize(
    "options, match",
    [
        ({"num_frames": 8}, "4k\\+1"),
        ({"height": 24}, "multiples of 16"),
        ({"bogus": 1}, "bogus"),
        ({"posterior": "median"}, "posterior"),
    ],
)
def test_bad_options(options, match):
    with pytest.raises(UserInputError, match=match):
        load_tiny("cogvideox", **options)


# --- frames ------------------------------------------------------------------------------------
def test_resample_frames_keeps_ends_and_is_linear():
    fr = _frames(5, 6, 6)
    assert torch.equal(resample_frames(fr, 5, 6, 6), fr)
    out = resample_frames(fr, 9, 6, 6)
    torch.testing.assert_close(out[0], fr[0])
    torch.testing.assert_close(out[-1], fr[-1])
    torch.testing.assert_close(out[1], 0.5 * (fr[0] + fr[1]))
    assert resample_frames(fr, 3, 12, 4).shape == (3, 12, 4, 3)


def test_default_size_is_paper_256_capped_by_native():
    p = load_prior("cogvideox", str(tiny_dir("cogvideox")))
    # the tiny transformer's sample size is 2x2 latents (16 px) and 9 frames
    assert (p.num_frames, p.height, p.width) == (9, 16, 16)
    q = load_prior("modelscope", str(tiny_dir("modelscope")))
    assert (q.num_frames, q.height, q.width) == (16, 16, 16)


def test_diffusers_dummy_layout_runs_lmd_with_defaults(tmp_path):
    """A pipeline laid out as diffusers' own dummy (other sizes than ours), default options."""
    from loss_helpers import build, two_iterations_move_theta
    from tiny_pipelines import write_diffusers_dummy_modelscope

    root = write_diffusers_dummy_modelscope(tmp_path / "ms")
    p = load_prior("modelscope", str(root), num_frames=4)
    assert (p.height, p.width) == (32, 32) and p.latent_shape() == (1, 4, 4, 32, 32)
    loss = build("lmd", p)
    values, grads, theta = two_iterations_move_theta(loss)
    assert all(torch.isfinite(torch.tensor(values))) and all(g != 0 for g in grads)
