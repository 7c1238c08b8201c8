"""``bench prior``: the prior's part of one LMD iteration, timed, with peak memory.

The architecture is built from its recorded published configuration
(:mod:`motionphysics.priors.configs`) with random weights (nothing is downloaded); the
text embeddings are random tensors of the text encoder's output shape (the prompt is
encoded once per run, not per iteration, so the text encoder is not part of the
iteration). One iteration is the paper's setting: 16 rendered frames at 256² that require
grad -> ``lmd`` loss (encode with grad, t draw, one guided prediction over
[uncond; cond], extractor step + EMA) -> ``backward`` to the frames.

``size: tiny`` shrinks widths and depths but keeps the structure (runs on a CPU);
``size: full`` is the published size (CUDA only: 5b is ~5.6 B parameters). This module
must not be imported by core modules; it imports diffusers inside functions.
"""

from __future__ import annotations

import json as _json
import resource
import time

import torch

from motionphysics.errors import UserInputError

__all__ = [
    "MODELS_BENCHED",
    "MODELS_REMOVED",
    "build_random_prior",
    "check_model",
    "run_prior_bench",
]

MODELS_BENCHED = ("cogvideox-5b", "cogvideox-2b", "modelscope")
MODELS_REMOVED = ("tiny",)
"""Models these benchmarks no longer offer (the embedded pixel prior, removed 2026-12-03):
the ``--model`` choices admit them so that :func:`check_model` refuses them in one line."""


def check_model(model: str, command: str) -> str:
    """``model`` if ``command`` (``bench prior``, ``bench iteration``) can bench it, else a
    one-line :class:`UserInputError` (a removed model: why, and what to use instead)."""
    from motionphysics.priors import PRIORS

    if model in MODELS_REMOVED:
        raise UserInputError(
            f"{command} --model {model}: {PRIORS.removed[model]}; use --model "
            f"{', '.join(MODELS_BENCHED[:-1])} or {MODELS_BENCHED[-1]} (random weights)"
        )
    if model not in MODELS_BENCHED:
        raise UserInputError(
            f"{command} --model {model!r}: expected one of {', '.join(MODELS_BENCHED)}"
        )
    return model


def _cls(name: str):
    import diffusers

    return getattr(diffusers, name)


def build_random_prior(
    model: str, size: str, device: str | torch.device, dtype=None, resolution: int = 256
):
    """A prior of ``model``'s architecture with seeded random weights and random text."""
    from motionphysics.priors.base import TextEmbeddings
    from motionphysics.priors.configs import model_config
    from motionphysics.priors.diffusers_common import place
    from motionphysics.priors.loading import resolve_dtype

    dev = torch.device(device)
    cfg = model_config(model, size)
    dt = resolve_dtype(dev, dtype, getattr(torch, cfg["cuda_dtype"]))

    def make(part: str):
        c = dict(cfg[part])
        cls = _cls(c.pop("class"))
        torch.manual_seed(0)
        with torch.device(dev):
            model = cls(**c)
        return place(model, dev, dt).eval().requires_grad_(False)

    sc = dict(cfg["scheduler"])
    scheduler = _cls(sc.pop("class"))(**sc)
    vae, denoiser = make("vae"), make("denoiser")
    if dev.type == "cuda":
        vae.enable_gradient_checkpointing()
    if cfg["prior"] == "cogvideox":
        from motionphysics.priors.cogvideox import CogVideoXPrior

        prior = CogVideoXPrior(
            vae=vae,
            transformer=denoiser,
            scheduler=scheduler,
            device=dev,
            dtype=dt,
            num_frames=cfg["num_frames"],
            height=resolution,
            width=resolution,
        )
        length, dim = denoiser.config.max_text_seq_length, denoiser.config.text_embed_dim
    else:
        from motionphysics.priors.modelscope import ModelScopePrior

        prior = ModelScopePrior(
            vae=vae,
            unet=denoiser,
            scheduler=scheduler,
            device=dev,
            dtype=dt,
            num_frames=cfg["num_frames"],
            height=resolution,
            width=resolution,
        )
        length = cfg["text_encoder"]["max_position_embeddings"]
        dim = denoiser.config.cross_attention_dim
    g = torch.Generator().manual_seed(1)
    emb = torch.randn(2, length, dim, generator=g).to(dev, dt)
    prior._text = TextEmbeddings(cond=emb[:1], uncond=emb[1:], prompt="bench", negative_prompt="")
    params = sum(p.numel() for p in vae.parameters()) + sum(
        p.numel() for p in denoiser.parameters()
    )
    return prior, params


