"""Published component configurations of the diffusers priors, recorded in the package so
``bench prior --random-weights`` builds the real architectures without downloading.

Sources (no Hub file was read from here; the values were gathered, in the project's
research notes, from the diffusers 0.42.1 classes, the CogVideoX conversion
script ``scripts/convert_cogvideox_to_diffusers.py``, the SAT configs of THUDM/CogVideo and
a mirror of the ModelScope ``unet/config.json``): every field below equals the published
``config.json`` / ``scheduler_config.json`` as far as those sources show. The loaders
never use these: a real model directory's own configs are always read.

``TINY`` variants keep every structural choice of their model (block types, latent
channels, compression ratios, patching, RoPE or sin-cos, text length, schedule) and shrink
widths and depths so a CPU can run them (``bench prior --size tiny``).
"""

from __future__ import annotations

import copy

__all__ = ["MODELS", "model_config"]

_COG_SCHEDULER = {
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "clip_sample": False,
    "num_train_timesteps": 1000,
    "prediction_type": "v_prediction",
    "rescale_betas_zero_snr": True,
    "set_alpha_to_one": True,
    "timestep_spacing": "trailing",
    "steps_offset": 0,
}

_COG_VAE = {
    "in_channels": 3,
    "out_channels": 3,
    "down_block_types": ["CogVideoXDownBlock3D"] * 4,
    "up_block_types": ["CogVideoXUpBlock3D"] * 4,
    "block_out_channels": [128, 256, 256, 512],
    "latent_channels": 16,
    "layers_per_block": 3,
    "act_fn": "silu",
    "norm_eps": 1e-6,
    "norm_num_groups": 32,
    "temporal_compression_ratio": 4,
    "sample_height": 480,
    "sample_width": 720,
    "use_quant_conv": False,
    "use_post_quant_conv": False,
}

_COG_TRANSFORMER = {
    "in_channels": 16,
    "out_channels": 16,
    "attention_head_dim": 64,
    "time_embed_dim": 512,
    "text_embed_dim": 4096,
    "patch_size": 2,
    "sample_frames": 49,
    "sample_height": 60,
    "sample_width": 90,
    "max_text_seq_length": 226,
    "temporal_compression_ratio": 4,
    "flip_sin_to_cos": True,
    "freq_shift": 0,
    "activation_fn": "gelu-approximate",
    "timestep_activation_fn": "silu",
    "norm_elementwise_affine": True,
    "norm_eps": 1e-5,
    "spatial_interpolation_scale": 1.875,
    "temporal_interpolation_scale": 1.0,
}

# google/t5-v1_1-xxl encoder (the text encoder of both CogVideoX models).
_T5_XXL = {
    "vocab_size": 32128,
    "d_model": 4096,
    "d_kv": 64,
    "d_ff": 10240,
    "num_layers": 24,
    "num_heads": 64,
    "relative_attention_num_buckets": 32,
    "relative_attention_max_distance": 128,
    "feed_forward_proj": "gated-gelu",
    "is_gated_act": True,
    "dense_act_fn": "gelu_new",
}

