"""init.ranges: the extended table (the default) and the paper's table.

``init.ranges: paper`` must reproduce what the paper-table code estimated:
``tests/data/paper_ranges_today.json`` holds the outputs of commit 0c2e362 (before the
extended table), recorded with that commit's code: kb estimates of every prompt of
tests/data/prompts.csv and a few more, the median baseline, LLM answers validated and
resolved, and the LLM inquiry texts.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from motionphysics.init import EstimateOptions, estimate_many
from motionphysics.init.baselines import median_params
from motionphysics.init.llm import _validated
from motionphysics.init.prompt import build_objects_prompt, build_prompt
from motionphysics.materials.catalog import MATERIALS, PAPER_MATERIALS, spec, use_ranges
from motionphysics.materials.resolve import resolve_material

TODAY = json.loads(
    (Path(__file__).resolve().parents[1] / "data" / "paper_ranges_today.json").read_text()
)

# The only prompts whose paper-table estimate differs from 0c2e362, each on purpose:
# a modifier now moves the named material's value (the paper's table then clamps it,
# often to the same value, but the substitution reports the moved real value), or the kb
# now has an entry of its own for what jelly / silicone rubber stood in for.
CHANGED = {
    "A toy dinosaur made of soft rubber bounces off the floor.": "modifier soft",
    "A soft toy cat bounces when dropped.": "modifier soft",
    "A soft wax candle is pressed and stays dented.": "modifier soft",
    "A squishy rubber frog is tossed onto the bed.": "modifier squishy",
    "Soft clay is pressed by a thumb.": "modifier soft",
    "A gummy bear is squeezed and returns to its shape.": "entry gummy candy (was jelly)",
    "A gummy bear is squeezed and bounces back.": "entry gummy candy (was jelly)",
    "A soft silicone spatula bends and springs back.": "entry soft silicone",
}


@pytest.fixture(scope="module")
def paper_estimates():
    prompts = [k["prompt"] for k in TODAY["kb"]]
    opts = EstimateOptions(announce=False, ranges="paper")
    return dict(zip(prompts, estimate_many(prompts, backend="kb", options=opts), strict=True))


def test_paper_table_reproduces_the_kb_estimates(paper_estimates):
    assert len(TODAY["kb"]) >= 300
    wrong, unchanged = [], []
    for k in TODAY["kb"]:
        est = paper_estimates[k["prompt"]]
        got = {
            "class": est.cls,
            "density": est.density,
            "values": est.values,
            "clamped": [c.to_dict() for c in est.clamped],
        }
        want = {f: k[f] for f in ("class", "density", "values", "clamped")}
        assert est.ranges == "paper"
        if k["prompt"] in CHANGED:
            assert est.cls == k["class"], k["prompt"]  # never another class
            if got == want:
                unchanged.append(k["prompt"])
        elif got != want:
            wrong.append((k["prompt"], want, got))
    assert not wrong, wrong[:5]
    assert not unchanged, f"listed in CHANGED but reproduced: {unchanged}"


def test_paper_table_values_stay_in_the_papers_ranges(paper_estimates):
    for est in paper_estimates.values():
        for name, v in {"density": est.density, **est.values}.items():
            assert spec(est.cls, name, "paper").contains(v), (est.prompt, name, v)


def test_paper_table_reproduces_the_median_baseline():
    for key, want in TODAY["median"].items():
        cls, kind = key.split("/")
        got = median_params(cls, kind, "paper")
        assert got.density == want["density"] and got.values == want["values"], key


def test_paper_table_reproduces_llm_clamps_and_resolution():
    for rec in TODAY["llm"]:
        params, clamps, _ = _validated(rec["answer"], "llm", "paper")
        assert params.cls == rec["class"] and params.density == rec["density"]
        assert params.values == rec["values"]
        assert [c.to_dict() for c in clamps] == rec["clamped"], rec["answer"]
    for rec in TODAY["resolve"]:
        d = json.loads(rec["estimate"])
        cls, rho = d.pop("material_type"), d.pop("density")
        est = {"class": cls, "density": rho, "params": d, "backend": "llm", "clamps": []}
        res = resolve_material(None, {}, estimate=est, ranges="paper")
        m = res["material"]
        assert (m.cls, m.density, m.values) == (rec["class"], rec["density"], rec["values"])
        assert res["clamps"] == rec["clamps"] and res["ranges"] == "paper"
        # the same through the active table of a run (init.ranges: paper)
        with use_ranges("paper"):
            assert resolve_material(None, {}, estimate=est)["clamps"] == rec["clamps"]


def test_paper_table_reproduces_the_llm_inquiry():
    for rec in TODAY["llm_inquiry"]:
        text = build_prompt(
            rec["text"], ranged=rec["ranged"], has_image=rec["has_image"], table="paper"
        )
        assert text == rec["inquiry"]
    (rec,) = TODAY["llm_objects_inquiry"]
    assert build_objects_prompt(rec["text"], rec["names"], table="paper") == rec["inquiry"]


def test_extended_table_changes_only_what_the_paper_left_out(paper_estimates):
    """Under the extended table (the default) the kb keeps the real values the paper's
    table clamped: jelly 5e3 Pa, tofu 3e4 Pa, rubber 2e6 Pa, lava 300 Pa s, lead's E..."""
    prompts = [k["prompt"] for k in TODAY["kb"]]
    ext = dict(
        zip(prompts, estimate_many(prompts, options=EstimateOptions(announce=False)), strict=True)
    )
    moved = 0
    for p in prompts:
        e, pp = ext[p], paper_estimates[p]
        assert e.ranges == "extended" and e.cls == pp.cls, p
        for name, v in e.values.items():
            if v != pp.values[name]:
                moved += 1
                # only values the paper's table clamped move, and then to a value
                # beyond the paper's range (or one a modifier moved)
                assert any(c.field == name for c in pp.clamped), (p, name)
                assert not spec(e.cls, name, "paper").contains(v), (p, name, v)
    assert moved >= 20
    jelly = ext["A wobbly jelly cube."]
    assert jelly.cls == "elastic" and jelly.values["E"] == 5e3 and jelly.clamped == []
    lava = ext["Lava flows down the slope."]
    assert lava.values["mu"] == 300.0 and lava.clamped == []


