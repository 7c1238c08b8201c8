"""CLIPSIM and OC with tiny random weights saved in the official on-disk layouts.

CLIP: a tiny ``transformers.CLIPModel`` + tokenizer files via ``save_pretrained``.
ViCLIP: a ``{"model": state_dict}`` .pth whose keys are written out here by hand in the
official ViClip-InternVid-10M-FLT.pth layout (not taken from our module), loaded
strictly through ``metrics.viclip.load_viclip``; the score is checked against an
independent functional forward written in this file.
"""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
from motionphysics.errors import UserInputError  # noqa: E402
from motionphysics.metrics.clip import CLIP_MEAN, CLIP_STD, clipsim, openai_preprocess  # noqa: E402
from motionphysics.metrics.viclip import (  # noqa: E402
    BPETokenizer,
    _bytes_to_unicode,
    frame_indices,
    overall_consistency,
    vbench_preprocess,
)

MERGES = ["t h", "th e</w>", "l l</w>", "b a", "ba ll</w>", "w a", "wa t", "e r</w>", "o u", "n c"]


def _vocab():
    base = list(_bytes_to_unicode().values())
    vocab = base + [b + "</w>" for b in base] + ["".join(m.split()) for m in MERGES]
    return vocab + ["<|startoftext|>", "<|endoftext|>"]


def _write_bpe(path):
    with gzip.open(path, "wt", encoding="utf-8") as f:
        f.write("#version: test\n" + "\n".join(MERGES) + "\n")
    return path


def test_bpe_tokenizer_merges_and_context():
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        tok = BPETokenizer(_write_bpe(Path(d) / "bpe_simple_vocab_16e6.txt.gz"))
    vocab = _vocab()
    assert tok.vocab_size == len(vocab) == 512 + len(MERGES) + 2
    ids = tok.encode("The BALL &amp; water")
    assert [vocab[i] for i in ids] == ["the</w>", "ball</w>", "&</w>", "wat", "er</w>"]
    t = tok.tokenize("the ball", context_length=6)[0].tolist()
    assert t == [tok.sot, vocab.index("the</w>"), vocab.index("ball</w>"), tok.eot, 0, 0]
    long = tok.tokenize("the " * 40, context_length=8)[0].tolist()
    assert len(long) == 8 and long[-1] == tok.eot and long[0] == tok.sot


def test_openai_preprocess_matches_hand_computed_reference():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(7, 4, 3), dtype=np.uint8)  # H=7, W=4: short side = n_px
    out = openai_preprocess(img, n_px=4)
    # no resize (short side already 4); crop top = round((7 - 4) / 2) = round(1.5) = 2
    ref = np.empty((3, 4, 4), np.float32)
    for c in range(3):
        for i in range(4):
            for j in range(4):
                ref[c, i, j] = (img[2 + i, j, c] / 255.0 - CLIP_MEAN[c]) / CLIP_STD[c]
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-6)
    # even margin, W=9 -> left = round(2.5) = 2 (half to even, as torchvision)
    img2 = rng.integers(0, 256, size=(5, 9, 3), dtype=np.uint8)
    out2 = openai_preprocess(img2, n_px=5)
    np.testing.assert_allclose(
        out2[0], (img2[:, 2:7, 0] / 255.0 - CLIP_MEAN[0]) / CLIP_STD[0], atol=1e-6
    )
    # a constant image stays constant through the bicubic resize
    flat = np.full((30, 50, 3), 77, np.uint8)
    np.testing.assert_allclose(
        openai_preprocess(flat, 8)[1], (77 / 255 - CLIP_MEAN[1]) / CLIP_STD[1], atol=1e-6
    )
    assert openai_preprocess(flat, 8).shape == (3, 8, 8)


