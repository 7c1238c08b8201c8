"""What the diffusers-backed priors (CogVideoX, ModelScope) share: option validation,
component loading with one-line errors, the scheduler's ᾱ and prediction type, the text
encoder's lifetime (encode once, then release), and device / dtype placement.

Imports diffusers and transformers only inside functions.
"""

from __future__ import annotations

import gc
from typing import Any

import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from motionphysics.errors import UserInputError
from motionphysics.priors.base import TextEmbeddings, VideoPrior
from motionphysics.priors.loading import ModelDir, component_config, load_failed, require_weights

__all__ = ["DiffusersPrior", "DiffusersPriorOptions", "load_scheduler"]


class DiffusersPriorOptions(BaseModel):
    """Options of a diffusers-backed prior (``load_prior(name, path, **options)``)."""

    model_config = ConfigDict(extra="forbid")

    num_frames: int | None = Field(default=None, ge=1)
    """Frames per clip the prior sees (rendered clips are resampled to this).
    None: the backend's default (CogVideoX 17 = 4·4+1, ModelScope 16)."""
    height: int | None = Field(default=None, ge=8)
    """Pixel height the prior runs at. None: the paper's 256, or the model's native
    sample height (from its configs) where that is smaller -- a model is never run above
    the size it was trained at unless asked."""
    width: int | None = Field(default=None, ge=8)
    """Pixel width the prior runs at (None: as ``height``, from the native sample width)."""
    dtype: str | None = None
    """Network dtype: float32 / float16 / bfloat16 (float64 for gradient checks). None: float32 on CPU; on CUDA the
    dtype the model was trained in (CogVideoX-5b-style RoPE models bf16, -2b fp16,
    ModelScope fp16)."""
    vae_checkpointing: bool | None = None
    """Gradient checkpointing in the VAE (the encoder runs with grad). None: on CUDA only
    (on CPU memory is not the limit and recomputation costs time)."""
    vae_tiling: bool = False
    """Tiled VAE encode/decode (diffusers ``enable_tiling``): lower peak memory at large
    sizes; at 256² CogVideoX tiles only when ``vae_tile_size`` is below the size."""
    vae_tile_size: int | None = Field(default=None, ge=16)
    """Tile side in pixels when ``vae_tiling`` (None: the VAE's own default)."""
    posterior: str = "sample"
    """``sample`` the VAE posterior (the released code and the pipelines' img2img) or take
    its ``mode`` (the mean; deterministic)."""
    release_text_encoder: bool = True
    """Free the text encoder after the prompt is encoded (it is reloaded from the model
    directory if another prompt is set)."""
    negative_prompt: str = ""
    """Default negative prompt (the pipelines' default is the empty string)."""


def parse_options(model: type[BaseModel], prior: str, options: dict) -> Any:
    try:
        opts = model.model_validate(options)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        raise UserInputError(
            f"prior option {loc}: {first['msg']} (got {first.get('input')!r}) for --prior {prior}"
        ) from None
    if opts.posterior not in ("sample", "mode"):
        raise UserInputError(
            f"prior option posterior: expected 'sample' or 'mode', got {opts.posterior!r}"
        )
    return opts


def load_scheduler(md: ModelDir):
    """The pipeline's scheduler (for ᾱ and the prediction type), from ``scheduler/``."""
    import diffusers

    cls_name = md.class_name("scheduler")
    cls = getattr(diffusers, cls_name, None)
    if cls is None or not hasattr(cls, "from_pretrained"):
        raise UserInputError(
            f"{md.root / 'model_index.json'}: scheduler class {cls_name!r} is not a diffusers "
            f"scheduler; {md.hint()}"
        )
    cfg = component_config(md, "scheduler", "scheduler_config.json")
    pt = cfg.get("prediction_type", "epsilon")
    if pt not in ("epsilon", "v_prediction"):
        raise UserInputError(
            f"{md.sub('scheduler') / 'scheduler_config.json'}: prediction_type {pt!r}; "
            f"expected 'epsilon' or 'v_prediction'"
        )
    try:
        sched = cls.from_pretrained(md.root, subfolder="scheduler")
    except Exception as err:
        raise load_failed(md, "scheduler", err) from None
    if not hasattr(sched, "alphas_cumprod"):
        raise UserInputError(
            f"{md.sub('scheduler')}: scheduler {cls_name} has no alphas_cumprod (a DDPM-family "
            f"scheduler is needed); {md.hint()}"
        )
    return sched


