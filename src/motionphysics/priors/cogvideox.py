"""CogVideoX (THUDM/CogVideoX-2b, -5b) as a motion prior, through diffusers.

Components, as ``CogVideoXPipeline`` holds them: a T5 tokenizer and ``T5EncoderModel``,
``AutoencoderKLCogVideoX`` (a causal 3-D VAE: 4× in time, 8× in space),
``CogVideoXTransformer3DModel`` and a CogVideoX DDIM / DPM scheduler (v-prediction with a
zero-terminal-SNR schedule on the published models). Everything the method depends on is
read from the directory's configs, not assumed: the prediction type (scheduler), the
VAE's scaling factor and compression ratios, the text length (the transformer's
``max_text_seq_length``; the 2b's joint positional embedding needs exactly that length)
and whether the transformer uses RoPE (the 5b: without the rotary embeddings it would
silently lose all positional information; they are built with the pipeline's own
``_prepare_rotary_positional_embeddings``).

Layouts: the VAE works in ``[B, C, F, H, W]``, the pipeline and this prior in
``[B, F_lat, C, h, w]``; ``F_lat = (F - 1) / 4 + 1`` for the trained 4k+1 frame counts.

The prompt is tokenised to ``max_text_seq_length`` with padding and encoded **without an
attention mask**, as ``CogVideoXPipeline._get_t5_prompt_embeds`` does.

This module must not render or simulate; it imports diffusers only when a prior is built.
"""

from __future__ import annotations

from types import SimpleNamespace

import torch
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.priors.base import resample_frames
from motionphysics.priors.diffusers_common import (
    DiffusersPrior,
    DiffusersPriorOptions,
    build_prior,
    check_text_width,
    default_side,
    parse_options,
    place,
)
from motionphysics.priors.loading import component_config, open_model_dir, resolve_dtype

__all__ = ["CogVideoXPrior"]

HUB_ID = "THUDM/CogVideoX-2b"
COMPONENTS = {
    "tokenizer": (),
    "text_encoder": ("T5EncoderModel",),
    "vae": ("AutoencoderKLCogVideoX",),
    "transformer": ("CogVideoXTransformer3DModel",),
    "scheduler": (),
}


