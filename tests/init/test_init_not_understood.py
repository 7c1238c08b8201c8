"""No guess passed off as an answer (issue 27, item 4).

When the kb understands too little of a prompt to name a class (``kb.UNDERSTOOD_RULE``: no
word of it is a material or object it knows, a class word or a behaviour cue), ``init``
and ``run`` / ``simulate`` stop with exit status 2 and one line that says what it
understood and how to go on, unless the config gives ``material.class``; ``init --from``
writes an error record for such a line and goes on with the others.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from motionphysics.cli import main
from motionphysics.init import EstimateOptions, estimate_many
from motionphysics.init.kb import SEMANTIC_EVIDENCE, get_matcher

NOT_UNDERSTOOD = [
    "果冻在桌子上晃动",  # "the jelly wobbles on the table"
    "一个橡皮球掉在地上弹起来",
    "Una pelota de goma rebota en el suelo",
    "Der Gummiball fällt auf den Boden und springt zurück",
    "Le ballon tombe sur la table et rebondit",
    "Резиновый мяч падает на пол",
    "ゼリーがテーブルの上で揺れる",
    "A thing falls.",
]
UNDERSTOOD = [
    "A ball falls.",  # a shape word: a guess, said as "not sure", not refused
    "Something wobbles.",  # a behaviour cue
    "果冻 jelly wobbles on the table",  # one known word is enough
    "A soft donut drops onto the table.",
]


def test_the_threshold_is_no_known_word():
    got = get_matcher(announce=False).match_many(NOT_UNDERSTOOD + UNDERSTOOD)
    for prompt, m in zip(NOT_UNDERSTOOD, got, strict=False):
        assert not m.names_class and m.evidence == "semantic", prompt
        assert m.confidence <= SEMANTIC_EVIDENCE
    for prompt, m in zip(UNDERSTOOD, got[len(NOT_UNDERSTOOD) :], strict=True):
        assert m.names_class and m.understood, prompt
    ests = estimate_many(NOT_UNDERSTOOD + UNDERSTOOD, options=EstimateOptions(announce=False))
    assert all(e.error for e in ests[: len(NOT_UNDERSTOOD)])
    assert not any(e.error for e in ests[len(NOT_UNDERSTOOD) :])


@pytest.mark.parametrize("prompt", NOT_UNDERSTOOD)
def test_init_stops_with_one_line(prompt, capsys):
    assert main(["init", prompt]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1, err
    assert err.startswith("motionphysics: error: prompt: the kb backend cannot name a material")
    assert "--backend llm" in err and "in English" in err and "material.class" in err
    if prompt != "A thing falls.":
        assert "the kb reads English only" in err


def test_init_says_which_words_it_understood(capsys):
    assert main(["init", "A soft thing falls."]) == 2
    err = capsys.readouterr().err
    assert "it understood only 'soft'" in err and err.count("\n") == 1


def test_init_median_needs_the_kb_class_or_a_given_one(capsys):
    assert main(["init", "果冻在桌子上晃动", "--backend", "median"]) == 2
    assert "cannot name a material class" in capsys.readouterr().err
    rc = main(["init", "果冻在桌子上晃动", "--backend", "median", "--class", "elastic", "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["material"]["class"] == "elastic"


def test_init_from_file_writes_an_error_record_and_goes_on(tmp_path, capsys):
    prompts = ["A jelly wobbles.", "果冻在桌子上晃动", "Honey drips.", "A thing falls."]
    f = tmp_path / "prompts.txt"
    f.write_text("\n".join(prompts) + "\n", encoding="utf-8")
    assert main(["init", "--from", str(f)]) == 0
    out, err = capsys.readouterr()
    lines = [json.loads(line) for line in out.splitlines()]
    assert [d["prompt"] for d in lines] == prompts
    assert [d.get("material", {}).get("class") for d in lines] == [
        "elastic",
        None,
        "newtonian",
        None,
    ]
    for k in (1, 3):
        assert set(lines[k]) == {"prompt", "error", "understood"}
        assert lines[k]["error"].startswith("prompt: the kb backend cannot name")
    assert f"--from {f}: line 2: error: prompt:" in err and "line 4: error:" in err


def test_a_real_process_prints_only_the_line():
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    r = subprocess.run(
        [sys.executable, "-m", "motionphysics", "init", "果冻在桌子上晃动"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr


CONFIG = """\
scene: {{source: "builtin:cube", scale: 0.2, translate: [0, 0, 0.12], max_particles: 500}}
prompt: "{prompt}"
sim: {{grid: 16, frames: 2, frame_dt: 0.04, substeps: auto}}
camera: {{width: 32, height: 24}}
"""


@pytest.mark.parametrize("command", ["simulate", "run"])
def test_a_run_stops_unless_the_config_gives_the_class(tmp_path, capsys, command):
    cfg = tmp_path / "zh.yaml"
    cfg.write_text(CONFIG.format(prompt="果冻在桌子上晃动"), encoding="utf-8")
    assert main(["--quiet", command, str(cfg), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "cannot name a material class" in err
    assert "material.class in the config" in err and "--init llm" in err
    if command == "run":
        return
    # The class given: the run goes on, and no value of the kb's guess is used.
    cfg.write_text(
        CONFIG.format(prompt="果冻在桌子上晃动") + "material: {class: elastic, E: 5.0e3}\n",
        encoding="utf-8",
    )
    out = tmp_path / "b"
    assert main(["--quiet", command, str(cfg), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    p = json.loads((out / "params.json").read_text())
    assert p["class"] == "elastic" and p["params"]["E"] == 5.0e3
    assert p["provenance"]["sources"]["nu"] == "range centre of elastic"
    assert p["provenance"]["sources"]["density"] == "range centre of elastic"
    assert "from the centre of the class range" in err and "ceramic" not in err


MOTION_ONLY = [
    # (prompt, class, kb entry): no word names a material, an object the kb knows, a
    # class or a cue; the motion words read as a motion group (MiniLM against the
    # prior's training phrasings, never its held-out ones) and that group's material
    ("A ring disintegrates into a pile.", "sand", "dry sand"),
    ("A ring splatters across the floor.", "newtonian", "water"),
    ("A ring gets flattened and stays that way.", "plasticine", "plasticine"),
    ("A ring jumps right back up after it hits the floor.", "elastic", "rubber"),
    # a word that names only what a thing depicts ("duck": the kb's animal figure) is no
    # material: the motion decides; a material-bearing object keeps its material
    ("A duck disintegrates into a pile.", "sand", "dry sand"),
]


def test_a_prompt_that_only_describes_a_motion_gets_that_motions_material(tmp_path, capsys):
    """``simulate CONFIG`` with a config whose prompt names no material but a motion: the
    run goes on with the motion's class, says so in one warning, and keeps the evidence
    semantic (low confidence); a prompt with neither stays refused (above)."""
    for k, (prompt, cls, entry) in enumerate(MOTION_ONLY):
        cfg = tmp_path / f"m{k}.yaml"
        cfg.write_text(CONFIG.format(prompt=prompt), encoding="utf-8")
        out = tmp_path / f"m{k}"
        assert main(["--quiet", "simulate", str(cfg), "--out", str(out)]) == 0, prompt
        err = capsys.readouterr().err
        said = [ln for ln in err.splitlines() if "reads as the motion" in ln]
        assert len(said) == 1 and f"-> {cls} ({entry})" in said[0], err
        assert "name the material" in said[0]
        params = json.loads((out / "params.json").read_text())
        assert params["class"] == cls, prompt
        est = params["provenance"]["estimate"]
        assert est["source"].startswith(f"{entry}:") and est["confidence"] < 0.5


def test_a_material_bearing_object_keeps_its_material():
    got = get_matcher(announce=False).match_many(
        ["A rubber ball squashes when it lands.", "A steel ball splashes into the pool."]
    )
    assert [m.cls for m in got] == ["elastic", "metal"]
    assert not any("reads as the motion" in w for m in got for w in m.warnings)
