"""CLIPSIM: mean over frames of the cosine between CLIP image and text embeddings.

The paper (appendix, metrics) writes ``CLIPSIM = sum_l <CLIP(I_l), CLIP(P)> / (|.| |.|)``
and reports it x10^-2, i.e. as a mean cosine x100; it follows OmniPhysGS in using
CLIP ViT-L/14. We return the raw MEAN cosine over ALL frames of the video (the number
of frames is reported beside it); x100 is a printing choice.

The model is ``transformers.CLIPModel`` loaded from a LOCAL folder (``--clip DIR``,
``local_files_only``: nothing is downloaded) with its ``CLIPTokenizer`` files
(vocab.json, merges.txt). The image preprocessing is our own and reproduces OpenAI's
``clip._transform`` to the pixel rather than using ``CLIPImageProcessor``, whose centre
crop floors the offset where OpenAI's (torchvision's) rounds it and whose default
backend may change:

1. resize the short side to ``n_px`` with PIL bicubic (``Image.resize``, PIL's own
   antialiasing), the long side to ``int(n_px * long / short)`` (torchvision's rule);
2. centre crop ``n_px`` x ``n_px`` at ``top = int(round((H - n_px) / 2))``,
   ``left = int(round((W - n_px) / 2))`` (Python round: half to even, as torchvision);
3. ``/ 255``, then ``(x - mean) / std`` with OpenAI's constants.

This module needs torch, transformers and PIL, imported inside the functions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from motionphysics.errors import UserInputError

__all__ = ["CLIP_MEAN", "CLIP_STD", "openai_preprocess", "load_clip", "clipsim"]

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def _resized_size(h: int, w: int, n_px: int) -> tuple[int, int]:
    """(new_h, new_w): short side n_px, long side int(n_px * long / short) (torchvision)."""
    if h <= w:
        return n_px, int(n_px * w / h)
    return int(n_px * h / w), n_px


def openai_preprocess(image: np.ndarray, n_px: int = 224) -> np.ndarray:
    """OpenAI CLIP's transform of one RGB uint8 image [H, W, 3] -> float32 [3, n_px, n_px]."""
    from PIL import Image

    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"image must be uint8 [H, W, 3], got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    nh, nw = _resized_size(h, w, n_px)
    pil = Image.fromarray(img, "RGB")
    if (nh, nw) != (h, w):
        pil = pil.resize((nw, nh), Image.Resampling.BICUBIC)
    arr = np.asarray(pil)
    top = int(round((nh - n_px) / 2.0))
    left = int(round((nw - n_px) / 2.0))
    arr = arr[top : top + n_px, left : left + n_px].astype(np.float32) / 255.0
    arr = (arr - np.asarray(CLIP_MEAN, np.float32)) / np.asarray(CLIP_STD, np.float32)
    return np.ascontiguousarray(arr.transpose(2, 0, 1))


def load_clip(path: str | Path, device: str = "cpu"):
    """(model, tokenizer, image_size) from a local transformers CLIP folder."""
    p = Path(path)
    if not (p / "config.json").is_file():
        raise UserInputError(f"--clip {p}: no config.json (expected a transformers CLIP folder)")
    for name in ("vocab.json", "merges.txt"):
        if not (p / name).is_file():
            raise UserInputError(f"--clip {p}: no {name} (the CLIP tokenizer files are needed)")
    from transformers import CLIPModel, CLIPTokenizer

    try:
        model = CLIPModel.from_pretrained(p, local_files_only=True)
        tok = CLIPTokenizer.from_pretrained(p, local_files_only=True)
    except (OSError, ValueError) as err:
        raise UserInputError(
            f"--clip {p}: cannot load a CLIP model ({str(err).splitlines()[0]})"
        ) from None
    model = model.eval().to(device)
    return model, tok, int(model.config.vision_config.image_size)


def _pooled(out):
    # transformers 5 returns a model output whose pooler_output is the projected embedding;
    # earlier versions returned the tensor itself
    return out if hasattr(out, "shape") else out.pooler_output


def clipsim(
    frames: np.ndarray,
    prompt: str,
    path: str | Path,
    *,
    device: str = "cpu",
    batch: int = 16,
) -> dict[str, Any]:
    """CLIPSIM of frames [T, H, W, 3] uint8 against ``prompt`` with the CLIP at ``path``.

    Returns ``{"clipsim", "per_frame", "frames", "model", "image_size"}`` (raw cosines).
    """
    import torch

    model, tok, n_px = load_clip(path, device)
    frames = np.asarray(frames)
    with torch.no_grad():
        ctx = int(model.config.text_config.max_position_embeddings)
        ids = tok([prompt], padding=True, truncation=True, max_length=ctx, return_tensors="pt")
        txt = _pooled(
            model.get_text_features(
                input_ids=ids["input_ids"].to(device),
                attention_mask=ids["attention_mask"].to(device),
            )
        ).float()
        txt = txt / txt.norm(dim=-1, keepdim=True)
        cos = []
        for i in range(0, len(frames), batch):
            px = np.stack([openai_preprocess(f, n_px) for f in frames[i : i + batch]])
            img = _pooled(model.get_image_features(pixel_values=torch.from_numpy(px).to(device)))
            img = img.float()
            img = img / img.norm(dim=-1, keepdim=True)
            cos.append((img @ txt.T)[:, 0].cpu().numpy())
    per_frame = np.concatenate(cos).astype(np.float64)
    return {
        "clipsim": float(per_frame.mean()),
        "per_frame": per_frame.tolist(),
        "frames": int(len(per_frame)),
        "model": str(path),
        "image_size": n_px,
    }
