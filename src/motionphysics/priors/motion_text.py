"""What the motion prior reads of a prompt: the sentence vector and a motion reading.

A prior trained on a few phrasings per motion learns those phrasings: a new way to say
the same motion ("splatters and spreads out widely" for a splash) lands where the
network has never been, and the held-out caption discrimination of a prior that reads
only the pooled sentence vector stalled at 67 % while the same prior scored 91 % with the
phrasings it was trained on (MODEL_CARD_motion.md). MiniLM itself knows the words: the
nearest training phrasing of 15 of the 16 held-out phrasings is one of its own group.

So the prior's text condition is the pooled MiniLM vector of the prompt's **subject** (its
words before the first verb: the object, its material and firmness words, "A soft, wobbly
rubber capsule"; the whole prompt when it has no verb) followed by a **motion reading**, a
soft vote over the motion groups by the training phrasings the prompt's motion clauses
are closest to. The words that say what the thing does reach the network only through
the reading, which a phrasing it never saw gets from its neighbours; a vector of the
whole sentence (``sentence="whole"``, the first reading checkpoints) also carries the
predicate's words, and a new phrasing moves it where the network has not been (held-out
discrimination 74.5 % with it, MODEL_CARD_motion.md). The reading:

- the predicate of the prompt (what it says the thing does, after its first verb) is
  split into clauses at commas, "and", "then", "but", "while"
  (:func:`~motionphysics.language.captions.prompt_clauses`);
- a clause counts when its closest anchor (a training phrasing) is at least
  ``MIN_MOTION_SIMILARITY`` and closer than every event phrase ("is dropped", "hits the
  ground": :data:`~motionphysics.language.captions.READING_NEUTRAL`);
- each counting clause gives ``softmax(cos(clause, anchors) / tau)`` summed per group;
  the reading is the mean over counting clauses, all zeros when none counts (no motion
  claim: the unconditional prompt ``""`` and the neutral captions of clips no group
  fits).

Training reads every caption **leaving its own phrasing out** of the anchors
(``leave_out=True``): the network learns the reading that a phrasing it has not seen
gets from its neighbours, which is what a user's words get. The anchors (texts and
groups) and ``tau`` are stored in the checkpoint, so a prior reads prompts the way it
was trained whatever later versions add to the caption tables.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from motionphysics.language.captions import (
    GROUPS,
    MIN_MOTION_SIMILARITY,
    READING_NEUTRAL,
    prompt_clauses,
    prompt_subject,
    training_phrasings,
)
from motionphysics.language.text import TEXT_DIM, sentence_embeddings

__all__ = ["READING_TAU", "SENTENCE_PARTS", "MotionText", "default_anchors"]

READING_TAU = 0.05
"""Softmax temperature of the reading over cosine similarities: a training phrasing
0.05 closer than another weighs e times more (paraphrases of one motion sit 0.1-0.3
closer to each other than to other motions' in MiniLM)."""


SENTENCE_PARTS = ("subject", "whole")
"""What the sentence vector is pooled over: the prompt's subject, or the whole prompt."""


def default_anchors() -> tuple[list[str], list[str]]:
    """Every training phrasing of every group, and its group."""
    phrases = [p for g in GROUPS for p in training_phrasings(g)]
    groups = [g for g in GROUPS for _ in training_phrasings(g)]
    return phrases, groups


class MotionText:
    """Text condition ``[N, TEXT_DIM + len(groups)]``: the pooled vector of the prompt's
    subject (or the whole prompt: ``sentence``) + the motion reading."""

    def __init__(
        self,
        anchors: Sequence[str],
        groups: Sequence[str],
        tau: float = READING_TAU,
        group_names: Sequence[str] = GROUPS,
        sentence: str = "subject",
    ):
        if sentence not in SENTENCE_PARTS:
            raise ValueError(
                f"motion text: sentence must be one of {SENTENCE_PARTS}, not {sentence!r}"
            )
        self.sentence = sentence
        if len(anchors) != len(groups) or not anchors:
            raise ValueError("motion text: anchors and their groups must be non-empty and aligned")
        self.anchors = list(anchors)
        self.groups = list(groups)
        self.group_names = list(group_names)
        self.tau = float(tau)
        unknown = sorted(set(self.groups) - set(self.group_names))
        if unknown:
            raise ValueError(f"motion text: anchors of unknown groups {unknown}")
        emb = sentence_embeddings(self.anchors + list(READING_NEUTRAL))
        self._anchor_emb = emb[: len(self.anchors)]
        self._neutral_emb = emb[len(self.anchors) :]
        onehot = torch.zeros(len(self.anchors), len(self.group_names))
        for i, g in enumerate(self.groups):
            onehot[i, self.group_names.index(g)] = 1.0
        self._onehot = onehot

    @property
    def dim(self) -> int:
        return TEXT_DIM + len(self.group_names)

    def config(self) -> dict:
        """What a checkpoint stores to read prompts the same way (:meth:`from_config`)."""
        return {
            "anchors": self.anchors,
            "groups": self.groups,
            "tau": self.tau,
            "group_names": self.group_names,
            "sentence": self.sentence,
        }

    @classmethod
    def from_config(cls, cfg: dict) -> MotionText:
        # checkpoints from before the subject vector pooled the whole prompt
        return cls(
            cfg["anchors"],
            cfg["groups"],
            cfg.get("tau", READING_TAU),
            cfg.get("group_names", GROUPS),
            cfg.get("sentence", "whole"),
        )

    @classmethod
    def default(cls) -> MotionText:
        return cls(*default_anchors())

    def readings(self, texts: Sequence[str], *, leave_out: bool = False) -> Tensor:
        """``[N, len(groups)]`` motion readings (see the module docstring). ``leave_out``:
        anchors contained in a text are not used to read it (training captions)."""
        per_text = [prompt_clauses(t) for t in texts]
        flat = [c for cl in per_text for c in cl]
        out = torch.zeros(len(texts), len(self.group_names))
        if not flat:
            return out
        emb = sentence_embeddings(flat)
        sims = emb @ self._anchor_emb.T  # [clauses, anchors]
        neutral = (emb @ self._neutral_emb.T).amax(1) if len(self._neutral_emb) else None
        k = 0
        for i, (text, clauses) in enumerate(zip(texts, per_text, strict=True)):
            low = text.lower()
            mask = (
                torch.tensor([a.lower() in low for a in self.anchors])
                if leave_out
                else torch.zeros(len(self.anchors), dtype=torch.bool)
            )
            votes = []
            for _ in clauses:
                s = sims[k].masked_fill(mask, -1.0)
                best = float(s.max())
                if best >= MIN_MOTION_SIMILARITY and (neutral is None or best > float(neutral[k])):
                    votes.append(torch.softmax(s / self.tau, 0) @ self._onehot)
                k += 1
            if votes:
                out[i] = torch.stack(votes).mean(0)
        return out

    def sentences(self, texts: Sequence[str]) -> list[str]:
        """What each text's sentence vector is pooled over."""
        if self.sentence == "whole":
            return list(texts)
        return [prompt_subject(t) for t in texts]

    def sentence_vectors(self, texts: Sequence[str]) -> Tensor:
        """``[N, TEXT_DIM]`` pooled MiniLM vectors of :meth:`sentences` (each distinct one
        embedded once)."""
        parts = self.sentences(texts)
        uniq = list(dict.fromkeys(parts))
        if not uniq:
            return torch.zeros(0, TEXT_DIM)
        emb = sentence_embeddings(uniq)
        at = {u: i for i, u in enumerate(uniq)}
        return emb[torch.tensor([at[p] for p in parts], dtype=torch.long)]

    def encode(self, texts: Sequence[str], *, leave_out: bool = False) -> Tensor:
        """``[N, dim]`` float32: the sentence vectors followed by the readings."""
        texts = list(texts)
        if not texts:
            return torch.zeros(0, self.dim)
        return torch.cat(
            [self.sentence_vectors(texts), self.readings(texts, leave_out=leave_out)], 1
        ).float()
