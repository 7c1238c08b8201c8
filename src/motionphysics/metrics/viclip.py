"""OC: VBench's overall consistency with ViCLIP, re-implemented so the official
``ViClip-InternVid-10M-FLT.pth`` loads STRICTLY from a local path.

Architecture (VBench ``third_party/ViCLIP``; key names are the checkpoint's):

- ``vision_encoder``: ViT-L/14 over 8 frames. ``conv1`` Conv3d(3, 1024, (1, 14, 14),
  no bias), ``class_embedding`` [1024], ``positional_embedding`` [257, 1024],
  ``temporal_positional_embedding`` [1, 8, 1024] (added to the patch tokens only),
  ``ln_pre``, 24 pre-LN residual blocks (``nn.MultiheadAttention``, MLP ``c_fc`` ->
  QuickGELU -> ``c_proj``) attending jointly over the 8 x 256 patch tokens plus one
  CLS token, ``ln_post``, ``proj`` [1024, 768] applied to the CLS token.
- ``text_encoder``: the CLIP text tower with a 32-token context: ``token_embedding``
  [49408, 768], ``positional_embedding`` [32, 768], 12 causal blocks, ``ln_final``,
  ``text_projection`` [768, 768], pooled at the end-of-text token (``argmax`` of ids).
- ``temp`` (the contrastive temperature; loaded, unused by the score).

Sizes are read from the checkpoint's tensor shapes (heads = width / 64, CLIP's head
width in every released model), so the same loader serves the official file and the
tiny random checkpoints of the tests; the load itself is ``strict=True``.

Tokenizer: OpenAI CLIP's byte-level BPE (:class:`BPETokenizer`) from
``bpe_simple_vocab_16e6.txt.gz`` (or a transformers ``merges.txt``, the same merges),
text cleaned with ftfy + html unescape + whitespace collapse + lower case;
``[SOT] + bpe + [EOT]`` zero-padded to 32; longer prompts are cut to 32 with the last
token forced to EOT.

Score (VBench ``overall_consistency``): 8 frames at the middle of 8 equal intervals
(``linspace(0, n, 9)``), each resized (short side 224, bicubic, no antialias, on the
uint8 tensor so the result is re-quantised), centre-cropped 224 (offset rounded),
``/255`` and normalised with CLIP's mean / std; OC = cosine of the L2-normalised video
and text embeddings (raw; papers print x100).
"""

from __future__ import annotations

import gzip
import html
import math
from collections import OrderedDict
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError

__all__ = [
    "BPETokenizer",
    "ViCLIP",
    "load_viclip",
    "frame_indices",
    "vbench_preprocess",
    "overall_consistency",
    "BPE_FILE",
]

BPE_FILE = "bpe_simple_vocab_16e6.txt.gz"
N_MERGES = 49152 - 256 - 2
"""Merges OpenAI's tokenizer reads (lines 1..48894 of the vocabulary file)."""


# ---------------------------------------------------------------------------- tokenizer
@lru_cache
def _bytes_to_unicode() -> dict[int, str]:
    """OpenAI / GPT-2's reversible byte -> printable unicode map."""
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


def _read_merges(path: Path) -> list[tuple[str, str]]:
    try:
        raw = gzip.open(path).read() if path.suffix == ".gz" else path.read_bytes()
        lines = raw.decode("utf-8").split("\n")
    except (OSError, UnicodeDecodeError) as err:
        raise UserInputError(f"{path}: not a BPE merges file ({err})") from None
    merges = [tuple(line.split()) for line in lines[1 : N_MERGES + 1] if line.strip()]
    if not merges or any(len(m) != 2 for m in merges):
        raise UserInputError(
            f"{path}: not a BPE merges file (expected 'a b' pairs after a header line)"
        )
    return merges  # type: ignore[return-value]


