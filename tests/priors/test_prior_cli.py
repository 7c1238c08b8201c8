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


def test_data_counts_the_clips_it_holds_and_names_why_the_others_failed(
    tmp_path, capsys, monkeypatch
):
    """`prior data` reports the clips the shards hold, not the count asked: draws that
    never simulate are left out and the line says how many and why; when none simulated
    it stops with exit 2 (on a GPU machine without trimesh it printed "64 clips" for
    shards that held none, and `prior train` then said only "the shards hold no clips")."""
    from motionphysics.errors import SimulationError
    from motionphysics.priors import motion_data

    real = motion_data.simulate_clip

    def unstable_for_clip_1(spec):
        if spec.index == 1:
            raise SimulationError("frame 3: velocity ran away")
        return real(spec)

    monkeypatch.setattr(motion_data, "simulate_clip", unstable_for_clip_1)
    out_dir = tmp_path / "d"
    rc, out, _ = _run(["--quiet", "prior", "data", str(out_dir), "--clips", "2"], capsys)
    assert rc == 0
    assert out.startswith(f"{out_dir}: 1 clips (seed 0")
    assert "1 of 2 failed to simulate and were left out" in out
    assert "SimulationError: frame 3: velocity ran away" in out

    def never(spec):
        raise SimulationError("frame 0: NaN")

    monkeypatch.setattr(motion_data, "simulate_clip", never)
    rc, _, err = _run(["--quiet", "prior", "data", str(tmp_path / "e"), "--clips", "1"], capsys)
    assert rc == 2
    (line,) = err.strip().splitlines()
    assert "no clip simulated" in line and "SimulationError: frame 0: NaN" in line


def test_data_lets_a_broken_install_through_instead_of_calling_it_an_unstable_draw(
    tmp_path, capsys, monkeypatch
):
    from motionphysics.priors import motion_data

    def no_trimesh(spec):
        raise ModuleNotFoundError("No module named 'trimesh'")

    monkeypatch.setattr(motion_data, "simulate_clip", no_trimesh)
    with pytest.raises(ModuleNotFoundError, match="trimesh"):
        main(["--quiet", "prior", "data", str(tmp_path / "d"), "--clips", "1"])
