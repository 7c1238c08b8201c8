"""The examples trust the sentence: most leave `material` out and the kb reads the class
from the prompt; each has its gallery GIF; every motion group of the motion prior has an
example whose simulated motion falls in that group by the prior's own rules.

The gallery record (docs/gallery/gallery.json, written by docs/gallery/make_gallery.py
from real runs) must belong to the current files: an example edited without regenerating
its GIF fails here. The slow test re-simulates the group examples and measures them again.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from motionphysics.config import load_config

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
GALLERY = ROOT / "docs" / "gallery"
RECORD = GALLERY / "gallery.json"
OWN = sorted(EXAMPLES.glob("*.yaml"))

GROUP_EXAMPLE = {
    "bounces_high": "bouncy_ball",
    "barely_bounces": "wooden_block",
    "wobbles": "jelly_cube",
    "splashes": "newtonian_droplet",
    "oozes": "lava_blob",
    "keeps_shape": "steel_block",
    "crumbles": "sand_column",
    "squashes_flat": "plasticine_blob",
}
"""One example per motion group of the motion prior (language.captions.GROUPS)."""

KB_CLASS = {
    "bouncy_ball": "elastic",
    "demo": "elastic",
    "elastic_ball": "elastic",
    "jelly_cube": "elastic",
    "lava_blob": "newtonian",
    "metal_rod": "metal",
    "newtonian_dam_break": "newtonian",
    "newtonian_droplet": "newtonian",
    "plasticine_blob": "plasticine",
    "sand_column": "sand",
    "steel_block": "metal",
    "wooden_block": "elastic",
}
"""The class a person reads in each example's sentence (the examples without `material`)."""


def record() -> dict:
    return json.loads(RECORD.read_text(encoding="utf-8"))


def leaves_material_out(path: Path) -> bool:
    return "material" not in (yaml.safe_load(path.read_text(encoding="utf-8")) or {})


def test_at_least_half_of_the_examples_let_the_words_decide():
    free = [p.stem for p in OWN if leaves_material_out(p)]
    assert 2 * len(free) >= len(OWN), (free, [p.stem for p in OWN])
    assert sorted(free) == sorted(KB_CLASS), "KB_CLASS lists exactly the examples without material"


def test_the_kb_reads_the_class_a_person_reads():
    from motionphysics.init.estimate import estimate_many

    names = sorted(KB_CLASS)
    prompts = [load_config(EXAMPLES / f"{n}.yaml").prompt for n in names]
    got = {n: e.cls for n, e in zip(names, estimate_many(prompts), strict=True)}
    assert got == KB_CLASS


def test_every_motion_group_has_an_example():
    from motionphysics.language.captions import GROUPS

    assert sorted(GROUP_EXAMPLE) == sorted(GROUPS)
    for name in GROUP_EXAMPLE.values():
        assert (EXAMPLES / f"{name}.yaml").is_file(), name


def test_each_group_example_says_its_motion():
    """The sentence makes the claim of its group (the prior's prompt reader agrees)."""
    from motionphysics.language.captions import prompt_motion_group

    wrong = {}
    for group, name in GROUP_EXAMPLE.items():
        said, sim = prompt_motion_group(load_config(EXAMPLES / f"{name}.yaml").prompt)
        if said != group:
            wrong[name] = (group, said, round(sim, 3))
    assert not wrong, wrong


@pytest.mark.parametrize("path", [*OWN, EXAMPLES / "objects" / "axe_and_duck.yaml"], ids=str)
def test_each_example_has_its_gallery_gif(path):
    from PIL import Image

    gif = GALLERY / f"{path.stem}.gif"
    assert gif.is_file(), (
        f"no {gif.relative_to(ROOT)}: .venv/bin/python docs/gallery/make_gallery.py"
    )
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames >= 10, (im.format, im.n_frames)


def test_the_gallery_record_belongs_to_the_current_examples():
    rec = record()
    stale = []
    for path in OWN:
        r = rec.get(path.stem)
        if r is None:
            continue  # an example whose GIF predates the record (checked above to exist)
        sha = hashlib.sha256(path.read_bytes()).hexdigest()
        if r["config_sha256"] != sha:
            stale.append(path.stem)
    assert not stale, f"examples changed since their GIF was made: {stale}"
    for name in [*GROUP_EXAMPLE.values(), *KB_CLASS]:
        if name == "demo":
            continue  # the demo's GIF is the full-size `make demo` run
        assert name in rec, f"{name}: no gallery record; run docs/gallery/make_gallery.py {name}"


def test_each_group_example_was_measured_in_its_group():
    rec = record()
    got = {g: rec[n]["measured_group"] for g, n in GROUP_EXAMPLE.items()}
    assert got == {g: g for g in GROUP_EXAMPLE}, got
    for name in KB_CLASS:
        if name in rec:
            assert rec[name]["class"] == KB_CLASS[name] and rec[name]["source"] == "kb", name


@pytest.mark.slow
@pytest.mark.parametrize("group", sorted(GROUP_EXAMPLE))
def test_group_example_simulates_into_its_group(group, tmp_path):
    """Re-run the example at gallery size and measure it with the prior's rules."""
    sys.path.insert(0, str(GALLERY))
    try:
        import make_gallery
    finally:
        sys.path.pop(0)
    name = GROUP_EXAMPLE[group]
    cfg, _ = make_gallery.reduced(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()))
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    out = tmp_path / name
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "motionphysics",
            "--quiet",
            "simulate",
            str(path),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = make_gallery.measure(out)
    assert got["measured_group"] == group, got