def _peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB -> GiB


def run_prior_bench(
    model: str,
    random_weights: bool = True,
    device: str = "cpu",
    json: bool = False,
    *,
    size: str = "tiny",
    frames: int = 16,
    resolution: int = 256,
    guidance: float = 100.0,
    repeats: int = 3,
    out=print,
) -> dict:
    """Time ``repeats`` prior iterations (after one warm-up) and report peak memory.

    Returns the result dict (also printed: one JSON line with ``json``, else a table)."""
    check_model(model, "bench prior")
    if not random_weights:
        raise UserInputError(
            "bench prior: only --random-weights is supported (nothing is downloaded)"
        )
    if size not in ("tiny", "full"):
        raise UserInputError(f"bench prior --size {size!r}: expected tiny or full")
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UserInputError("bench prior --device cuda: no CUDA device is available")
    if size == "full" and dev.type != "cuda":
        raise UserInputError(
            f"bench prior --size full --model {model}: the published size needs a GPU "
            "(tens of GB, hours per iteration on a CPU); use --device cuda or --size tiny"
        )
    from motionphysics.losses.base import LossContext, Prediction
    from motionphysics.losses.lmd import LmdLoss

    t_build = time.perf_counter()
    prior, params = build_random_prior(model, size, dev, resolution=resolution)
    prompt = prior.text.prompt
    loss = LmdLoss(prior, prompt, LmdLoss.Options(guidance=guidance))
    build_s = time.perf_counter() - t_build

    # split: wrap encode / predict with synchronising timers
    split = {"encode": 0.0, "predict": 0.0}

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize()

    def timed(name, fn):
        def wrapper(*a, **k):
            sync()
            t0 = time.perf_counter()
            r = fn(*a, **k)
            sync()
            split[name] += time.perf_counter() - t0
            return r

        return wrapper

    prior.encode = timed("encode", prior.encode)
    prior.predict = timed("predict", prior.predict)
    g = torch.Generator().manual_seed(0)
    rgb0 = torch.rand(frames, resolution, resolution, 3, generator=g).to(dev)
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    rng = torch.Generator().manual_seed(0)
    times, backs, totals = [], [], []
    for i in range(repeats + 1):
        for k in split:
            split[k] = 0.0
        rgb = rgb0.clone().requires_grad_(True)
        sync()
        t0 = time.perf_counter()
        value = loss(
            Prediction(frame_indices=tuple(range(frames)), rgb=rgb),
            LossContext(iteration=i, num_frames=frames, rng=rng),
        )
        sync()
        t1 = time.perf_counter()
        value.backward()
        sync()
        t2 = time.perf_counter()
        if not torch.isfinite(rgb.grad).all():
            raise RuntimeError("bench prior: non-finite gradient reached the frames")
        if i == 0:
            continue  # warm-up (allocator, kernel selection)
        times.append(dict(split))
        backs.append(t2 - t1)
        totals.append(t2 - t0)
    med = sorted(range(repeats), key=lambda j: totals[j])[repeats // 2]
    result = {
        "model": model,
        "size": size,
        "device": str(dev),
        "dtype": str(prior.dtype).replace("torch.", ""),
        "parameters": int(params),
        "frames": frames,
        "resolution": resolution,
        "prior_frames": prior.num_frames,
        "latent_shape": list(prior.latent_shape()),
        "guidance": guidance,
        "repeats": repeats,
        "build_s": round(build_s, 3),
        "iteration_s": round(totals[med], 4),
        "encode_s": round(times[med]["encode"], 4),
        "predict_s": round(times[med]["predict"], 4),
        "backward_s": round(backs[med], 4),
        "iteration_min_s": round(min(totals), 4),
        "peak_memory_gb": round(
            torch.cuda.max_memory_allocated() / 1024**3 if dev.type == "cuda" else _peak_rss_gb(), 3
        ),
        "peak_memory_kind": "cuda max_memory_allocated"
        if dev.type == "cuda"
        else "process peak RSS",
    }
    if json:
        out(_json.dumps(result))
    else:
        for k, v in result.items():
            out(f"{k:>18}: {v}")
    return result
