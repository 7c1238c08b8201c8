"""The LLM inquiry prompt follows the paper's template and carries every range."""

from __future__ import annotations

import base64

from motionphysics.init.prompt import build_messages, build_prompt
from motionphysics.materials.catalog import DENSITY, materials, use_ranges

# The appendix table's ranges as they must read in the prompt (SI units).
PAPER_RANGES = [
    "E: 1e7 - 4e11 Pa",
    "nu: 0.1 - 0.5",  # elastic
    "E: 1e6 - 5e6 Pa",
    "nu: 0.3 - 0.4",
    "tau_Y: 5e3 - 2e4 Pa",  # plasticine
    "E: 4.5e10 - 4e11 Pa",
    "nu: 0.25 - 0.35",
    "tau_Y: 1e7 - 2e9 Pa",  # metal
    "E: 1e3 - 1e7 Pa",
    "nu: 0 - 0.3",
    "tau_Y: 1e4 - 1e6 Pa",
    "eta: 0.1 - 1",  # foam
    "theta_fric: 27 - 45 deg",  # sand
    "mu: 1e-3 - 10 Pa s",
    "kappa: 1e9 - 5e9 Pa",  # newtonian
    "mu: 1e-3 - 1e3 Pa s",
    "tau_Y: 1 - 2e3 Pa",
    "n: 0.3 - 1",  # non-newtonian
    "10 - 2.3e4 kg/m^3",  # density
]


# The extended table (the default) where it widens the paper's.
EXTENDED_RANGES = [
    "E: 1e3 - 4e11 Pa",  # elastic: down to gels
    "E: 1e5 - 1e8 Pa",
    "tau_Y: 1e3 - 1e6 Pa",  # plasticine
    "E: 1e10 - 4e11 Pa",
    "nu: 0.25 - 0.45",
    "tau_Y: 1e6 - 2e9 Pa",  # metal
    "E: 1e3 - 1e8 Pa",  # foam
    "theta_fric: 20 - 50 deg",  # sand
    "mu: 1e-4 - 1e4 Pa s",  # newtonian: oozing at tens of centimetres
    "mu: 1e-3 - 1e4 Pa s",
    "tau_Y: 1 - 1e4 Pa",
    "n: 0.2 - 1",  # non-newtonian
    "10 - 2.3e4 kg/m^3",  # density
]


def test_ranged_prompt_contains_every_range_of_the_table():
    for table, expected in (("paper", PAPER_RANGES), ("extended", EXTENDED_RANGES)):
        text = build_prompt("An axe is hitting the ground.", table=table)
        for r in expected:
            assert r in text, (table, r)
        for cls, mc in materials(table).items():
            assert f'("{cls}")' in text
            for ps in mc.params:
                assert f"{ps.name}: {ps.range_text()}" in text
        assert DENSITY.range_text() in text
    # the default is the extended table, which also says what modifiers do
    default = build_prompt("An axe is hitting the ground.")
    assert default == build_prompt("An axe is hitting the ground.", table="extended")
    assert "E: 1e3 - 4e11 Pa" in default and "do not change the type" in default
    with use_ranges("paper"):  # a run with init.ranges: paper
        assert "E: 1e7 - 4e11 Pa" in build_prompt("An axe.")
        assert "do not change the type" not in build_prompt("An axe.")


def test_prompt_structure_follows_the_paper():
    text = build_prompt("An axe is hitting the ground.", has_image=True)
    order = [
        "Textual simulation prompt",
        "Reference image",
        "What is this object?",
        "primarily on the textual simulation prompt",
        "secondary visual reference only",
        "must strictly fall within",
        "Respond in this exact format",
        "Only include fields relevant",
    ]
    positions = [text.index(s) for s in order]
    assert positions == sorted(positions)
    for key in ("material_type", "density", "E", "nu", "tau_Y", "mu", "kappa", "eta", "theta_fric"):
        assert f'"{key}": ' in text


def test_naive_prompt_has_no_ranges():
    text = build_prompt("An axe.", ranged=False)
    assert "must strictly fall within" not in text
    assert "4e11" not in text and "Respond in this exact format" in text


def test_messages_with_and_without_image():
    msgs = build_messages("An axe.")
    assert [m["role"] for m in msgs] == ["system", "user"] and isinstance(msgs[1]["content"], str)
    png = b"\x89PNG\r\n\x1a\nfake"
    msgs = build_messages("An axe.", image_png=png)
    parts = msgs[1]["content"]
    assert parts[0]["type"] == "text" and "Reference image" in parts[0]["text"]
    url = parts[1]["image_url"]["url"]
    assert base64.b64decode(url.split(",", 1)[1]) == png
