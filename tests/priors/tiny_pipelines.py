"""Tiny seeded random CogVideoX and ModelScope pipelines written in the real on-disk
layout (``save_pretrained``), with tokenizers built offline. Reusable by other suites:

    from tests.priors.tiny_pipelines import write_tiny_cogvideox, write_tiny_modelscope
    write_tiny_cogvideox(tmp_path / "cog")      # -> a directory for --prior-path

The components follow diffusers' own dummy components (tests/pipelines/cogvideo and
text_to_video_synthesis), with the text encoder's width matched to the transformer /
UNet. The T5 tokenizer is a sentencepiece unigram model trained here on a few sentences;
the CLIP tokenizer is a byte-level BPE over the byte alphabet plus a few merges.
"""

from __future__ import annotations

import io
from pathlib import Path

CORPUS = [
    "a rubber ball bounces on the floor and comes back",
    "a soft jelly wobbles after it is pushed",
    "the metal bar bends under the load",
    "sand flows down the slope",
    "honey drips slowly from the spoon",
    "a plush toy squashes and recovers",
    "the telephone cord is gently vibrating",
]


def tiny_t5_tokenizer():
    """A sentencepiece (unigram) T5 tokenizer trained offline on :data:`CORPUS`."""
    import sentencepiece as spm
    from transformers import T5Tokenizer

    buf = io.BytesIO()
    spm.SentencePieceTrainer.train(
        sentence_iterator=iter(CORPUS * 4),
        model_writer=buf,
        vocab_size=80,
        model_type="unigram",
        pad_id=0,
        eos_id=1,
        unk_id=2,
        bos_id=-1,
        hard_vocab_limit=False,
        minloglevel=2,
    )
    sp = spm.SentencePieceProcessor(model_proto=buf.getvalue())
    vocab = [(sp.id_to_piece(i), sp.get_score(i)) for i in range(sp.get_piece_size())]
    return T5Tokenizer(vocab=vocab, extra_ids=0)


def _bytes_to_unicode() -> dict[int, str]:
    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1))
    bs += list(range(ord("®"), ord("ÿ") + 1))
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, [chr(c) for c in cs], strict=True))


def tiny_clip_tokenizer(model_max_length: int = 16):
    """A byte-level BPE CLIP tokenizer (byte alphabet, a few merges), built offline."""
    from transformers import CLIPTokenizer

    chars = list(_bytes_to_unicode().values())
    vocab: dict[str, int] = {}
    for c in chars + [c + "</w>" for c in chars]:
        vocab.setdefault(c, len(vocab))
    merges = [
        ("t", "h"),
        ("th", "e</w>"),
        ("a", "l"),
        ("al", "l</w>"),
        ("b", "o"),
        ("o", "u"),
        ("n", "c"),
    ]
    for m in merges:
        vocab.setdefault("".join(m), len(vocab))
    for special in ("<|startoftext|>", "<|endoftext|>"):
        vocab.setdefault(special, len(vocab))
    tok = CLIPTokenizer(vocab=vocab, merges=merges)
    tok.model_max_length = model_max_length
    return tok


def write_cogvideox_pipeline(
    directory, tokenizer, scheduler, *, seed: int, transformer: dict, vae: dict, text: dict,
    reseed: bool = True,
) -> Path:  # fmt: skip
    """Write a CogVideoX pipeline (T5 text encoder, 3-D VAE of four blocks, transformer,
    ``scheduler``) in diffusers' ``save_pretrained`` layout, from the keyword arguments of
    each component over the layout every builder here shares. The torch seed is set
    before the transformer and, with ``reseed``, again before the VAE and the text
    encoder."""
    import torch
    from diffusers import AutoencoderKLCogVideoX, CogVideoXPipeline, CogVideoXTransformer3DModel
    from transformers import T5Config, T5EncoderModel

    directory = Path(directory)
    torch.manual_seed(seed)
    net = CogVideoXTransformer3DModel(
        sample_width=2, sample_height=2, temporal_compression_ratio=4, **transformer
    )
    if reseed:
        torch.manual_seed(seed)
    vae_model = AutoencoderKLCogVideoX(
        in_channels=3,
        out_channels=3,
        down_block_types=("CogVideoXDownBlock3D",) * 4,
        up_block_types=("CogVideoXUpBlock3D",) * 4,
        layers_per_block=1,
        norm_num_groups=2,
        temporal_compression_ratio=4,
        **vae,
    )
    if reseed:
        torch.manual_seed(seed)
    text_encoder = T5EncoderModel(T5Config(vocab_size=len(tokenizer), **text))
    CogVideoXPipeline(
        tokenizer=tokenizer,
        text_encoder=text_encoder,
        vae=vae_model,
        transformer=net,
        scheduler=scheduler,
    ).save_pretrained(directory)
    return directory