class BPETokenizer:
    """OpenAI CLIP's tokenizer (the one ViCLIP uses), from a merges file."""

    def __init__(self, bpe_path: str | Path):
        import regex

        self.byte_encoder = _bytes_to_unicode()
        merges = _read_merges(Path(bpe_path))
        vocab = list(self.byte_encoder.values())
        vocab = vocab + [v + "</w>" for v in vocab]
        vocab += ["".join(m) for m in merges]
        vocab += ["<|startoftext|>", "<|endoftext|>"]
        self.encoder = {v: i for i, v in enumerate(vocab)}
        self.bpe_ranks = {m: i for i, m in enumerate(merges)}
        self.cache = {"<|startoftext|>": "<|startoftext|>", "<|endoftext|>": "<|endoftext|>"}
        self.pat = regex.compile(
            r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+""",
            regex.IGNORECASE,
        )
        self.sot = self.encoder["<|startoftext|>"]
        self.eot = self.encoder["<|endoftext|>"]
        self.vocab_size = len(vocab)

    def _bpe(self, token: str) -> str:
        if token in self.cache:
            return self.cache[token]
        word = tuple(token[:-1]) + (token[-1] + "</w>",)
        while len(word) > 1:
            pairs = {(word[i], word[i + 1]) for i in range(len(word) - 1)}
            best = min(pairs, key=lambda p: self.bpe_ranks.get(p, math.inf))
            if best not in self.bpe_ranks:
                break
            first, second = best
            new: list[str] = []
            i = 0
            while i < len(word):
                if i < len(word) - 1 and word[i] == first and word[i + 1] == second:
                    new.append(first + second)
                    i += 2
                else:
                    new.append(word[i])
                    i += 1
            word = tuple(new)
        out = " ".join(word)
        self.cache[token] = out
        return out

    @staticmethod
    def clean(text: str) -> str:
        import re

        import ftfy

        text = html.unescape(html.unescape(ftfy.fix_text(text))).strip()
        return re.sub(r"\s+", " ", text).strip().lower()

    def encode(self, text: str) -> list[int]:
        ids: list[int] = []
        for token in self.pat.findall(self.clean(text)):
            token = "".join(self.byte_encoder[b] for b in token.encode("utf-8"))
            ids.extend(self.encoder[t] for t in self._bpe(token).split(" "))
        return ids

    def tokenize(self, text: str, context_length: int = 32):
        """ids [1, context_length] int64: SOT + bpe + EOT, zero-padded; cut with EOT last."""
        import torch

        tokens = [self.sot, *self.encode(text), self.eot]
        if len(tokens) > context_length:
            tokens = tokens[:context_length]
            tokens[-1] = self.eot
        out = torch.zeros(1, context_length, dtype=torch.long)
        out[0, : len(tokens)] = torch.tensor(tokens)
        return out


# ---------------------------------------------------------------------------- model
def _modules():
    """The torch modules, built on first use (torch is imported lazily)."""
    import torch
    from torch import nn

    class QuickGELU(nn.Module):
        def forward(self, x):
            return x * torch.sigmoid(1.702 * x)

    class ResidualAttentionBlock(nn.Module):
        def __init__(self, d: int, heads: int):
            super().__init__()
            self.attn = nn.MultiheadAttention(d, heads)
            self.ln_1 = nn.LayerNorm(d)
            self.mlp = nn.Sequential(
                OrderedDict(
                    [
                        ("c_fc", nn.Linear(d, 4 * d)),
                        ("gelu", QuickGELU()),
                        ("c_proj", nn.Linear(4 * d, d)),
                    ]
                )
            )
            self.ln_2 = nn.LayerNorm(d)

        def forward(self, x, mask=None):  # x [N, B, d] (sequence first)
            h = self.ln_1(x)
            x = x + self.attn(h, h, h, need_weights=False, attn_mask=mask)[0]
            return x + self.mlp(self.ln_2(x))

    class Transformer(nn.Module):
        def __init__(self, width: int, layers: int, heads: int):
            super().__init__()
            self.resblocks = nn.ModuleList(
                [ResidualAttentionBlock(width, heads) for _ in range(layers)]
            )

        def forward(self, x, mask=None):
            for blk in self.resblocks:
                x = blk(x, mask)
            return x

    class VisionTransformer(nn.Module):
        def __init__(self, res, patch, width, layers, heads, out_dim, frames):
            super().__init__()
            self.conv1 = nn.Conv3d(3, width, (1, patch, patch), (1, patch, patch), bias=False)
            self.class_embedding = nn.Parameter(torch.zeros(width))
            self.positional_embedding = nn.Parameter(torch.zeros((res // patch) ** 2 + 1, width))
            self.temporal_positional_embedding = nn.Parameter(torch.zeros(1, frames, width))
            self.ln_pre = nn.LayerNorm(width)
            self.transformer = Transformer(width, layers, heads)
            self.ln_post = nn.LayerNorm(width)
            self.proj = nn.Parameter(torch.zeros(width, out_dim))

        def forward(self, x):  # x [B, 3, T, H, W]
            x = self.conv1(x)  # [B, C, T, h, w]
            B, C, T, h, w = x.shape
            x = x.permute(0, 2, 3, 4, 1).reshape(B * T, h * w, C)
            cls = self.class_embedding.to(x.dtype) + x.new_zeros(B * T, 1, C)
            x = torch.cat([cls, x], 1) + self.positional_embedding.to(x.dtype)
            cls_tokens = x[:B, :1]
            x = x[:, 1:].reshape(B, T, h * w, C).permute(0, 2, 1, 3)  # [B, n, T, C]
            if T == 1:
                x = x + self.temporal_positional_embedding.mean(1)
            else:
                x = x + self.temporal_positional_embedding
            x = x.reshape(B, h * w * T, C)  # tokens ordered (n t), as the original
            x = self.ln_pre(torch.cat([cls_tokens, x], 1))
            x = self.transformer(x.permute(1, 0, 2))
            x = self.ln_post(x)
            return x[0] @ self.proj

    class TextTransformer(nn.Module):
        def __init__(self, ctx, vocab, width, layers, heads, embed):
            super().__init__()
            self.context_length = ctx
            self.token_embedding = nn.Embedding(vocab, width)
            self.positional_embedding = nn.Parameter(torch.zeros(ctx, width))
            self.transformer = Transformer(width, layers, heads)
            self.ln_final = nn.LayerNorm(width)
            self.text_projection = nn.Parameter(torch.zeros(width, embed))
            # causal mask: a plain attribute, not a buffer (the checkpoint has no such key)
            self.attn_mask = torch.full((ctx, ctx), float("-inf")).triu_(1)

        def forward(self, ids):  # ids [B, ctx] int64
            x = self.token_embedding(ids) + self.positional_embedding
            mask = self.attn_mask.to(device=x.device, dtype=x.dtype)
            x = self.transformer(x.permute(1, 0, 2), mask).permute(1, 0, 2)
            x = self.ln_final(x)
            return x[torch.arange(x.shape[0]), ids.argmax(-1)] @ self.text_projection

    class _ViCLIP(nn.Module):
        def __init__(self, cfg: dict[str, int]):
            super().__init__()
            self.cfg = dict(cfg)
            self.vision_encoder = VisionTransformer(
                cfg["image_size"],
                cfg["patch"],
                cfg["vision_width"],
                cfg["vision_layers"],
                cfg["vision_width"] // 64,
                cfg["embed_dim"],
                cfg["num_frames"],
            )
            self.text_encoder = TextTransformer(
                cfg["context_length"],
                cfg["vocab_size"],
                cfg["text_width"],
                cfg["text_layers"],
                cfg["text_width"] // 64,
                cfg["text_embed_dim"],
            )
            self.temp = nn.Parameter(torch.ones([]) / 100.0)

        def encode_vision(self, video):  # [B, T, 3, H, W] normalised
            return self.vision_encoder(video.permute(0, 2, 1, 3, 4).contiguous())

        def encode_text(self, ids):
            return self.text_encoder(ids)

    return _ViCLIP


def ViCLIP(cfg: dict[str, int]):  # noqa: N802 - a class factory (torch imported lazily)
    """A ViCLIP module for the sizes in ``cfg`` (see :func:`config_from_state_dict`)."""
    return _modules()(cfg)


L14 = {
    "image_size": 224,
    "patch": 14,
    "vision_width": 1024,
    "vision_layers": 24,
    "embed_dim": 768,
    "num_frames": 8,
    "context_length": 32,
    "vocab_size": 49408,
    "text_width": 768,
    "text_layers": 12,
    "text_embed_dim": 768,
}
"""The official ViCLIP-L/14 (what ViClip-InternVid-10M-FLT.pth holds)."""


def config_from_state_dict(sd: dict[str, Any]) -> dict[str, int]:
    """Sizes of the architecture from a checkpoint's tensor shapes."""

    def count(prefix: str) -> int:
        ids = {int(k[len(prefix) :].split(".")[0]) for k in sd if k.startswith(prefix)}
        return max(ids) + 1 if ids else 0

    w = sd["vision_encoder.conv1.weight"]  # [width, 3, 1, patch, patch]
    patch = int(w.shape[-1])
    n_pos = int(sd["vision_encoder.positional_embedding"].shape[0])
    return {
        "image_size": int(round(math.sqrt(n_pos - 1))) * patch,
        "patch": patch,
        "vision_width": int(w.shape[0]),
        "vision_layers": count("vision_encoder.transformer.resblocks."),
        "embed_dim": int(sd["vision_encoder.proj"].shape[1]),
        "num_frames": int(sd["vision_encoder.temporal_positional_embedding"].shape[1]),
        "context_length": int(sd["text_encoder.positional_embedding"].shape[0]),
        "vocab_size": int(sd["text_encoder.token_embedding.weight"].shape[0]),
        "text_width": int(sd["text_encoder.token_embedding.weight"].shape[1]),
        "text_layers": count("text_encoder.transformer.resblocks."),
        "text_embed_dim": int(sd["text_encoder.text_projection"].shape[1]),
    }


def _find_bpe(pth: Path, bpe_path: str | Path | None) -> Path:
    if bpe_path is not None:
        p = Path(bpe_path)
        if not p.is_file():
            raise UserInputError(f"--viclip-bpe {p}: file not found")
        return p
    for name in (BPE_FILE, "merges.txt"):
        if (pth.parent / name).is_file():
            return pth.parent / name
    raise UserInputError(
        f"--viclip {pth}: no {BPE_FILE} (or merges.txt) beside it; pass --viclip-bpe PATH"
    )


def load_viclip(path: str | Path, *, bpe_path: str | Path | None = None, device: str = "cpu"):
    """(model, tokenizer) from a local ViCLIP checkpoint (``{"model": state_dict}``), strict."""
    import torch

    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"--viclip {p}: file not found")
    bpe = _find_bpe(p, bpe_path)
    try:
        ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure is a bad file
        raise UserInputError(
            f"--viclip {p}: not a torch checkpoint ({str(err).splitlines()[0]})"
        ) from None
    sd = ckpt.get("model", ckpt) if isinstance(ckpt, dict) else None
    if not isinstance(sd, dict) or "vision_encoder.conv1.weight" not in sd:
        raise UserInputError(
            f"--viclip {p}: expected {{'model': state_dict}} with vision_encoder.* / text_encoder.* keys"
        )
    try:
        model = ViCLIP(config_from_state_dict(sd))
        model.load_state_dict(sd, strict=True)
    except (RuntimeError, KeyError) as err:
        raise UserInputError(
            f"--viclip {p}: does not match the ViCLIP architecture ({str(err).splitlines()[0]})"
        ) from None
    tok = BPETokenizer(bpe)
    if tok.vocab_size != model.cfg["vocab_size"]:
        raise UserInputError(
            f"--viclip-bpe {bpe}: {tok.vocab_size} tokens, the checkpoint has {model.cfg['vocab_size']}"
        )
    return model.eval().to(device), tok


