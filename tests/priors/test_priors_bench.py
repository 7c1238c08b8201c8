"""The recorded published configurations build the published architectures (parameter
counts on the meta device, no memory), and ``bench prior`` runs at tiny size."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("diffusers")

from motionphysics.errors import UserInputError  # noqa: E402
from motionphysics.optimize.prior_bench import run_prior_bench  # noqa: E402
from motionphysics.priors.configs import MODELS, model_config  # noqa: E402

# Published sizes in millions of parameters (model cards / diffusers docs):
# CogVideoX-2b transformer 1.69 B, -5b 5.57 B, their VAE 215.6 M, T5-v1.1-XXL encoder 4.76 B;
# ModelScope UNet3D 1.41 B, its VAE 83.7 M, OpenCLIP-H text tower 340 M.
EXPECTED_M = {
    ("cogvideox-2b", "denoiser"): 1693.8,
    ("cogvideox-5b", "denoiser"): 5570.3,
    ("cogvideox-2b", "vae"): 215.6,
    ("cogvideox-5b", "text_encoder"): 4762.3,
    ("modelscope", "denoiser"): 1411.2,
    ("modelscope", "vae"): 83.65,
    ("modelscope", "text_encoder"): 340.4,
}


def _build(part_cfg: dict):
    import diffusers
    import transformers

    c = dict(part_cfg)
    name = c.pop("class")
    if hasattr(diffusers, name):
        return getattr(diffusers, name)(**c)
    cfg_name = {"T5EncoderModel": "T5Config", "CLIPTextModel": "CLIPTextConfig"}[name]
    return getattr(transformers, name)(getattr(transformers, cfg_name)(**c))


@pytest.mark.parametrize("key", sorted(EXPECTED_M))
def test_full_configs_build_published_sizes(key):
    model, part = key
    with torch.device("meta"):
        module = _build(model_config(model)[part])
    n = sum(p.numel() for p in module.parameters()) / 1e6
    assert n == pytest.approx(EXPECTED_M[key], rel=2e-3)


def test_configs_keep_structure_at_tiny_size():
    for m in MODELS:
        full, tiny = model_config(m), model_config(m, "tiny")
        assert tiny["scheduler"] == full["scheduler"]
        for k in ("latent_channels", "scaling_factor", "down_block_types"):
            assert tiny["vae"][k] == full["vae"][k]
    assert model_config("cogvideox-5b", "tiny")["denoiser"]["use_rotary_positional_embeddings"]
    assert model_config("cogvideox-2b")["scheduler"]["snr_shift_scale"] == 3.0


def test_bench_runs_tiny_on_cpu():
    torch.set_num_threads(1)
    lines = []
    r = run_prior_bench(
        "cogvideox-5b",
        True,
        "cpu",
        True,
        size="tiny",
        frames=5,
        resolution=32,
        repeats=1,
        out=lines.append,
    )
    assert r["latent_shape"] == [1, 5, 16, 4, 4] and r["iteration_s"] > 0
    assert r["encode_s"] > 0 and r["predict_s"] > 0 and r["backward_s"] > 0
    assert len(lines) == 1 and lines[0].startswith("{")
    with pytest.raises(UserInputError, match="--size full"):
        run_prior_bench("cogvideox-5b", True, "cpu", True, size="full")
    with pytest.raises(UserInputError, match="--model"):
        run_prior_bench("sora", True, "cpu", True)


@pytest.mark.parametrize("target", ["prior", "iteration"])
def test_bench_model_tiny_is_refused_in_one_line(capsys, target):
    """The embedded pixel prior (``--model tiny``) was removed: exit 2, one line naming
    what happened and what to bench instead; the usage no longer lists it."""
    from motionphysics.cli import main

    extra = ["--random-weights"] if target == "prior" else []
    assert main(["bench", target, "--model", "tiny", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"motionphysics: error: bench {target} --model tiny: the embedded pixel prior was "
        "removed (it could not tell motions apart: 20 % held-out caption discrimination); "
        "use --model cogvideox-5b, cogvideox-2b or modelscope (random weights)"
    ]
    with pytest.raises(SystemExit):
        main(["bench", target, "--help"])
    usage = capsys.readouterr().out
    assert "--model {cogvideox-5b,cogvideox-2b,modelscope}" in usage and "tiny}" not in usage
