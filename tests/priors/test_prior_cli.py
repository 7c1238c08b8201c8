"""``motionphysics prior``: the subcommands exist and bad input is exit status 2, one line
(``--prior tiny``, the removed pixel prior, included)."""

from __future__ import annotations

import pytest

from motionphysics.cli import main


def _run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def test_prior_is_a_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["prior", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "data" in out and "train" in out and "eval" in out


def test_train_on_a_directory_without_shards_is_exit_2(tmp_path, capsys):
    rc, _, err = _run(["--quiet", "prior", "train", str(tmp_path)], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(tmp_path) in lines[0] and "shard" in lines[0]


def test_eval_with_missing_checkpoint_is_exit_2(tmp_path, capsys):
    rc, _, err = _run(["prior", "eval", str(tmp_path / "none.pt"), str(tmp_path)], capsys)
    assert rc == 2 and "none.pt" in err and len(err.strip().splitlines()) == 1


def test_non_positive_clip_count_is_rejected(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["prior", "data", str(tmp_path / "d"), "--clips", "0"])
    assert e.value.code == 2
    assert "--clips" in capsys.readouterr().err


REMOVED = (
    "--prior tiny: the embedded pixel prior was removed (it could not tell motions apart: "
    "20 % held-out caption discrimination); use --prior motion (the embedded default) or "
    "--prior cogvideox/modelscope with a local model path (--prior-path DIR)"
)


@pytest.mark.parametrize("step", ["data", "train", "eval"])
def test_the_removed_pixel_prior_is_refused_in_one_line(tmp_path, capsys, step):
    where = {
        "data": [str(tmp_path / "d")],
        "train": [str(tmp_path)],
        "eval": [str(tmp_path / "w.pt"), str(tmp_path)],
    }[step]
    rc, out, err = _run(["prior", step, *where, "--prior", "tiny"], capsys)
    assert rc == 2 and out == ""
    assert err.strip().splitlines() == [f"motionphysics: error: {REMOVED}"]
    assert not (tmp_path / "d").exists()  # refused before any work


def test_prior_help_offers_only_the_motion_prior(capsys):
    with pytest.raises(SystemExit):
        main(["prior", "train", "--help"])
    out = capsys.readouterr().out
    assert "--prior {motion}" in out and "tiny" not in out