def load_model(md: ModelDir, component: str, library: str, dtype: torch.dtype):
    """A model component (diffusers or transformers) by the class named in model_index."""
    import importlib

    require_weights(md, component)
    lib = importlib.import_module(library)
    cls = getattr(lib, md.class_name(component))
    try:
        if library == "transformers":
            model = cls.from_pretrained(md.sub(component), dtype=dtype)
        else:
            model = cls.from_pretrained(md.root, subfolder=component, torch_dtype=dtype)
    except Exception as err:
        raise load_failed(md, component, err) from None
    model.requires_grad_(False)
    model.eval()
    return model


def load_tokenizer(md: ModelDir):
    """The tokenizer by the class named in ``model_index.json`` (falling back to the Auto
    class), so a sentencepiece T5 or a BPE CLIP tokenizer written by anyone loads."""
    import transformers

    sub = md.sub("tokenizer")
    errors = []
    cls = getattr(transformers, md.class_name("tokenizer"), None)
    for loader in (cls, transformers.AutoTokenizer):
        if loader is None:
            continue
        try:
            return loader.from_pretrained(sub)
        except Exception as err:  # try the next loader; report the first failure
            errors.append(err)
    raise load_failed(md, "tokenizer", errors[0]) from None


PAPER_SIDE = 256
"""The paper's (and the released code's) prior resolution: renders resized to 256²."""


