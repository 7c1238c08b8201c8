"""The offline kb backend: the knowledge base file, the matcher, accuracy on a prompt set."""

from __future__ import annotations

import csv
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.init import EstimateOptions, estimate_many
from motionphysics.init.kb import (
    PACKAGED_EMBEDDINGS,
    KBMatcher,
    get_matcher,
    load_kb,
    tokenize,
)
from motionphysics.materials.catalog import MATERIALS, spec

PROMPTS = Path(__file__).resolve().parents[1] / "data" / "prompts.csv"

REQUIRED = [
    "rubber",
    "jelly",
    "steel",
    "aluminium",
    "copper",
    "gold",
    "clay",
    "play-doh",
    "bread",
    "sponge",
    "memory foam",
    "dry sand",
    "wet sand",
    "snow",
    "water",
    "honey",
    "oil",
    "syrup",
    "toothpaste",
    "ketchup",
    "mayonnaise",
    "cream",
    "mud",
]


def test_knowledge_base_content():
    kb = load_kb()
    assert len(kb.entries) >= 150
    counts = Counter(e.cls for e in kb.entries)
    assert set(counts) == set(MATERIAL_CLASSES) and min(counts.values()) >= 10
    words = {w.lower() for e in kb.entries for w in e.texts}
    for w in REQUIRED:
        assert w in words, w
    for e in kb.entries:
        assert e.source and e.kind in ("substance", "object")
        assert spec(e.cls, "density").contains(e.density), e.name
        assert set(e.values) == set(MATERIALS[e.cls].names), e.name
        for k, v in e.values.items():
            assert spec(e.cls, k).contains(v), (e.name, k, v)


def test_packaged_embeddings_match_the_kb_file():
    # Regenerate with KBMatcher().write_packaged_embeddings() after editing the KB.
    kb = load_kb()
    with np.load(PACKAGED_EMBEDDINGS) as z:
        assert str(z["kb_sha256"]) == kb.sha256
        n_texts = sum(len(e.texts) for e in kb.entries) + sum(map(len, kb.prototypes.values()))
        assert z["embeddings"].shape == (n_texts, 384)


def test_tokenize():
    assert tokenize("Sandcastles, Play-Doh & knight's helmets!") == [
        "sandcastle",
        "play",
        "doh",
        "knight",
        "helmet",
    ]
    assert tokenize("glasses of molasses") == ["glass", "of", "molass"]


def test_lexical_context_rules_without_the_model():
    m = KBMatcher(announce=False)

    def factors(text):
        toks = tokenize(text)
        return {
            " ".join(toks[s.start : s.end]): s.factor for s in m._spans(toks) if s.kb or s.explicit
        }

    f = factors("A bucket of water is spilled onto the table")
    assert f["bucket"] < 1.0 and f["water"] == 1.0  # container before "of"
    f = factors("Honey flows slowly from a spoon")
    assert f["honey"] == 1.0 and f["spoon"] < 1.0  # surface after a preposition
    f = factors("A toy cat made of steel")
    assert f["steel"] > 1.0  # "made of" names the material
    f = factors("A wooden spoon falls")
    assert f["wooden"] > 1.0 and f["spoon"] == 1.0  # a substance modifying the next noun
    f = factors("non-Newtonian fluid flows")
    assert list(f) == ["non newtonian fluid"]  # longest phrase wins, "fluid" not reused


@pytest.fixture(scope="module")
def matcher():
    t0 = time.monotonic()
    m = get_matcher()
    m.match("warm-up")
    load_s = time.monotonic() - t0
    # Budget: 15 s on an idle machine (model ~3-5 s there); allow contention on shared CI.
    assert load_s < 60, load_s
    return m


