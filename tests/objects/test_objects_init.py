"""Per-object material initialisation from one prompt (issue 15).

kb: each object's phrase is found in the sentence by its name (and the kb's synonyms)
and estimated on its own; an object the sentence does not name falls back to the whole
sentence with a warning naming it. llm: one request listing the object names, one JSON
answer per name, against the loopback chat server of tests/init/test_init_llm.py.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from motionphysics.init import EstimateOptions, LLMError, LLMOptions
from motionphysics.init.estimate import estimate_objects, object_phrase

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "init"))
from test_init_llm import FakeChatServer, _user_text  # noqa: E402

QUIET = EstimateOptions(announce=False)


@pytest.mark.parametrize(
    ("prompt", "name", "phrase"),
    [
        ("a steel axe falls onto a rubber duck", "axe", "a steel axe"),
        ("a steel axe falls onto a rubber duck", "duck", "a rubber duck"),
        ("A ball made of steel hits a jelly cube.", "ball", "A ball made of steel"),
        ("Two foam cubes slide into a honey puddle", "cube", "Two foam cubes"),
        ("a steel axe falls onto a rubber duck", "cat", None),
    ],
)
def test_object_phrase(prompt, name, phrase):
    assert object_phrase(prompt, name) == phrase


def test_phrase_by_synonym_when_the_name_is_absent():
    # "duck" is not in the sentence, "rubber ducky" (a kb synonym) is
    assert object_phrase("a steel axe hits a rubber ducky", "duck", ("rubber ducky",)) == (
        "a rubber ducky"
    )


def test_kb_two_objects():
    a, d = estimate_objects("a steel axe falls onto a rubber duck", ["axe", "duck"], options=QUIET)
    assert (a.cls, d.cls) == ("metal", "elastic")
    assert a.prompt == "a steel axe" and d.prompt == "a rubber duck"
    assert a.density > 5000 > d.density
    assert not any("not named" in w for w in a.warnings + d.warnings)


def test_kb_three_objects_and_a_missing_one(capsys):
    names = ["drop", "pillow", "bucket", "cat"]
    ests = estimate_objects(
        "A honey drop falls on a foam pillow next to a bucket of sand",
        names,
        options=EstimateOptions(announce=True),
    )
    assert [e.cls for e in ests[:3]] == ["newtonian", "foam", "sand"]
    # the cat is not in the sentence: whole sentence, and a warning naming it
    assert ests[3].prompt.startswith("A honey drop")
    assert any("'cat'" in w and "whole sentence" in w for w in ests[3].warnings)
    assert "'cat'" in capsys.readouterr().err


def _opts(srv):
    return EstimateOptions(
        llm=LLMOptions(base_url=srv.base_url, model="m", api_key="k", timeout=10, max_retries=0),
        announce=False,
    )


AXE = {"material_type": "metal", "density": 7850, "E": 2.0e11, "nu": 0.3, "tau_Y": 2.5e8}
DUCK = {"material_type": "elastic", "density": 1100, "E": 2.0e7, "nu": 0.45}


def test_llm_per_object_answer_in_one_request():
    with FakeChatServer([json.dumps({"axe": AXE, "duck": DUCK})]) as srv:
        a, d = estimate_objects(
            "a steel axe falls onto a rubber duck",
            ["axe", "duck"],
            backend="llm",
            options=_opts(srv),
        )
    assert len(srv.requests) == 1
    text = _user_text(srv.requests[0])
    assert '"axe"' in text and '"duck"' in text and "E: 1e10 - 4e11 Pa" in text  # extended table
    assert (a.cls, a.density, a.values["E"]) == ("metal", 7850.0, 2.0e11)
    assert (d.cls, d.values["nu"]) == ("elastic", 0.45)
    assert a.clamped == [] and d.clamped == []


def test_llm_one_object_missing_is_reasked_then_refused():
    # first answer lacks the duck: re-asked once naming it; the second gives it
    with FakeChatServer([json.dumps({"axe": AXE}), json.dumps({"duck": DUCK})]) as srv:
        a, d = estimate_objects(
            "a steel axe falls onto a rubber duck",
            ["axe", "duck"],
            backend="llm",
            options=_opts(srv),
        )
    assert len(srv.requests) == 2
    assert 'no answer for object "duck"' in srv.requests[1]["messages"][-1]["content"]
    assert (a.cls, d.cls) == ("metal", "elastic")
    # missing twice: one-line error naming the object
    with FakeChatServer([json.dumps({"axe": AXE}), json.dumps({"axe": AXE})]) as srv:
        with pytest.raises(LLMError, match='object "duck"') as err:
            estimate_objects(
                "a steel axe hits a duck", ["axe", "duck"], backend="llm", options=_opts(srv)
            )
    assert "\n" not in str(err.value)


def test_llm_out_of_range_object_is_clamped():
    soft = {**DUCK, "E": 10.0}  # below the elastic range floor (1e4 Pa)
    with FakeChatServer([json.dumps({"axe": AXE, "duck": soft})]) as srv:
        a, d = estimate_objects(
            "a steel axe falls onto a rubber duck",
            ["axe", "duck"],
            backend="llm",
            options=_opts(srv),
        )
    assert a.clamped == []
    assert [(c.field, c.original) for c in d.clamped] == [("E", 10.0)]
    assert d.values["E"] == d.clamped[0].clamped > 10.0