def test_vbench_preprocess_and_frame_indices():
    assert frame_indices(8, 150) == [8, 27, 46, 65, 83, 102, 121, 140]
    assert frame_indices(8, 4) == [0, 0, 0, 1, 1, 2, 2, 3] or len(frame_indices(8, 4)) == 8
    img = np.random.default_rng(1).integers(0, 256, size=(1, 6, 9, 3), dtype=np.uint8)
    x = vbench_preprocess(img, n_px=6)  # no resize; left = round(1.5) = 2
    ref = (img[0, :, 2:8, 0] / 255.0 - CLIP_MEAN[0]) / CLIP_STD[0]
    np.testing.assert_allclose(x[0, 0].numpy(), ref, atol=1e-6)


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory):
    from transformers import CLIPConfig, CLIPModel

    d = tmp_path_factory.mktemp("clip")
    vocab = _vocab()
    cfg = CLIPConfig(
        text_config=dict(
            vocab_size=len(vocab),
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
            max_position_embeddings=16,
            bos_token_id=len(vocab) - 2,
            eos_token_id=len(vocab) - 1,
            pad_token_id=len(vocab) - 1,
        ),
        vision_config=dict(
            image_size=32,
            patch_size=8,
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
        ),
        projection_dim=16,
    )
    torch.manual_seed(0)
    CLIPModel(cfg).save_pretrained(d)
    (d / "vocab.json").write_text(json.dumps({t: i for i, t in enumerate(vocab)}))
    (d / "merges.txt").write_text("#version: 0.2\n" + "\n".join(MERGES) + "\n")
    return d


def test_clipsim_against_the_model_forward(clip_dir):
    from transformers import CLIPModel, CLIPTokenizer

    rng = np.random.default_rng(2)
    frames = rng.integers(0, 256, size=(3, 40, 50, 3), dtype=np.uint8)
    out = clipsim(frames, "the ball", clip_dir)
    assert out["frames"] == 3 and len(out["per_frame"]) == 3 and out["image_size"] == 32
    model = CLIPModel.from_pretrained(clip_dir).eval()
    tok = CLIPTokenizer.from_pretrained(clip_dir)
    ids = tok(["the ball"], return_tensors="pt")
    px = torch.from_numpy(np.stack([openai_preprocess(f, 32) for f in frames]))
    with torch.no_grad():
        o = model(input_ids=ids["input_ids"], attention_mask=ids["attention_mask"], pixel_values=px)
        cos = (o.logits_per_image[:, 0] / model.logit_scale.exp()).numpy()
    np.testing.assert_allclose(out["per_frame"], cos, atol=1e-5)
    assert out["clipsim"] == pytest.approx(float(cos.mean()), abs=1e-5)
    assert all(-1.0 <= c <= 1.0 for c in out["per_frame"])


def test_clip_dir_without_weights_is_user_error(tmp_path):
    with pytest.raises(UserInputError, match="config.json"):
        clipsim(np.zeros((1, 8, 8, 3), np.uint8), "x", tmp_path)


# ------------------------------------------------------------------ ViCLIP, official key layout
V = dict(width=128, layers=2, patch=4, res=16, frames=8, out=32, twidth=64, tlayers=2, ctx=32)


def _block_keys(prefix, d):
    return {
        f"{prefix}.attn.in_proj_weight": (3 * d, d),
        f"{prefix}.attn.in_proj_bias": (3 * d,),
        f"{prefix}.attn.out_proj.weight": (d, d),
        f"{prefix}.attn.out_proj.bias": (d,),
        f"{prefix}.ln_1.weight": (d,),
        f"{prefix}.ln_1.bias": (d,),
        f"{prefix}.mlp.c_fc.weight": (4 * d, d),
        f"{prefix}.mlp.c_fc.bias": (4 * d,),
        f"{prefix}.mlp.c_proj.weight": (d, 4 * d),
        f"{prefix}.mlp.c_proj.bias": (d,),
        f"{prefix}.ln_2.weight": (d,),
        f"{prefix}.ln_2.bias": (d,),
    }