class CogVideoXPrior(DiffusersPrior):
    """CogVideoX behind :class:`~motionphysics.priors.base.VideoPrior`.

    Build with :meth:`from_pretrained` (a diffusers directory or hub id) or directly from
    components (benchmarks with random weights pass ``text_encoder=None`` and set the
    embeddings themselves).
    """

    name = "cogvideox"
    Options = DiffusersPriorOptions

    def __init__(
        self,
        *,
        vae,
        transformer,
        scheduler,
        text_encoder=None,
        tokenizer=None,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        num_frames: int | None = None,
        height: int | None = None,
        width: int | None = None,
        **kwargs,
    ):
        spatial = 2 ** (len(vae.config.block_out_channels) - 1)
        side = spatial * int(transformer.config.patch_size)
        height = default_side(height, transformer.config.sample_height * spatial, side)
        width = default_side(width, transformer.config.sample_width * spatial, side)
        if num_frames is None:
            # 17 = 4·4+1, the trained 4k+1 count nearest the paper's 16 frames; fewer
            # where the transformer's sample_frames says the model saw fewer.
            k = int(vae.config.temporal_compression_ratio)
            native = int(transformer.config.sample_frames)
            num_frames = 17 if native >= 17 else max(1, (native - 1) // k * k + 1)
        super().__init__(
            scheduler=scheduler,
            device=device,
            dtype=dtype,
            num_frames=num_frames,
            height=height,
            width=width,
            text_encoder=text_encoder,
            tokenizer=tokenizer,
            **kwargs,
        )
        self.vae = place(vae, self.device, self.dtype)
        self.transformer = place(transformer, self.device, self.dtype)
        self.scaling_factor = float(vae.config.scaling_factor)
        self.spatial_scale = 2 ** (len(vae.config.block_out_channels) - 1)
        self.temporal_scale = int(vae.config.temporal_compression_ratio)
        self.latent_channels = int(vae.config.latent_channels)
        self.text_length = int(transformer.config.max_text_seq_length)
        self.use_rope = bool(transformer.config.use_rotary_positional_embeddings)
        patch = int(transformer.config.patch_size)
        side = self.spatial_scale * patch
        if self.height % side or self.width % side:
            raise UserInputError(
                f"prior option height/width: {self.height}x{self.width} must be multiples of "
                f"{side} (VAE scale {self.spatial_scale} x patch {patch})"
            )
        if (self.num_frames - 1) % self.temporal_scale:
            raise UserInputError(
                f"prior option num_frames: {self.num_frames} must be {self.temporal_scale}k+1 "
                f"(the causal VAE compresses time {self.temporal_scale}x after the first frame)"
            )
        p_t = transformer.config.patch_size_t
        if p_t is not None and self.latent_frames % int(p_t):
            raise UserInputError(
                f"prior option num_frames: {self.num_frames} gives {self.latent_frames} latent "
                f"frames, not a multiple of the transformer's patch_size_t {p_t}"
            )
        self._rope_cache: dict = {}

    # --- loading --------------------------------------------------------------------
    @classmethod
    def from_pretrained(
        cls, path: str | None, *, device: str = "cpu", dtype: torch.dtype | None = None, **options
    ) -> CogVideoXPrior:
        """Load from a diffusers CogVideoX directory (or hub id).

        ``options`` are :class:`DiffusersPriorOptions` fields (``num_frames`` 17 by
        default: the 4k+1 count nearest the paper's 16 frames; 256² unless the model's
        native sample size is smaller)."""
        opts = parse_options(DiffusersPriorOptions, "cogvideox", options)
        md = open_model_dir(path, prior="cogvideox", hub_id=HUB_ID, components=COMPONENTS)
        dev = torch.device(device)
        tf_cfg = component_config(md, "transformer")
        vae_cfg = component_config(md, "vae")
        te_cfg = component_config(md, "text_encoder")
        if "scaling_factor" not in vae_cfg:
            raise UserInputError(f"{md.sub('vae') / 'config.json'}: no scaling_factor; {md.hint()}")
        d_model, text_dim = te_cfg.get("d_model"), tf_cfg.get("text_embed_dim", 4096)
        check_text_width(md, "d_model", d_model, "transformer's text_embed_dim", text_dim)
        # Trained precisions: 5b-style (RoPE) in bf16 (fp16 gives NaNs), 2b in fp16.
        rope = bool(tf_cfg.get("use_rotary_positional_embeddings", False))
        dt = resolve_dtype(
            dev, opts.dtype if dtype is None else dtype, torch.bfloat16 if rope else torch.float16
        )
        return build_prior(cls, md, opts, dev, dt, "transformer", text_encoder=None, tokenizer=None)

    # --- the interface ----------------------------------------------------------------
    @property
    def latent_frames(self) -> int:
        return (self.num_frames - 1) // self.temporal_scale + 1

    def latent_shape(self) -> tuple[int, ...]:
        s = self.spatial_scale
        return (1, self.latent_frames, self.latent_channels, self.height // s, self.width // s)

    def _encode_prompts(self, prompts: list[str]) -> Tensor:
        ids = self.tokenizer(
            prompts,
            padding="max_length",
            max_length=self.text_length,
            truncation=True,
            add_special_tokens=True,
            return_tensors="pt",
        ).input_ids
        # No attention mask: the pipeline encodes the pad tokens too (the model was trained so).
        return self.text_encoder(ids.to(self.device))[0]

    def encode(self, frames: Tensor, generator: torch.Generator | None = None) -> Tensor:
        x = resample_frames(frames, self.num_frames, self.height, self.width)  # [F, H, W, 3]
        x = (x * 2.0 - 1.0).permute(3, 0, 1, 2).unsqueeze(0)  # [1, 3, F, H, W] in [-1, 1]
        dist = self.vae.encode(x.to(self.device, self.dtype)).latent_dist
        z = self._posterior_sample(dist, generator) * self.scaling_factor  # [1, C, F_lat, h, w]
        return self._wide(z.permute(0, 2, 1, 3, 4))  # [1, F_lat, C, h, w]

    def decode(self, latents: Tensor) -> Tensor:
        z = latents.permute(0, 2, 1, 3, 4).to(self.device, self.dtype) / self.scaling_factor
        video = self.vae.decode(z).sample  # [1, 3, F, H, W] in [-1, 1]
        return ((self._wide(video[0]) + 1.0) / 2.0).permute(1, 2, 3, 0)

    def _rope(self, f_lat: int, h: int, w: int):
        """(cos, sin) [F_lat·gh·gw, head_dim] from the pipeline's own function, cached."""
        if not self.use_rope:
            return None
        key = (f_lat, h, w)
        if key not in self._rope_cache:
            from diffusers import CogVideoXPipeline

            shim = SimpleNamespace(
                vae_scale_factor_spatial=self.spatial_scale, transformer=self.transformer
            )
            cos, sin = CogVideoXPipeline._prepare_rotary_positional_embeddings(
                shim, h * self.spatial_scale, w * self.spatial_scale, f_lat, self.device
            )
            self._rope_cache[key] = (cos, sin)
        return self._rope_cache[key]

    def model_output(self, z_t: Tensor, t: Tensor, text: Tensor) -> Tensor:
        b, f_lat, _, h, w = z_t.shape
        out = self.transformer(
            hidden_states=z_t.to(self.device, self.dtype),
            encoder_hidden_states=text.to(self.device, self.dtype),
            timestep=t.to(self.device).expand(b),
            image_rotary_emb=self._rope(f_lat, h, w),
            return_dict=False,
        )[0]
        return self._wide(out)