def write_tiny_cogvideox(
    directory, *, rope: bool = False, v_prediction: bool = True, seed: int = 0
) -> Path:
    """Write a tiny CogVideoX pipeline (T5 + tokenizer, 3-D VAE, transformer, scheduler).

    ``rope``: the 5b-style transformer (rotary embeddings, no sin-cos table);
    ``v_prediction``: the CogVideoX DDIM scheduler of the published models (zero terminal
    SNR); otherwise a plain epsilon DDIM, as diffusers' dummy uses.
    Runs at 16x16 px, 9 frames -> latents [1, 3, 4, 2, 2]."""
    from diffusers import CogVideoXDDIMScheduler, DDIMScheduler

    if v_prediction:
        scheduler = CogVideoXDDIMScheduler(
            snr_shift_scale=3.0,
            beta_start=0.00085,
            beta_end=0.012,
            beta_schedule="scaled_linear",
            clip_sample=False,
            num_train_timesteps=1000,
            prediction_type="v_prediction",
            rescale_betas_zero_snr=True,
            set_alpha_to_one=True,
            timestep_spacing="trailing",
        )
    else:
        scheduler = DDIMScheduler()
    return write_cogvideox_pipeline(
        directory,
        tiny_t5_tokenizer(),
        scheduler,
        seed=seed,
        transformer={
            "num_attention_heads": 4,
            # RoPE splits the head dim 1/4 time + 3/8 + 3/8 space, each even: 16 is the least.
            "attention_head_dim": 16 if rope else 8,
            "in_channels": 4,
            "out_channels": 4,
            "time_embed_dim": 2,
            "text_embed_dim": 32,
            "num_layers": 1,
            "sample_frames": 9,
            "patch_size": 2,
            "max_text_seq_length": 16,
            "use_rotary_positional_embeddings": rope,
        },
        vae={"block_out_channels": (8, 8, 8, 8), "latent_channels": 4},
        text={
            "d_model": 32,
            "d_kv": 8,
            "d_ff": 37,
            "num_layers": 2,
            "num_heads": 4,
            "relative_attention_num_buckets": 8,
        },
    )


def write_modelscope_pipeline(
    directory, tokenizer, *, seed: int, unet: dict, vae: dict, text: dict,
    scheduler: dict | None = None, reseed: bool = True,
) -> Path:  # fmt: skip
    """Write a ModelScope T2V pipeline (CLIP text encoder, 2-D VAE, UNet3D, DDIM) in
    diffusers' ``save_pretrained`` layout, from the keyword arguments of each component
    over the layout every builder here shares (two-block UNet with cross-attention in
    the outer blocks, ``DownEncoderBlock2D`` VAE blocks, GELU CLIP). The torch seed is set
    before the UNet and, with ``reseed``, again before the VAE and the text encoder."""
    import torch
    from diffusers import AutoencoderKL, DDIMScheduler, TextToVideoSDPipeline, UNet3DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    directory = Path(directory)
    torch.manual_seed(seed)
    unet = UNet3DConditionModel(
        layers_per_block=1,
        down_block_types=("CrossAttnDownBlock3D", "DownBlock3D"),
        up_block_types=("UpBlock3D", "CrossAttnUpBlock3D"),
        attention_head_dim=4,
        **unet,
    )
    sched = DDIMScheduler(
        **(
            scheduler
            or {
                "beta_start": 0.00085,
                "beta_end": 0.012,
                "beta_schedule": "scaled_linear",
                "clip_sample": False,
                "set_alpha_to_one": False,
            }
        )
    )
    if reseed:
        torch.manual_seed(seed)
    blocks = vae.pop("blocks")
    vae_model = AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=["DownEncoderBlock2D"] * blocks,
        up_block_types=["UpDecoderBlock2D"] * blocks,
        **vae,
    )
    if reseed:
        torch.manual_seed(seed)
    text_encoder = CLIPTextModel(
        CLIPTextConfig(
            bos_token_id=tokenizer.bos_token_id,
            eos_token_id=tokenizer.eos_token_id,
            pad_token_id=tokenizer.pad_token_id,
            vocab_size=len(tokenizer),
            **text,
        )
    )
    TextToVideoSDPipeline(
        vae=vae_model, text_encoder=text_encoder, tokenizer=tokenizer, unet=unet, scheduler=sched
    ).save_pretrained(directory)
    return directory


