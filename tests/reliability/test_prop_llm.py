"""Property: any LLM answer ends in a validated material or ONE line (re-ask included).

Answers start from a valid one for a random class and are damaged: a field dropped,
a value of the wrong type, out of range (clamped, recorded), physically impossible
(re-asked, then refused), numbers as strings with units, extra keys; and written as
plain JSON, JSON in prose, in a code fence, truncated JSON, Python repr, or nothing.
"""

from __future__ import annotations

import json
import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reliability_cases import CASES, OUTCOMES, examples

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.materials.catalog import DENSITY, MATERIALS, spec

WRONG = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=8),
    st.sampled_from(["2.2 GPa", "1e11", "7,850", "3 x 10^9", "soft", "NaN", "-1"]),
    st.lists(st.floats(), max_size=2),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
)


@st.composite
def answers(draw):
    cls = draw(st.sampled_from(MATERIAL_CLASSES))
    rnd = random.Random(draw(st.integers(0, 2**31)))
    obj = {"material_type": MATERIALS[cls].label, "density": rnd.uniform(DENSITY.low, DENSITY.high)}
    for ps in MATERIALS[cls].params:
        obj[ps.name] = rnd.uniform(ps.low, ps.high)
    keys = [k for k in obj]
    for _ in range(draw(st.integers(0, 3))):
        k = draw(st.sampled_from(keys))
        how = draw(st.sampled_from(["drop", "wrong", "scale", "impossible", "extra", "class"]))
        if how == "drop":
            obj.pop(k, None)
        elif how == "wrong":
            obj[k] = draw(WRONG)
        elif how == "scale" and isinstance(obj.get(k), float):
            obj[k] *= draw(st.sampled_from([1e-6, 1e-2, 10.0, 1e6]))
        elif how == "impossible" and k != "material_type":
            obj[k] = draw(st.sampled_from([-1.0, 0.0, 0.75, -2.0, 1e400 * 0]))
        elif how == "extra":
            obj[draw(st.text(min_size=1, max_size=6))] = draw(WRONG)
        elif how == "class":
            obj["material_type"] = draw(
                st.sampled_from(["Rubber", "steel", "", "Metal (steel)", "gel"])
            )
    text = json.dumps(obj, allow_nan=True)
    form = draw(st.sampled_from(["plain", "prose", "fence", "truncated", "repr", "empty"]))
    if form == "prose":
        text = f"Sure! Here is my estimate:\n{text}\nLet me know if you need more."
    elif form == "fence":
        text = f"```json\n{text}\n```"
    elif form == "truncated":
        text = text[: draw(st.integers(0, max(0, len(text) - 1)))]
    elif form == "repr":
        text = repr(obj)
    elif form == "empty":
        text = ""
    return text


@settings(max_examples=examples(200), deadline=None, suppress_health_check=list(HealthCheck))
@given(answers())
def test_answer_validates_or_one_line(text):
    from motionphysics.init.llm import _validated

    CASES["llm: damaged answer (parse + validate)"] += 1
    try:
        params, clamps, _ = _validated(text)
    except ValueError as err:
        OUTCOMES["llm: answer refused (would be re-asked)"] += 1
        assert "\n" not in str(err) and str(err), str(err)
        return
    OUTCOMES["llm: answer accepted"] += 1
    assert spec(params.cls, "density").contains(params.density)
    for k, v in params.values.items():
        assert spec(params.cls, k).contains(v), (k, v)
    for c in clamps:
        assert c.kind == "clamped" and not spec(params.cls, c.field).contains(c.original)


@settings(max_examples=examples(15), deadline=None, suppress_health_check=list(HealthCheck))
@given(answers(), answers())
def test_two_answers_through_a_server(first, second):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "init"))
    from test_init_llm import FakeChatServer

    from motionphysics.init.llm import LLMError, LLMOptions, ask_material

    CASES["llm: two damaged answers through a chat server (re-ask)"] += 1
    with FakeChatServer([first, second]) as srv:
        opts = LLMOptions(base_url=srv.base_url, model="m", api_key="k", timeout=10, max_retries=0)
        try:
            ans = ask_material("An axe.", None, opts)
            OUTCOMES["llm: server round trip accepted"] += 1
            assert len(ans.raw_answers) in (1, 2)
        except LLMError as err:
            OUTCOMES["llm: server round trip refused in one line"] += 1
            assert "\n" not in str(err) and "re-ask" in str(err)
            assert len(srv.requests) == 2
