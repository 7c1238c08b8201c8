"""load_scene dispatch and its one-line user errors; the CLI turns them into exit status 2."""

from __future__ import annotations

import pytest

from motionphysics.errors import UserInputError
from motionphysics.scene import load_scene, write_ply
from motionphysics.scene.builtin import build_builtin


@pytest.mark.parametrize(
    "source, needle",
    [
        ("", "scene.source"),
        ("scene.xyz", "unsupported scene file extension"),
        ("noext", "unsupported"),
        ("missing.ply", "not found"),
        ("missing.obj", "not found"),
        ("builtin:", "unknown builtin"),
    ],
)
def test_bad_sources(tmp_path, source, needle):
    src = str(tmp_path / source) if source and not source.startswith("builtin:") else source
    with pytest.raises(UserInputError) as e:
        load_scene(src)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg


def test_dispatch_3dgs_ply_keeps_values(tmp_path):
    s = build_builtin("cube")
    path = write_ply(s, tmp_path / "cube.ply")
    back = load_scene(str(path))
    assert back.num == s.num and bool((back.means == s.means).all())


def test_cli_exit_status_for_bad_scene(tmp_path, capsys):
    from motionphysics.cli import main

    # The render command loads through load_scene: a bad source is a one-line exit 2.
    rc = main(["render", "builtin:unicorn", "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "builtin:unicorn" in err[0]
