"""The motion prior's text condition (``priors/motion_text.py``): the sentence vector and
the motion reading of the prompt's clauses, against what MiniLM measures directly."""

from __future__ import annotations

import json

import pytest
import torch

from motionphysics.language.captions import GROUPS, HELD_OUT, training_phrasings
from motionphysics.language.text import TEXT_DIM, sentence_embeddings
from motionphysics.priors.motion_text import MotionText


@pytest.fixture(scope="module")
def reader() -> MotionText:
    return MotionText.default()


def test_held_out_phrasings_read_as_their_group(reader):
    """The 16 held-out phrasings (never an anchor) read as their own group by the reading's
    arg-max. Measured 15/16 for MiniLM's nearest training phrasing; 14 leaves one more
    phrasing to a tie that a different MiniLM build (float rounding) could flip."""
    texts = [f"A rubber ball {p}." for g in GROUPS for p in HELD_OUT[g]]
    truth = [g for g in GROUPS for _ in HELD_OUT[g]]
    r = reader.readings(texts)
    assert r.shape == (16, len(GROUPS))
    hits = sum(GROUPS[int(r[i].argmax())] == truth[i] for i in range(16))
    assert hits >= 14, [(t, GROUPS[int(r[i].argmax())]) for i, t in enumerate(texts)]
    # a reading is a mean of softmax votes: a distribution over the groups
    assert torch.allclose(r.sum(1), torch.ones(16), atol=1e-5)


def test_no_motion_claim_reads_as_nothing(reader):
    """The unconditional prompt, a subject without a verb and an event phrase claim no
    motion: their reading is all zeros (the unconditional reading), never a guess."""
    r = reader.readings(["", "a rubber duck", "A ball is dropped and hits the ground."])
    assert torch.equal(r, torch.zeros(3, len(GROUPS)))


def test_each_motion_clause_votes(reader):
    """Two motion clauses: the reading is the mean of their votes, so each clause's group
    holds about half (the other half spread over its neighbours at tau = 0.05)."""
    r = reader.readings(["A jelly cube wobbles back and forth, then squashes and stays flat."])[0]
    top2 = {GROUPS[i] for i in r.topk(2).indices.tolist()}
    assert top2 == {"wobbles", "squashes_flat"}
    assert float(r.max()) < 0.75


def test_leave_out_is_the_reading_without_the_contained_anchors():
    """``leave_out=True`` equals reading the same text with a reader built without the
    anchors the text contains (a brute-force twin: a second reader)."""
    anchors = ["bounces up high", "springs back into the air", "oozes slowly", "wobbles"]
    groups = ["bounces_high", "bounces_high", "oozes", "wobbles"]
    full = MotionText(anchors, groups)
    twin = MotionText(anchors[1:], groups[1:])
    text = ["A rubber ball bounces up high."]
    left = full.readings(text, leave_out=True)
    assert torch.allclose(left, twin.readings(text), atol=1e-6)
    # the own phrasing is what reads it when it is kept: a nearly pure vote
    assert float(full.readings(text)[0, GROUPS.index("bounces_high")]) > 0.99


def test_encode_is_subject_vector_then_reading(reader):
    texts = ["A honey drop oozes slowly.", ""]
    e = reader.encode(texts)
    assert e.shape == (2, reader.dim) and reader.dim == TEXT_DIM + len(GROUPS)
    assert torch.allclose(e[:, :TEXT_DIM], sentence_embeddings(["A honey drop", ""]), atol=1e-6)
    assert torch.equal(e[:, TEXT_DIM:], reader.readings(texts))
    assert int(e[0, TEXT_DIM:].argmax()) == GROUPS.index("oozes")
    assert reader.encode([]).shape == (0, reader.dim)


def test_config_round_trip_reads_the_same(reader):
    """What a checkpoint stores (JSON-able) rebuilds a reader that encodes bit-identically."""
    cfg = json.loads(json.dumps(reader.config()))
    same = MotionText.from_config(cfg)
    texts = ["A cube of jelly trembles after the impact.", "A sand castle crumbles."]
    assert torch.equal(same.encode(texts), reader.encode(texts))
    assert cfg["anchors"] == [p for g in GROUPS for p in training_phrasings(g)]


def test_bad_anchors_are_refused():
    with pytest.raises(ValueError, match="aligned"):
        MotionText(["bounces"], [])
    with pytest.raises(ValueError, match="unknown groups"):
        MotionText(["bounces"], ["hops"])


def test_the_predicate_reaches_the_network_only_through_the_reading(reader):
    """Subject vectors: two phrasings of one motion for one object differ only in their
    reading; firmness words before the verb stay in the vector; a prompt without a verb is
    pooled whole. ``sentence="whole"`` (a checkpoint without the key) pools every word."""
    a, b = "A stiff rubber duck jumps right back up.", "A stiff rubber duck bounces up high."
    e = reader.encode([a, b, "A soft rubber duck bounces up high.", "a bouncy ball"])
    assert torch.equal(e[0, :TEXT_DIM], e[1, :TEXT_DIM])
    assert not torch.equal(e[1, :TEXT_DIM], e[2, :TEXT_DIM])
    # (allclose: the pooled sum's rounding depends on the batch's padding)
    assert torch.allclose(e[3, :TEXT_DIM], sentence_embeddings(["a bouncy ball"])[0], atol=1e-6)
    cfg = reader.config()
    del cfg["sentence"]
    whole = MotionText.from_config(cfg)
    assert whole.sentence == "whole"
    w = whole.encode([a, b])
    assert torch.allclose(w[:, :TEXT_DIM], sentence_embeddings([a, b]), atol=1e-6)
    assert torch.equal(w[:, TEXT_DIM:], e[:2, TEXT_DIM:])
    with pytest.raises(ValueError, match="sentence must be one of"):
        MotionText(["bounces"], ["bounces_high"], sentence="predicate")
