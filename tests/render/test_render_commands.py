"""The ``render`` and ``bench render`` commands through the CLI entry point."""

import json

import imageio.v2 as imageio
import numpy as np
import pytest

from motionphysics import cli


@pytest.fixture
def run_cli(monkeypatch):
    # Only this helper's commands: others may be mid-edit while these tests run.
    monkeypatch.setattr(cli, "COMMANDS", ["render", "bench"])
    return cli.main


def test_render_builtin_writes_png(run_cli, tmp_path):
    out = tmp_path / "sphere.png"
    assert (
        run_cli(["render", "builtin:sphere", "--out", str(out), "--width", "64", "--height", "48"])
        == 0
    )
    img = imageio.imread(out)
    assert img.shape == (48, 64, 3)
    # Something is drawn on the white background, and it is framed (border stays white).
    assert (img < 250).any(axis=-1).mean() > 0.05
    assert (img[0] >= 250).all() and (img[-1] >= 250).all()


def test_render_inria_ply(run_cli, tmp_path):
    from motionphysics.scene import load_scene
    from motionphysics.scene.ply import write_ply

    ply = tmp_path / "duck.ply"
    write_ply(load_scene("builtin:duck"), ply)
    out = tmp_path / "duck.png"
    assert (
        run_cli(
            [
                "render",
                str(ply),
                "--out",
                str(out),
                "--width",
                "40",
                "--height",
                "40",
                "--azimuth",
                "120",
                "--elevation",
                "10",
            ]
        )
        == 0
    )
    assert (imageio.imread(out) < 250).any(axis=-1).mean() > 0.05


def test_render_orbit_gif(run_cli, tmp_path):
    out = tmp_path / "orbit.gif"
    assert (
        run_cli(
            [
                "render",
                "builtin:cube",
                "--orbit",
                "--frames",
                "3",
                "--out",
                str(out),
                "--width",
                "32",
                "--height",
                "32",
            ]
        )
        == 0
    )
    from motionphysics.io.video import read_video

    frames = read_video(out)
    assert frames.shape == (3, 32, 32, 3)
    assert np.abs(frames[0].astype(int) - frames[1].astype(int)).max() > 0


@pytest.mark.parametrize(
    "args,msg",
    [
        (["builtin:nope", "--out", "x.png"], "builtin"),
        (["builtin:sphere", "--out", "x.mp4"], "--out"),
        (["builtin:sphere", "--orbit", "--out", "x.png"], "--orbit"),
        (["builtin:sphere", "--out", "x.png", "--fov", "0"], "--fov"),
        (["missing.ply", "--out", "x.png"], "missing.ply"),
    ],
)
def test_render_bad_input_exits_2_with_one_line(run_cli, tmp_path, capsys, args, msg):
    args = [a.replace("x.", str(tmp_path / "x.")) for a in args]
    assert run_cli(["render", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and msg in err


def test_bench_render_json(run_cli, capsys):
    assert (
        run_cli(
            [
                "bench",
                "render",
                "--splats",
                "300",
                "--size",
                "32",
                "--backward",
                "--repeats",
                "2",
                "--threads",
                "1",
                "--json",
            ]
        )
        == 0
    )
    res = json.loads(capsys.readouterr().out)
    assert res["splats"] == 300 and res["size"] == 32 and res["backward"] is True
    assert len(res["seconds"]) == 2 and res["seconds_median"] > 0
    assert res["coverage"] > 0.05


def test_render_every_builtin(run_cli, tmp_path):
    from motionphysics.scene.builtin import list_builtins

    names = [name for name, _ in list_builtins()]
    assert names
    for name in names:
        out = tmp_path / f"{name}.png"
        assert (
            run_cli(
                ["render", f"builtin:{name}", "--out", str(out), "--width", "24", "--height", "24"]
            )
            == 0
        ), name
        assert (imageio.imread(out) < 250).any(axis=-1).mean() > 0.02, name
