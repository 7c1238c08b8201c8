"""``motionphysics init``: JSON schema, --from order, exit status 2 on bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from motionphysics.cli import main
from motionphysics.materials.catalog import MATERIALS, spec


def _run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def test_init_json_schema(capsys):
    rc, out, _ = _run(["init", "A rubber duck hits the ground and bounces back", "--json"], capsys)
    assert rc == 0
    d = json.loads(out)
    mat = d["material"]
    assert mat["class"] == "elastic"
    assert set(mat) == {"class", "density", *MATERIALS["elastic"].names}
    for k in MATERIALS["elastic"].names:
        assert spec("elastic", k).contains(mat[k])
    assert d["backend"] == "kb" and d["raw_answer"] is None
    # The extended table holds rubber's real E (3e6 Pa): used as it is, nothing clamped.
    assert mat["E"] == 3e6 and d["clamped"] == [] and d["ranges"] == "extended"
    assert d["matched"] == "rubber duck" and d["adjusted"] == []
    assert 0 < d["confidence"] <= 1 and d["matches"][0]["name"] == "rubber duck"


def test_init_paper_ranges_clamp_as_the_paper_did(capsys):
    rc, out, _ = _run(
        ["init", "A rubber duck hits the ground and bounces back", "--json", "--ranges", "paper"],
        capsys,
    )
    d = json.loads(out)
    assert rc == 0 and d["ranges"] == "paper" and d["material"]["E"] == 1e7
    # Rubber's real E (3e6 Pa) lies below the paper's elastic floor: reported, never hidden.
    (c,) = d["clamped"]
    assert c["field"] == "E" and c["kind"] == "range floor" and c["clamped"] == 1e7
    assert c["original"] == 3e6
    with pytest.raises(SystemExit) as exc:
        main(["init", "A rubber duck", "--ranges", "cheese"])
    assert exc.value.code == 2 and "--ranges" in capsys.readouterr().err


def test_init_table(capsys):
    rc, out, _ = _run(["init", "Toothpaste is squeezed out of the tube."], capsys)
    assert rc == 0 and "Non-Newtonian fluid" in out and "tau_Y" in out and "range" in out


def test_init_from_file_keeps_order(tmp_path, capsys):
    prompts = [
        "The plane propeller is spinning.",
        "A water droplet splashes.",
        "",
        "The sandcastle is collapsing.",
        "A playdoh figure is squished.",
    ]
    f = tmp_path / "prompts.txt"
    f.write_text("\n".join(prompts) + "\n", encoding="utf-8")
    rc, out, _ = _run(["init", "--from", str(f)], capsys)
    assert rc == 0
    lines = [json.loads(line) for line in out.splitlines()]
    assert [d["prompt"] for d in lines] == [p for p in prompts if p]
    assert [d["material"]["class"] for d in lines] == ["metal", "newtonian", "sand", "plasticine"]


def test_init_median_backend(capsys):
    rc, out, _ = _run(
        ["init", "An axe is hitting the ground.", "--backend", "median", "--json"], capsys
    )
    d = json.loads(out)
    assert rc == 0 and d["backend"] == "median" and d["material"]["class"] == "metal"
    assert d["material"]["E"] == pytest.approx((1e10 + 4e11) / 2)  # the extended range
    rc, out, _ = _run(
        ["init", "An axe is hitting the ground.", "--backend", "median", "--ranges", "paper"]
        + ["--json"],
        capsys,
    )
    assert json.loads(out)["material"]["E"] == pytest.approx((4.5e10 + 4e11) / 2)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["init", ""], "empty"),
        (["init", "x" * 100_000], "too long"),
        (["init"], "exactly one"),
        (["init", "An axe.", "--from", "prompts.txt"], "exactly one"),
    ],
)
def test_init_bad_input_exit_2(argv, match, capsys):
    rc, _, err = _run(argv, capsys)
    assert rc == 2 and match in err and err.count("\n") == 1


def test_init_bad_files_exit_2(tmp_path, capsys):
    bad = tmp_path / "latin1.txt"
    bad.write_bytes("An axe.\nCr\xe8me br\xfbl\xe9e\n".encode("latin-1"))
    rc, _, err = _run(["init", "--from", str(bad)], capsys)
    assert rc == 2 and "line 2: not UTF-8" in err
    img = tmp_path / "broken.png"
    img.write_bytes(b"\x89PNG\r\n\x1a\ntruncated")
    rc, _, err = _run(["init", "An axe.", "--image", str(img)], capsys)
    assert rc == 2 and "not a readable image" in err
    rc, _, err = _run(["init", "--from", str(tmp_path / "nope.txt")], capsys)
    assert rc == 2 and "file not found" in err


def test_init_bad_backend_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["init", "An axe.", "--backend", "oracle"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_init_exit_status_from_a_real_process():
    env = dict(os.environ)
    r = subprocess.run(
        [sys.executable, "-m", "motionphysics", "init", "   "],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert r.returncode == 2
    assert r.stderr.strip().startswith("motionphysics: error: prompt: empty")
    assert "Traceback" not in r.stderr