def test_prompt_set_accuracy(matcher):
    rows = list(csv.DictReader(PROMPTS.open(encoding="utf-8")))
    counts = Counter(r["class"] for r in rows)
    assert len(rows) >= 70 and all(counts[c] >= 10 for c in MATERIAL_CLASSES), counts
    ests = estimate_many([r["prompt"] for r in rows], backend="kb")
    confusion = Counter((r["class"], e.cls) for r, e in zip(rows, ests, strict=True))
    for e in ests:
        for k, v in e.values.items():
            assert spec(e.cls, k).contains(v)
        assert spec(e.cls, "density").contains(e.density)
        assert 0.0 < e.confidence <= 1.0 and e.matches
    correct = sum(n for (t, p), n in confusion.items() if t == p)
    if correct < 0.95 * len(rows):
        header = "true \\ pred".ljust(14) + "".join(c[:7].rjust(8) for c in MATERIAL_CLASSES)
        lines = [header] + [
            t.ljust(14) + "".join(str(confusion[(t, p)]).rjust(8) for p in MATERIAL_CLASSES)
            for t in MATERIAL_CLASSES
        ]
        wrong = [
            f"{r['class']} -> {e.cls}: {r['prompt']}"
            for r, e in zip(rows, ests, strict=True)
            if r["class"] != e.cls
        ]
        pytest.fail(f"kb accuracy {correct}/{len(rows)} < 95 %\n" + "\n".join(lines + wrong))


@pytest.mark.parametrize(
    "prompt, cls",
    [
        ("A metal cat falls over.", "metal"),  # explicit word beats the object
        ("A cat made of water collapses.", "newtonian"),
        ("An elastic bird is hitting the ground.", "elastic"),
        ("A rubber duck hits the sand.", "elastic"),  # surface after an impact verb
        ("Some liquid metal flows.", "newtonian"),  # a known phrase before its words
        ("A sponge made of metal is dropped.", "metal"),
    ],
)
def test_explicit_words_and_context(matcher, prompt, cls):
    assert matcher.match(prompt).cls == cls


def test_answers_fast_after_loading(matcher):
    times = []
    for _ in range(3):
        t0 = time.monotonic()
        matcher.match("A rubber duck hits the ground and bounces back.")
        times.append(time.monotonic() - t0)
    # Requirement: < 1 s once the model is loaded (measured ~0.1 s on this 2-core box).
    assert min(times) < 1.0, times


def test_kb_cache_for_another_kb_file(tmp_path, monkeypatch):
    """A KB other than the packaged one is embedded once and cached under its hash."""
    monkeypatch.setenv("MOTIONPHYSICS_CACHE", str(tmp_path))
    src = load_kb()
    import json

    data = json.loads(src.path.read_text())
    data["entries"] = [
        e
        for e in data["entries"]
        if e["name"] in ("steel", "water", "rubber", "clay", "sponge", "dry sand", "toothpaste")
    ]
    small = tmp_path / "small_kb.json"
    small.write_text(json.dumps(data))
    m = KBMatcher(load_kb(str(small)), announce=False)
    emb = m.embeddings()
    cached = list((tmp_path / "kb").glob("embeddings-*.npy"))
    assert len(cached) == 1 and np.allclose(np.load(cached[0]), emb)
    assert m.match("Honey flows").cls == "newtonian"