def official_layout(vocab_size):
    w, tw = V["width"], V["twidth"]
    shapes = {
        "temp": (),
        "vision_encoder.conv1.weight": (w, 3, 1, V["patch"], V["patch"]),
        "vision_encoder.class_embedding": (w,),
        "vision_encoder.positional_embedding": ((V["res"] // V["patch"]) ** 2 + 1, w),
        "vision_encoder.temporal_positional_embedding": (1, V["frames"], w),
        "vision_encoder.ln_pre.weight": (w,),
        "vision_encoder.ln_pre.bias": (w,),
        "vision_encoder.ln_post.weight": (w,),
        "vision_encoder.ln_post.bias": (w,),
        "vision_encoder.proj": (w, V["out"]),
        "text_encoder.token_embedding.weight": (vocab_size, tw),
        "text_encoder.positional_embedding": (V["ctx"], tw),
        "text_encoder.ln_final.weight": (tw,),
        "text_encoder.ln_final.bias": (tw,),
        "text_encoder.text_projection": (tw, V["out"]),
    }
    for i in range(V["layers"]):
        shapes.update(_block_keys(f"vision_encoder.transformer.resblocks.{i}", w))
    for i in range(V["tlayers"]):
        shapes.update(_block_keys(f"text_encoder.transformer.resblocks.{i}", tw))
    g = torch.Generator().manual_seed(3)
    sd = {}
    for k, s in shapes.items():
        t = torch.randn(s, generator=g) * (0.2 if len(s) != 1 else 0.05)
        if k.endswith(
            ("ln_1.weight", "ln_2.weight", "ln_pre.weight", "ln_post.weight", "ln_final.weight")
        ):
            t = 1.0 + t
        sd[k] = t
    return sd


def _ref_block(x, sd, p, heads, mask=None):
    """Pre-LN block, sequence-first [N, B, d], from raw tensors (independent of nn.MHA)."""
    import torch.nn.functional as F

    N, B, d = x.shape
    h = F.layer_norm(x, (d,), sd[p + ".ln_1.weight"], sd[p + ".ln_1.bias"], 1e-5)
    qkv = h @ sd[p + ".attn.in_proj_weight"].T + sd[p + ".attn.in_proj_bias"]
    q, k, v = qkv.split(d, -1)

    def heads_(t):
        return t.reshape(N, B, heads, d // heads).permute(1, 2, 0, 3)  # [B, H, N, dh]

    q, k, v = heads_(q), heads_(k), heads_(v)
    a = q @ k.transpose(-1, -2) / math.sqrt(d // heads)
    if mask is not None:
        a = a + mask
    o = (a.softmax(-1) @ v).permute(2, 0, 1, 3).reshape(N, B, d)
    x = x + o @ sd[p + ".attn.out_proj.weight"].T + sd[p + ".attn.out_proj.bias"]
    h = F.layer_norm(x, (d,), sd[p + ".ln_2.weight"], sd[p + ".ln_2.bias"], 1e-5)
    h = h @ sd[p + ".mlp.c_fc.weight"].T + sd[p + ".mlp.c_fc.bias"]
    h = h * torch.sigmoid(1.702 * h)
    return x + h @ sd[p + ".mlp.c_proj.weight"].T + sd[p + ".mlp.c_proj.bias"]


def _ref_oc(sd, video, ids):
    import torch.nn.functional as F

    w, P = V["width"], V["patch"]
    T = video.shape[0]
    # patches of every frame: [T, n, 3*P*P] @ conv weight
    patches = video.unfold(2, P, P).unfold(3, P, P)  # [T, 3, h, w, P, P]
    patches = patches.permute(0, 2, 3, 1, 4, 5).reshape(T, -1, 3 * P * P)
    x = patches @ sd["vision_encoder.conv1.weight"].reshape(w, -1).T  # [T, n, w]
    pos = sd["vision_encoder.positional_embedding"]
    cls = sd["vision_encoder.class_embedding"] + pos[0]
    x = x + pos[1:] + sd["vision_encoder.temporal_positional_embedding"][0][:, None, :]
    x = torch.cat([cls[None], x.reshape(-1, w)], 0)[:, None, :]  # token order is irrelevant
    x = F.layer_norm(
        x, (w,), sd["vision_encoder.ln_pre.weight"], sd["vision_encoder.ln_pre.bias"], 1e-5
    )
    for i in range(V["layers"]):
        x = _ref_block(x, sd, f"vision_encoder.transformer.resblocks.{i}", w // 64)
    x = F.layer_norm(
        x, (w,), sd["vision_encoder.ln_post.weight"], sd["vision_encoder.ln_post.bias"], 1e-5
    )
    v = x[0, 0] @ sd["vision_encoder.proj"]
    tw = V["twidth"]
    t = sd["text_encoder.token_embedding.weight"][ids] + sd["text_encoder.positional_embedding"]
    t = t[:, None, :]
    mask = torch.full((V["ctx"], V["ctx"]), float("-inf")).triu(1)
    for i in range(V["tlayers"]):
        t = _ref_block(t, sd, f"text_encoder.transformer.resblocks.{i}", tw // 64, mask)
    t = F.layer_norm(
        t, (tw,), sd["text_encoder.ln_final.weight"], sd["text_encoder.ln_final.bias"], 1e-5
    )
    te = t[int(ids.argmax()), 0] @ sd["text_encoder.text_projection"]
    return float((v / v.norm()) @ (te / te.norm()))


@pytest.fixture(scope="module")
def viclip_pth(tmp_path_factory):
    d = tmp_path_factory.mktemp("viclip")
    _write_bpe(d / "bpe_simple_vocab_16e6.txt.gz")
    sd = official_layout(len(_vocab()))
    torch.save({"model": sd}, d / "ViClip-InternVid-10M-FLT.pth")
    return d / "ViClip-InternVid-10M-FLT.pth", sd


def test_viclip_strict_load_and_oc_matches_reference(viclip_pth):
    pth, sd = viclip_pth
    rng = np.random.default_rng(4)
    frames = rng.integers(0, 256, size=(20, 18, 24, 3), dtype=np.uint8)
    out = overall_consistency(frames, "the ball falls", pth)
    assert out["frame_indices"] == frame_indices(8, 20)
    video = vbench_preprocess(frames[out["frame_indices"]], V["res"])
    tok = BPETokenizer(pth.parent / "bpe_simple_vocab_16e6.txt.gz")
    ids = tok.tokenize("the ball falls", V["ctx"])[0]
    ref = _ref_oc(sd, video, ids)
    assert out["oc"] == pytest.approx(ref, abs=1e-5)
    assert -1.0 <= out["oc"] <= 1.0


def test_viclip_missing_or_extra_key_is_refused(viclip_pth, tmp_path):
    pth, sd = viclip_pth
    _write_bpe(tmp_path / "bpe_simple_vocab_16e6.txt.gz")
    frames = np.zeros((8, 16, 16, 3), np.uint8)
    bad = dict(sd)
    bad.pop("vision_encoder.temporal_positional_embedding")
    torch.save({"model": bad}, tmp_path / "a.pth")
    with pytest.raises(UserInputError, match="a.pth"):
        overall_consistency(frames, "x", tmp_path / "a.pth")
    extra = dict(sd)
    extra["vision_encoder.unexpected"] = torch.zeros(1)
    torch.save({"model": extra}, tmp_path / "b.pth")
    with pytest.raises(UserInputError, match="does not match"):
        overall_consistency(frames, "x", tmp_path / "b.pth")
    (tmp_path / "bpe_simple_vocab_16e6.txt.gz").unlink()
    torch.save({"model": sd}, tmp_path / "c.pth")
    with pytest.raises(UserInputError, match="viclip-bpe"):
        overall_consistency(frames, "x", tmp_path / "c.pth")