def default_side(requested: int | None, native: int, multiple: int) -> int:
    """``requested``, else min(256, native) rounded down to ``multiple`` (at least one)."""
    if requested is not None:
        return int(requested)
    side = min(PAPER_SIDE, int(native))
    return max(multiple, side // multiple * multiple)


class DiffusersPrior(VideoPrior):
    """Common state of the diffusers priors (subclasses supply the networks' calls)."""

    def __init__(
        self,
        *,
        scheduler,
        device: torch.device | str,
        dtype: torch.dtype,
        num_frames: int,
        height: int,
        width: int,
        text_encoder=None,
        tokenizer=None,
        model_dir: ModelDir | None = None,
        posterior: str = "sample",
        release_text_encoder: bool = True,
        negative_prompt: str = "",
    ):
        self.device = torch.device(device)
        self.dtype = dtype
        self.num_frames = int(num_frames)
        self.height = int(height)
        self.width = int(width)
        self.scheduler = scheduler
        self.prediction_type = scheduler.config.prediction_type
        if self.prediction_type not in ("epsilon", "v_prediction"):
            raise UserInputError(
                f"scheduler prediction_type {self.prediction_type!r}: expected 'epsilon' or "
                f"'v_prediction'"
            )
        # ᾱ in float64 by the schedulers; float32 is exact enough for √ᾱ and √(1-ᾱ).
        self.alphas_cumprod = scheduler.alphas_cumprod.to(torch.float32).to(self.device)
        self.text_encoder = text_encoder
        self.tokenizer = tokenizer
        self.model_dir = model_dir
        self.posterior = posterior
        self.release_text_encoder = release_text_encoder
        self.negative_prompt = negative_prompt
        self._text = None

    # --- text -----------------------------------------------------------------------
    def _ensure_text_encoder(self) -> None:
        if self.text_encoder is not None and self.tokenizer is not None:
            return
        if self.model_dir is None:
            raise RuntimeError(f"{self.name}: no text encoder (built without one)")
        self.text_encoder = load_model(self.model_dir, "text_encoder", "transformers", self.dtype)
        self.tokenizer = load_tokenizer(self.model_dir)

    def _release_text_encoder(self) -> None:
        if not self.release_text_encoder or self.model_dir is None:
            return
        self.text_encoder = None
        self.tokenizer = None
        gc.collect()
        if self.device.type == "cuda":
            torch.cuda.empty_cache()

    def _encode_prompts(self, prompts: list[str]) -> torch.Tensor:
        """[len(prompts), L, D] token embeddings (backend-specific)."""
        raise NotImplementedError

    def encode_text(self, prompt: str, negative_prompt: str | None = None) -> TextEmbeddings:
        neg = self.negative_prompt if negative_prompt in (None, "") else negative_prompt
        self._ensure_text_encoder()
        self.text_encoder.to(self.device)
        with torch.no_grad():
            emb = self._encode_prompts([prompt, neg]).to(self.device, self.dtype)
        self._release_text_encoder()
        return TextEmbeddings(cond=emb[0:1], uncond=emb[1:2], prompt=prompt, negative_prompt=neg)

    def set_prompt(self, prompt: str, negative_prompt: str = "") -> TextEmbeddings:
        return super().set_prompt(prompt, negative_prompt or self.negative_prompt)

    # --- helpers for the subclasses ---------------------------------------------------
    @staticmethod
    def _wide(x: torch.Tensor) -> torch.Tensor:
        """Half-precision network outputs to float32 (float32 / float64 kept)."""
        return x if x.dtype in (torch.float32, torch.float64) else x.float()

    def _posterior_sample(self, dist, generator: torch.Generator | None) -> torch.Tensor:
        if self.posterior == "mode":
            return dist.mode()
        return dist.sample(generator=generator)


def place(model, device: torch.device, dtype: torch.dtype):
    """Move a network to ``device`` / ``dtype`` (no dtype cast when it already matches:
    diffusers warns on casts of modules it keeps in float32)."""
    if getattr(model, "dtype", dtype) != dtype:
        model = model.to(dtype=dtype)
    return model.to(device)


def configure_vae(vae, opts, device: torch.device) -> None:
    """Gradient checkpointing and tiling per the options (see DiffusersPriorOptions)."""
    ckpt = opts.vae_checkpointing if opts.vae_checkpointing is not None else device.type == "cuda"
    if ckpt:
        vae.enable_gradient_checkpointing()
    if opts.vae_tiling:
        if opts.vae_tile_size is not None:
            kwargs = {
                "tile_sample_min_height": opts.vae_tile_size,
                "tile_sample_min_width": opts.vae_tile_size,
            }
            try:
                vae.enable_tiling(**kwargs)
            except TypeError:  # 2-D AutoencoderKL: enable_tiling() takes no sizes
                vae.enable_tiling()
                vae.tile_sample_min_size = opts.vae_tile_size
                vae.tile_latent_min_size = int(
                    opts.vae_tile_size / (2 ** (len(vae.config.block_out_channels) - 1))
                )
        else:
            vae.enable_tiling()


def check_text_width(md: ModelDir, key: str, value, other: str, other_value) -> None:
    """The text encoder's output width must be what the denoiser cross-attends to."""
    if value is not None and other_value is not None and int(value) != int(other_value):
        raise UserInputError(
            f"{md.sub('text_encoder') / 'config.json'}: {key} {value} does not match the "
            f"{other} {other_value}"
        )


def build_prior(cls, md: ModelDir, opts, device: torch.device, dtype: torch.dtype, denoiser: str,
                **extra):  # fmt: skip
    """Load the scheduler, the VAE (configured per ``opts``) and the ``denoiser`` component
    of ``md``, construct ``cls`` with them, then load its text encoder and tokenizer (so a
    broken tokenizer or encoder fails at startup). ``extra``: more constructor arguments."""
    scheduler = load_scheduler(md)
    vae = load_model(md, "vae", "diffusers", dtype)
    net = load_model(md, denoiser, "diffusers", dtype)
    configure_vae(vae, opts, device)
    prior = cls(
        vae=vae,
        scheduler=scheduler,
        device=device,
        dtype=dtype,
        num_frames=opts.num_frames,
        height=opts.height,
        width=opts.width,
        model_dir=md,
        posterior=opts.posterior,
        release_text_encoder=opts.release_text_encoder,
        negative_prompt=opts.negative_prompt,
        **{denoiser: net},
        **extra,
    )
    prior.text_encoder = load_model(md, "text_encoder", "transformers", dtype)
    prior.tokenizer = load_tokenizer(md)
    return prior