MODELS: dict[str, dict] = {
    "cogvideox-2b": {
        "prior": "cogvideox",
        "hub_id": "THUDM/CogVideoX-2b",
        "cuda_dtype": "float16",
        "scheduler": {"class": "CogVideoXDDIMScheduler", **_COG_SCHEDULER, "snr_shift_scale": 3.0},
        "vae": {"class": "AutoencoderKLCogVideoX", **_COG_VAE, "scaling_factor": 1.15258426},
        "denoiser": {
            "class": "CogVideoXTransformer3DModel",
            **_COG_TRANSFORMER,
            "num_attention_heads": 30,
            "num_layers": 30,
            "use_rotary_positional_embeddings": False,
        },
        "text_encoder": {"class": "T5EncoderModel", **_T5_XXL},
        "num_frames": 17,
    },
    "cogvideox-5b": {
        "prior": "cogvideox",
        "hub_id": "THUDM/CogVideoX-5b",
        "cuda_dtype": "bfloat16",
        "scheduler": {"class": "CogVideoXDDIMScheduler", **_COG_SCHEDULER, "snr_shift_scale": 1.0},
        "vae": {"class": "AutoencoderKLCogVideoX", **_COG_VAE, "scaling_factor": 0.7},
        "denoiser": {
            "class": "CogVideoXTransformer3DModel",
            **_COG_TRANSFORMER,
            "num_attention_heads": 48,
            "num_layers": 42,
            "use_rotary_positional_embeddings": True,
        },
        "text_encoder": {"class": "T5EncoderModel", **_T5_XXL},
        "num_frames": 17,
    },
    "modelscope": {
        "prior": "modelscope",
        "hub_id": "ali-vilab/text-to-video-ms-1.7b",
        "cuda_dtype": "float16",
        "scheduler": {
            "class": "DDIMScheduler",
            "beta_start": 0.00085,
            "beta_end": 0.012,
            "beta_schedule": "scaled_linear",
            "clip_sample": False,
            "num_train_timesteps": 1000,
            "prediction_type": "epsilon",
            "set_alpha_to_one": False,
            "steps_offset": 1,
        },
        "vae": {
            "class": "AutoencoderKL",
            "in_channels": 3,
            "out_channels": 3,
            "down_block_types": ["DownEncoderBlock2D"] * 4,
            "up_block_types": ["UpDecoderBlock2D"] * 4,
            "block_out_channels": [128, 256, 512, 512],
            "layers_per_block": 2,
            "latent_channels": 4,
            "norm_num_groups": 32,
            "sample_size": 256,
            "scaling_factor": 0.18215,
        },
        "denoiser": {
            "class": "UNet3DConditionModel",
            "in_channels": 4,
            "out_channels": 4,
            "down_block_types": ["CrossAttnDownBlock3D"] * 3 + ["DownBlock3D"],
            "up_block_types": ["UpBlock3D"] + ["CrossAttnUpBlock3D"] * 3,
            "block_out_channels": [320, 640, 1280, 1280],
            "layers_per_block": 2,
            "attention_head_dim": 64,
            "cross_attention_dim": 1024,
            "norm_num_groups": 32,
            "sample_size": 32,
        },
        # OpenCLIP ViT-H/14 text tower, as converted for the pipeline.
        "text_encoder": {
            "class": "CLIPTextModel",
            "hidden_size": 1024,
            "intermediate_size": 4096,
            "num_hidden_layers": 23,
            "num_attention_heads": 16,
            "max_position_embeddings": 77,
            "vocab_size": 49408,
            "hidden_act": "gelu",
        },
        "num_frames": 16,
    },
}

_TINY_OVERRIDES: dict[str, dict] = {
    "cogvideox-2b": {
        "vae": {"block_out_channels": [8, 8, 8, 8], "layers_per_block": 1, "norm_num_groups": 2},
        "denoiser": {
            "num_attention_heads": 2,
            "attention_head_dim": 16,
            "num_layers": 1,
            "time_embed_dim": 8,
            "text_embed_dim": 32,
        },
        "text_encoder": {"d_model": 32, "d_kv": 8, "d_ff": 37, "num_layers": 1, "num_heads": 4},
    },
    "cogvideox-5b": {
        "vae": {"block_out_channels": [8, 8, 8, 8], "layers_per_block": 1, "norm_num_groups": 2},
        "denoiser": {
            "num_attention_heads": 2,
            "attention_head_dim": 16,
            "num_layers": 1,
            "time_embed_dim": 8,
            "text_embed_dim": 32,
        },
        "text_encoder": {"d_model": 32, "d_kv": 8, "d_ff": 37, "num_layers": 1, "num_heads": 4},
    },
    "modelscope": {
        "vae": {"block_out_channels": [8, 8, 8, 8], "layers_per_block": 1, "norm_num_groups": 2},
        "denoiser": {
            "block_out_channels": [8, 8, 16, 16],
            "layers_per_block": 1,
            "attention_head_dim": 4,
            "cross_attention_dim": 32,
            "norm_num_groups": 4,
        },
        "text_encoder": {
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 1,
            "num_attention_heads": 2,
        },
    },
}


def model_config(model: str, size: str = "full") -> dict:
    """The recorded configuration of ``model`` (``full``: as published; ``tiny``: shrunk)."""
    if model not in MODELS:
        raise KeyError(model)
    cfg = copy.deepcopy(MODELS[model])
    if size == "tiny":
        for part, over in _TINY_OVERRIDES[model].items():
            cfg[part].update(over)
    elif size != "full":
        raise ValueError(f"size must be 'tiny' or 'full', got {size!r}")
    return cfg
