"""ModelScope text-to-video (damo-vilab/text-to-video-ms-1.7b) as a motion prior.

Components, as ``TextToVideoSDPipeline`` holds them: a CLIP tokenizer and
``CLIPTextModel``, a per-frame 2-D ``AutoencoderKL``, ``UNet3DConditionModel`` and a DDIM
scheduler (epsilon prediction on the published model; read from the scheduler config,
not assumed). Frames are not compressed in time: 16 frames give 16 latent frames.

Layouts: the UNet works in ``[B, C, F, h, w]``, this prior in ``[B, F, C, h, w]``; the VAE
encodes ``[F, 3, H, W]`` frame by frame. The prompt is tokenised Stable-Diffusion style
(``padding="max_length"`` to the tokenizer's ``model_max_length``, capped by the text
encoder's position embeddings), with the attention mask only where the text encoder's
config asks for one (``use_attention_mask``), as the pipeline's ``encode_prompt`` does.

The UNet has no gradient checkpointing in diffusers; it runs under ``no_grad`` here, so
that does not matter. This module must not render or simulate.
"""

from __future__ import annotations

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

__all__ = ["ModelScopePrior"]

HUB_ID = "ali-vilab/text-to-video-ms-1.7b"
COMPONENTS = {
    "tokenizer": (),
    "text_encoder": ("CLIPTextModel",),
    "vae": ("AutoencoderKL",),
    "unet": ("UNet3DConditionModel",),
    "scheduler": (),
}


class ModelScopePrior(DiffusersPrior):
    """ModelScope T2V behind :class:`~motionphysics.priors.base.VideoPrior`."""

    name = "modelscope"
    Options = DiffusersPriorOptions

    def __init__(
        self,
        *,
        vae,
        unet,
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
        side = spatial * 2 ** (len(unet.config.block_out_channels) - 1)
        native = int(unet.config.sample_size) * spatial
        height = default_side(height, native, side)
        width = default_side(width, native, side)
        num_frames = 16 if num_frames is None else num_frames
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
        self.unet = place(unet, self.device, self.dtype)
        self.scaling_factor = float(vae.config.scaling_factor)
        self.spatial_scale = 2 ** (len(vae.config.block_out_channels) - 1)
        self.latent_channels = int(vae.config.latent_channels)
        # The UNet downsamples len(block_out_channels)-1 times: the latent side must divide.
        side = self.spatial_scale * 2 ** (len(unet.config.block_out_channels) - 1)
        if self.height % side or self.width % side:
            raise UserInputError(
                f"prior option height/width: {self.height}x{self.width} must be multiples of {side}"
            )

    @classmethod
    def from_pretrained(
        cls, path: str | None, *, device: str = "cpu", dtype: torch.dtype | None = None, **options
    ) -> ModelScopePrior:
        """Load from a diffusers ModelScope T2V directory (or hub id).

        ``options`` are :class:`DiffusersPriorOptions` fields (``num_frames`` 16 by default,
        the pipeline's default and the paper's count)."""
        opts = parse_options(DiffusersPriorOptions, "modelscope", options)
        md = open_model_dir(path, prior="modelscope", hub_id=HUB_ID, components=COMPONENTS)
        dev = torch.device(device)
        unet_cfg = component_config(md, "unet")
        vae_cfg = component_config(md, "vae")
        te_cfg = component_config(md, "text_encoder")
        if "scaling_factor" not in vae_cfg:
            raise UserInputError(f"{md.sub('vae') / 'config.json'}: no scaling_factor; {md.hint()}")
        hidden, cross = te_cfg.get("hidden_size"), unet_cfg.get("cross_attention_dim")
        check_text_width(md, "hidden_size", hidden, "unet's cross_attention_dim", cross)
        dt = resolve_dtype(dev, opts.dtype if dtype is None else dtype, torch.float16)
        return build_prior(cls, md, opts, dev, dt, "unet")

    def latent_shape(self) -> tuple[int, ...]:
        s = self.spatial_scale
        return (1, self.num_frames, self.latent_channels, self.height // s, self.width // s)

    def _encode_prompts(self, prompts: list[str]) -> Tensor:
        cfg = self.text_encoder.config
        max_len = min(int(self.tokenizer.model_max_length), int(cfg.max_position_embeddings))
        tok = self.tokenizer(
            prompts, padding="max_length", max_length=max_len, truncation=True, return_tensors="pt"
        )
        mask = None
        if getattr(cfg, "use_attention_mask", False):
            mask = tok.attention_mask.to(self.device)
        return self.text_encoder(tok.input_ids.to(self.device), attention_mask=mask)[0]

    def encode(self, frames: Tensor, generator: torch.Generator | None = None) -> Tensor:
        x = resample_frames(frames, self.num_frames, self.height, self.width)  # [F, H, W, 3]
        x = (x * 2.0 - 1.0).permute(0, 3, 1, 2)  # [F, 3, H, W] in [-1, 1]
        dist = self.vae.encode(x.to(self.device, self.dtype)).latent_dist
        z = self._posterior_sample(dist, generator) * self.scaling_factor  # [F, C, h, w]
        return self._wide(z.unsqueeze(0))  # [1, F, C, h, w]

    def decode(self, latents: Tensor) -> Tensor:
        z = latents[0].to(self.device, self.dtype) / self.scaling_factor  # [F, C, h, w]
        frames = self.vae.decode(z).sample  # [F, 3, H, W] in [-1, 1]
        return ((self._wide(frames) + 1.0) / 2.0).permute(0, 2, 3, 1)

    def model_output(self, z_t: Tensor, t: Tensor, text: Tensor) -> Tensor:
        b = z_t.shape[0]
        out = self.unet(
            sample=z_t.permute(0, 2, 1, 3, 4).to(self.device, self.dtype),  # [B, C, F, h, w]
            timestep=t.to(self.device).expand(b),
            encoder_hidden_states=text.to(self.device, self.dtype),
            return_dict=False,
        )[0]
        return self._wide(out.permute(0, 2, 1, 3, 4))