def write_tiny_modelscope(directory, *, seed: int = 0) -> Path:
    """Write a tiny ModelScope T2V pipeline (CLIP + BPE tokenizer, 2-D VAE, UNet3D, DDIM).

    Runs at 16x16 px (VAE 2x, UNet 2x), 4 frames -> latents [1, 4, 4, 8, 8]."""
    return write_modelscope_pipeline(
        directory,
        tiny_clip_tokenizer(),
        seed=seed,
        unet={
            "block_out_channels": (4, 8),
            "sample_size": 8,
            "in_channels": 4,
            "out_channels": 4,
            "cross_attention_dim": 8,
            "norm_num_groups": 2,
        },
        vae={
            "blocks": 2,
            "block_out_channels": (8, 8),
            "latent_channels": 4,
            "sample_size": 16,
            "norm_num_groups": 2,
            "scaling_factor": 0.18215,
        },
        text={
            "hidden_size": 8,
            "intermediate_size": 16,
            "layer_norm_eps": 1e-05,
            "num_attention_heads": 2,
            "num_hidden_layers": 2,
            "max_position_embeddings": 16,
            "hidden_act": "gelu",
            "projection_dim": 8,
        },
    )


_CACHE: dict[str, Path] = {}


def tiny_dir(kind: str) -> Path:
    """A tiny pipeline directory written once per test process (``cogvideox``: 2b-style,
    v-prediction; ``cogvideox-rope``: 5b-style; ``cogvideox-eps``: epsilon DDIM as in
    diffusers' dummy; ``modelscope``). Removed at exit."""
    import atexit
    import shutil
    import tempfile

    if kind not in _CACHE:
        root = Path(tempfile.mkdtemp(prefix=f"mp-tiny-{kind}-"))
        atexit.register(shutil.rmtree, root, True)
        if kind == "cogvideox":
            write_tiny_cogvideox(root)
        elif kind == "cogvideox-rope":
            write_tiny_cogvideox(root, rope=True)
        elif kind == "cogvideox-eps":
            write_tiny_cogvideox(root, v_prediction=False)
        elif kind == "modelscope":
            write_tiny_modelscope(root)
        else:
            raise ValueError(kind)
        _CACHE[kind] = root
    return _CACHE[kind]


# Sizes the tiny pipelines run at (prior options for load_prior).
TINY_OPTIONS = {
    "cogvideox": {"num_frames": 9, "height": 16, "width": 16},
    "cogvideox-rope": {"num_frames": 9, "height": 16, "width": 16},
    "cogvideox-eps": {"num_frames": 9, "height": 16, "width": 16},
    "modelscope": {"num_frames": 4, "height": 16, "width": 16},
}


def load_tiny(kind: str, **options):
    """Load the tiny pipeline ``kind`` through the real loading code (``load_prior``)."""
    from motionphysics.priors import load_prior

    name = "modelscope" if kind == "modelscope" else "cogvideox"
    return load_prior(name, str(tiny_dir(kind)), **{**TINY_OPTIONS[kind], **options})


def write_diffusers_dummy_modelscope(directory, *, seed: int = 0) -> Path:
    """ModelScope with exactly diffusers' own dummy components (the removed
    tests/pipelines/text_to_video_synthesis test: a one-block VAE of spatial scale 1,
    sample_size 32, CLIP width 4), a different layout from :func:`write_tiny_modelscope`."""
    return write_modelscope_pipeline(
        directory,
        tiny_clip_tokenizer(model_max_length=77),
        seed=seed,
        unet={
            "block_out_channels": (4, 8),
            "sample_size": 32,
            "in_channels": 4,
            "out_channels": 4,
            "cross_attention_dim": 4,
            "norm_num_groups": 2,
        },
        vae={
            "blocks": 1,
            "block_out_channels": (8,),
            "latent_channels": 4,
            "sample_size": 32,
            "norm_num_groups": 2,
        },
        text={
            "hidden_size": 4,
            "intermediate_size": 16,
            "layer_norm_eps": 1e-05,
            "num_attention_heads": 2,
            "num_hidden_layers": 2,
            "hidden_act": "gelu",
            "projection_dim": 32,
        },
    )