def test_packaged_embeddings_are_the_models_embeddings(matcher):
    """Spot-check rows of the shipped float16 embeddings against a fresh encoding."""
    from motionphysics.init.kb import encode

    rows = [0, len(matcher._texts) // 2, len(matcher._texts) - 1]
    fresh = encode([matcher._texts[i] for i in rows], announce=False)
    shipped = matcher.embeddings()[rows]
    # float16 storage: ~1e-3 relative per component, cosine stays above 0.999
    cos = np.sum(fresh * shipped, axis=1) / np.linalg.norm(shipped, axis=1)
    assert np.all(cos > 0.999), cos


@pytest.mark.parametrize(
    "prompt, entry",
    [
        ("A bowling ball is dropped on the floor.", "bowling ball"),
        ("A chocolate bar falls off the table.", "chocolate bar"),
        ("A block of tofu is dropped onto a cutting board.", "tofu"),
        ("A marshmallow is squashed.", "marshmallow"),
        (
            "A rubber duck sits on a table next to a window with curtains, sunlight coming "
            "through the window glass, and it falls over.",
            "rubber duck",
        ),
    ],
)
def test_everyday_objects_and_scenery(matcher, prompt, entry):
    m = matcher.match(prompt)
    assert m.entry.name == entry and m.confidence >= 0.5 and m.warnings == []


@pytest.mark.parametrize("prompt, word", [("A ball falls.", "ball"), ("A cat falls.", "cat")])
def test_low_confidence_says_not_sure(matcher, prompt, word):
    from motionphysics.init.kb import CONFIDENCE_THRESHOLD

    m = matcher.match(prompt)
    assert m.confidence < CONFIDENCE_THRESHOLD and m.matched == word
    (w,) = m.warnings
    assert w.startswith(f"not sure: matched '{word}' -> {m.entry.name}")
    assert "name the material, or use --init llm" in w


@pytest.mark.parametrize(
    "prompt", ["Una pelota de goma rebota en el suelo", "一个橡皮球掉在地上弹起来"]
)
def test_non_english_prompt_is_warned(matcher, prompt):
    m = matcher.match(prompt)
    assert any("reads English only" in w for w in m.warnings)
    assert m.confidence < 0.5


def test_english_prompts_are_not_flagged_non_english():
    from motionphysics.init.kb import mostly_not_english

    rows = list(csv.DictReader(PROMPTS.open(encoding="utf-8")))
    assert not [r["prompt"] for r in rows if mostly_not_english(r["prompt"])]
    assert mostly_not_english("Le ballon tombe sur la table et rebondit")


def test_real_values_outside_the_class_are_reported(matcher):
    # The extended table holds tofu's real E (3e4 Pa): used as it is.
    (est,) = estimate_many(["A block of tofu is dropped."], backend="kb")
    assert est.values["E"] == 3e4 and est.clamped == [] and not est.notes
    # The paper's table does not (its elastic floor is 1e7 Pa): a substitution, reported.
    (est,) = estimate_many(
        ["A block of tofu is dropped."], backend="kb", options=EstimateOptions(ranges="paper")
    )
    (c,) = est.clamped
    assert c.kind == "range floor" and c.field == "E" and (c.original, c.clamped) == (3e4, 1e7)
    # a hint, not a warning: the substitution is listed in the clamps and the summary
    assert any("real E of tofu" in n for n in est.notes) and not est.warnings
    # A real value outside even the extended range (tungsten's E above 4e11 Pa) is
    # reported in either table.
    (est,) = estimate_many(["A tungsten cube falls."], backend="kb")
    (c,) = est.clamped
    assert c.field == "E" and c.kind == "clamped" and (c.original, c.clamped) == (4.07e11, 4e11)


def test_extended_prompt_set_entries(matcher):
    rows = [r for r in csv.DictReader(PROMPTS.open(encoding="utf-8")) if r.get("entry")]
    assert len(rows) >= 10
    got = matcher.match_many([r["prompt"] for r in rows])
    wrong = [
        (r["prompt"], m.entry.name)
        for r, m in zip(rows, got, strict=True)
        if m.entry.name != r["entry"]
    ]
    assert not wrong, wrong


@pytest.mark.parametrize(
    ("prompt", "cls", "entry"),
    [
        # behind "out" a substance would read as scenery; after "like" it is what the
        # thing behaves as (the duck was matched as an elastic animal figure before)
        ("a duck creeps out slowly like syrup", "newtonian", "maple syrup"),
        ("a bird spreads out like toothpaste", "non_newtonian", "toothpaste"),
        ("a duck slides down like the butter", "plasticine", "butter"),
        # a material named for the thing itself keeps its first-phrase bonus
        ("A rubber duck creeps like syrup", "elastic", "rubber duck"),
        ("a steel ball lands on the floor like a feather", "metal", "steel ball"),
        # no "like": behind a preposition a substance is still the surroundings
        ("a steel ball falls into a pool of honey", "metal", "steel ball"),
    ],
)
def test_a_simile_names_what_a_shape_is_made_of(matcher, prompt, cls, entry):
    m = matcher.match(prompt)
    assert (m.cls, m.entry.name) == (cls, entry), m.matches
    assert m.confidence >= 0.5 and m.warnings == []