# ---------------------------------------------------------------------------- VBench protocol
def frame_indices(num_frames: int, vlen: int) -> list[int]:
    """VBench ``get_frame_indices(num_frames, vlen, sample='middle')``."""
    intervals = np.linspace(0, vlen, num_frames + 1).astype(int)
    idx = [(int(intervals[i]) + int(intervals[i + 1]) - 1) // 2 for i in range(num_frames)]
    idx = [min(max(i, 0), vlen - 1) for i in idx]
    if len(idx) < num_frames:  # pragma: no cover - linspace always gives num_frames ranges
        idx += [idx[-1]] * (num_frames - len(idx))
    return idx


def vbench_preprocess(frames: np.ndarray, n_px: int = 224):
    """uint8 [T, H, W, 3] -> float32 tensor [T, 3, n_px, n_px] (VBench ``clip_transform``)."""
    import torch
    import torch.nn.functional as F

    x = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float()
    T, _, h, w = x.shape
    nh, nw = (n_px, int(n_px * w / h)) if h <= w else (int(n_px * h / w), n_px)
    if (nh, nw) != (h, w):
        x = F.interpolate(x, size=(nh, nw), mode="bicubic", align_corners=False, antialias=False)
        x = x.clamp(0, 255).round()  # torchvision re-quantises a uint8 tensor
    top, left = int(round((nh - n_px) / 2.0)), int(round((nw - n_px) / 2.0))
    x = x[:, :, top : top + n_px, left : left + n_px] / 255.0
    mean = torch.tensor((0.48145466, 0.4578275, 0.40821073)).view(1, 3, 1, 1)
    std = torch.tensor((0.26862954, 0.26130258, 0.27577711)).view(1, 3, 1, 1)
    return (x - mean) / std


def overall_consistency(
    frames: np.ndarray,
    prompt: str,
    path: str | Path,
    *,
    bpe_path: str | Path | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """OC of frames [T, H, W, 3] uint8 against ``prompt``: ``{"oc", "frame_indices", "model"}``."""
    import torch

    model, tok = load_viclip(path, bpe_path=bpe_path, device=device)
    n = model.cfg["num_frames"]
    idx = frame_indices(n, len(frames))
    video = vbench_preprocess(np.asarray(frames)[idx], model.cfg["image_size"])[None].to(device)
    with torch.no_grad():
        v = model.encode_vision(video).float()
        v = v / v.norm(dim=-1, keepdim=True)
        t = model.encode_text(tok.tokenize(prompt, model.cfg["context_length"]).to(device)).float()
        t = t / t.norm(dim=-1, keepdim=True)
    return {"oc": float((v @ t.T)[0, 0]), "frame_indices": idx, "model": str(path)}