def test_every_extended_range_holds_the_papers():
    for cls, mc in MATERIALS.items():
        paper = PAPER_MATERIALS[cls]
        assert mc.names == paper.names
        for ps, pp in zip(mc.params, paper.params, strict=True):
            assert ps.low <= pp.low and ps.high >= pp.high, (cls, ps.name)
            assert bool(ps.note) == ((ps.low, ps.high) != (pp.low, pp.high)), (cls, ps.name)


JELLY = """\
scene: {source: "builtin:cube", scale: 0.2, translate: [0, 0, 0.12], max_particles: 600}
prompt: "A wobbly jelly cube."
sim: {grid: 16, frames: 3, frame_dt: 0.04, substeps: auto}
boundary_conditions:
  - {type: surface_collider, point: [0, 0, 0], normal: [0, 0, 1], mode: frictional, friction: 0.3}
  - {type: bounding_box}
camera: {width: 32, height: 24}
"""


def test_init_ranges_config_key(tmp_path):
    from motionphysics.config import load_config
    from motionphysics.errors import UserInputError

    cfg = tmp_path / "c.yaml"
    cfg.write_text(JELLY)
    assert load_config(cfg).init.ranges == "extended"  # the default
    cfg.write_text(JELLY + "init: {ranges: paper}\n")
    assert load_config(cfg).init.ranges == "paper"
    cfg.write_text(JELLY + "init: {ranges: handbook}\n")
    with pytest.raises(UserInputError) as err:
        load_config(cfg)
    assert "init.ranges" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("table", ["extended", "paper"])
def test_jelly_through_simulate_keeps_its_real_modulus(tmp_path, table, capsys):
    """A wobbly jelly cube, words only: the kb's jelly (elastic, E = 5e3 Pa) lands in
    params.json as it is; with init.ranges: paper it is clamped to the paper's elastic
    floor, as the paper's table did, and the substitution is reported."""
    from motionphysics.cli import main

    cfg = tmp_path / "jelly.yaml"
    cfg.write_text(JELLY + ("init: {ranges: paper}\n" if table == "paper" else ""))
    out = tmp_path / "run"
    assert main(["--quiet", "simulate", str(cfg), "--out", str(out)]) == 0
    capsys.readouterr()
    p = json.loads((out / "params.json").read_text())
    assert p["class"] == "elastic" and p["provenance"]["estimate"]["ranges"] == table
    clamps = [c for c in p["provenance"]["clamps"] if c["kind"] != "mapped to simulation"]
    if table == "extended":
        assert p["params"]["E"] == 5e3 and clamps == []
    else:
        assert p["params"]["E"] == 1e7
        assert clamps == [
            {
                "field": "E",
                "original": 5e3,
                "clamped": 1e7,
                "kind": "range floor",
                "source": "kb",
            }
        ]
    assert yaml.safe_load((out / "run.yaml").read_text())["init"] == {"ranges": table}
