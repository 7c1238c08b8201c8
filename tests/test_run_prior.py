"""``motionphysics run --prior cogvideox|modelscope --prior-path DIR`` end to end.

The prior directories are tiny seeded random pipelines written by diffusers'
``save_pretrained`` and read back through the real loading code: ours
(:mod:`tests.priors.tiny_pipelines`) and *foreign* ones whose component configs differ
(other latent channel counts, text lengths, patch size, VAE depth, scheduler options, a
BPE sentencepiece T5 tokenizer with extra ids, a CLIP BPE tokenizer with other merges
and length), standing in for directories written by someone else.

What a run must give: a complete run directory, ``log.jsonl`` with one finite record per
iteration whose gradient reached theta (finite, non-zero) and moved it, ``params.json``
with the history and the initial and final parameters side by side, the loss and
parameter plots, ``prior_reference.mp4`` for the losses that sample one, and the final
simulation at the full frame rate from the refined parameters.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from tests.conftest import tiny_config_data
from tests.priors.tiny_pipelines import CORPUS, tiny_dir, write_diffusers_dummy_modelscope

from motionphysics.cli import main

FRAMES = 4
LOSSES = ["lmd", "sds", "flow", "video"]
PRIORS = ["cogvideox", "modelscope"]


# --------------------------------------------------------------------------- foreign dirs
def foreign_t5_tokenizer(directory: Path):
    """A T5 tokenizer from a sentencepiece *BPE* model file (100 extra ids), unlike ours."""
    import sentencepiece as spm
    from transformers import T5Tokenizer

    directory.mkdir(parents=True, exist_ok=True)
    spm.SentencePieceTrainer.train(
        sentence_iterator=iter(CORPUS * 3),
        model_prefix=str(directory / "spm"),
        vocab_size=60,
        model_type="bpe",
        pad_id=0,
        eos_id=1,
        unk_id=2,
        bos_id=-1,
        hard_vocab_limit=False,
        minloglevel=2,
    )
    return T5Tokenizer(vocab_file=str(directory / "spm.model"), model_max_length=8)


def write_foreign_cogvideox(directory: Path, seed: int = 3) -> Path:
    """CogVideoX with 8 latent channels, patch size 1, text length 8, T5 width 24,
    an epsilon-free v-prediction DDPM-style scheduler config with other betas."""
    from diffusers import CogVideoXDPMScheduler
    from tests.priors.tiny_pipelines import write_cogvideox_pipeline

    scheduler = CogVideoXDPMScheduler(
        snr_shift_scale=1.0,
        beta_start=0.001,
        beta_end=0.02,
        beta_schedule="scaled_linear",
        prediction_type="v_prediction",
        rescale_betas_zero_snr=True,
        timestep_spacing="trailing",
    )
    return write_cogvideox_pipeline(
        directory,
        foreign_t5_tokenizer(directory.parent / (directory.name + "-spm")),
        scheduler,
        seed=seed,
        reseed=False,
        transformer={
            "num_attention_heads": 2,
            "attention_head_dim": 16,  # inner 32: the sin-cos split 1/4 time, 3/8 + 3/8 space
            "in_channels": 8,
            "out_channels": 8,
            "time_embed_dim": 4,
            "text_embed_dim": 24,
            "num_layers": 2,
            "sample_frames": 13,
            "patch_size": 1,
            "max_text_seq_length": 8,
        },
        vae={"block_out_channels": (4, 8, 8, 8), "latent_channels": 8, "scaling_factor": 0.7},
        text={
            "d_model": 24,
            "d_kv": 6,
            "d_ff": 20,
            "num_layers": 1,
            "num_heads": 4,
            "relative_attention_num_buckets": 4,
        },
    )


def foreign_clip_tokenizer():
    """A CLIP byte-level BPE with other merges and a 24-token context."""
    from tests.priors.tiny_pipelines import _bytes_to_unicode
    from transformers import CLIPTokenizer

    chars = list(_bytes_to_unicode().values())
    vocab: dict[str, int] = {}
    for c in chars + [c + "</w>" for c in chars]:
        vocab.setdefault(c, len(vocab))
    merges = [("e", "r"), ("i", "n"), ("in", "g</w>"), ("s", "t"), ("r", "e"), ("a", "n")]
    for m in merges:
        vocab.setdefault("".join(m), len(vocab))
    for special in ("<|startoftext|>", "<|endoftext|>"):
        vocab.setdefault(special, len(vocab))
    tok = CLIPTokenizer(vocab=vocab, merges=merges)
    tok.model_max_length = 24
    return tok


def write_foreign_modelscope(directory: Path, seed: int = 5) -> Path:
    """ModelScope with a 3-level VAE (4x), 6 latent channels, CLIP width 12 and 24
    positions, other DDIM options (linear betas, steps_offset 1)."""
    from tests.priors.tiny_pipelines import write_modelscope_pipeline

    return write_modelscope_pipeline(
        directory,
        foreign_clip_tokenizer(),
        seed=seed,
        reseed=False,
        unet={
            "block_out_channels": (8, 16),
            "sample_size": 4,
            "in_channels": 6,
            "out_channels": 6,
            "cross_attention_dim": 12,
            "norm_num_groups": 4,
        },
        scheduler={
            "beta_start": 0.0001,
            "beta_end": 0.02,
            "beta_schedule": "linear",
            "clip_sample": False,
            "set_alpha_to_one": True,
            "steps_offset": 1,
        },
        vae={
            "blocks": 3,
            "block_out_channels": (4, 8, 8),
            "latent_channels": 6,
            "sample_size": 16,
            "norm_num_groups": 2,
            "scaling_factor": 0.5,
        },
        text={
            "hidden_size": 12,
            "intermediate_size": 24,
            "num_attention_heads": 3,
            "num_hidden_layers": 1,
            "max_position_embeddings": 24,
            "projection_dim": 12,
        },
    )


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("priors")
    return {
        "cogvideox": tiny_dir("cogvideox"),
        "modelscope": tiny_dir("modelscope"),
        "cogvideox-foreign": write_foreign_cogvideox(root / "cog-foreign"),
        "modelscope-foreign": write_foreign_modelscope(root / "ms-foreign"),
        # diffusers' own dummy ModelScope components (VAE of scale 1, 32 px native)
        "modelscope-dummy": write_diffusers_dummy_modelscope(root / "ms-dummy"),
        # the 5b layout: rotary positional embeddings instead of the sin-cos table
        "cogvideox-rope": tiny_dir("cogvideox-rope"),
    }


def write_config(path: Path, **optimize) -> Path:
    data = tiny_config_data()
    data["sim"]["frames"] = FRAMES
    data["optimize"] = {"boost": 1, "lr": 0.2, "warmup": 0, **optimize}
    path.write_text(yaml.safe_dump(data))
    return path


def run_cli(*args) -> int:
    return main(["--quiet", "run", *map(str, args)])


def records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


def check_run_directory(out: Path, iters: int = 2) -> dict:
    """The complete run directory of a refinement; returns params.json."""
    from motionphysics.io.video import read_video

    p = json.loads((out / "params.json").read_text())
    assert p["status"] == "complete" and not p["partial"]
    recs = records(out)
    assert [r["iteration"] for r in recs] == list(range(iters))
    for r in recs:
        assert math.isfinite(r["loss"])
        g = r["grad_norm"]["total"]
        assert math.isfinite(g) and g > 0, r["grad_norm"]
    assert len(p["history"]) == iters
    side = p["optimise"]["parameters"]
    assert side["E"]["optimised"] and side["E"]["initial"] != side["E"]["final"]
    assert p["params"]["E"] == pytest.approx(side["E"]["final"])
    assert p["initial"]["params"]["E"] == pytest.approx(side["E"]["initial"])
    for f in ("plots/loss.png", "plots/params.png", "video.mp4", "trajectory.npz", "run.yaml"):
        assert (out / f).is_file(), f
        assert f in p["files"] or f.startswith("plots/"), f
    # the final simulation at the full frame rate, from the refined parameters
    traj = np.load(out / "trajectory.npz")
    assert traj["x"].shape[0] == FRAMES
    assert read_video(out / "video.mp4").shape[0] == FRAMES
    return p


# ----------------------------------------------------------------------------- the CLI
# Two foreign pipelines in the default suite; the other two (and the loss x prior matrix
# beyond lmd) run with `make test-slow`: each case is a whole run (~15-50 s on 2 cores).
@pytest.mark.parametrize(
    "kind",
    [
        "cogvideox-foreign",
        "modelscope-foreign",
        pytest.param("modelscope-dummy", marks=pytest.mark.slow),
        pytest.param("cogvideox-rope", marks=pytest.mark.slow),
    ],
)
def test_run_on_pipelines_written_by_someone_else(dirs, tmp_path, kind):
    name = kind.split("-")[0]
    cfg = write_config(tmp_path / "c.yaml")
    out = tmp_path / "run"
    rc = run_cli(cfg, "--prior", name, "--prior-path", dirs[kind], "--loss", "lmd", "--iters", 2,
                 "--out", out)  # fmt: skip
    assert rc == 0
    p = check_run_directory(out)
    assert p["optimise"]["prior"] == name and p["optimise"]["loss"] == "lmd"


@pytest.mark.parametrize("prior", PRIORS)
@pytest.mark.parametrize(
    "loss",
    [pytest.param(name, marks=[] if name == "lmd" else [pytest.mark.slow]) for name in LOSSES],
)
def test_every_loss_and_prior_refines_end_to_end(dirs, tmp_path, prior, loss):
    cfg = write_config(tmp_path / "c.yaml", params=["E"])
    out = tmp_path / "run"
    rc = run_cli(cfg, "--prior", prior, "--prior-path", dirs[prior], "--loss", loss,
                 "--iters", 2, "--out", out)  # fmt: skip
    assert rc == 0
    p = check_run_directory(out)
    assert p["optimise"]["optimised"] == ["E"]
    assert (out / "prior_reference.mp4").is_file() == (loss in ("flow", "video"))
    if loss in ("flow", "video"):
        assert "prior_reference.mp4" in p["files"]
    recs = records(out)
    # the guidance each loss used is the loss's own default (no --guidance given)
    assert recs[0]["guidance"] == {"lmd": 100.0, "sds": 100.0, "flow": 6.0, "video": 6.0}[loss]


def test_guidance_flag_reaches_the_loss(dirs, tmp_path):
    cfg = write_config(tmp_path / "c.yaml", params=["E"], grad_mode="last_substep")
    out = tmp_path / "run"
    rc = run_cli(cfg, "--prior", "cogvideox", "--prior-path", dirs["cogvideox"],
                 "--iters", 2, "--guidance", 3.5, "--out", out)  # fmt: skip
    assert rc == 0
    p = check_run_directory(out)
    assert p["optimise"]["grad_mode"] == "last_substep"
    assert p["optimise"]["guidance_per_loss"] == {"lmd": 3.5}
    assert all(r["guidance"] == 3.5 and r["loss_guidance"] == 3.5 for r in records(out))


# ------------------------------------------------------------------------- user errors
def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    err = [line for line in err if line.startswith("motionphysics:")]
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def test_missing_directory_component_and_wrong_class_are_status_2(dirs, tmp_path, capsys):
    import shutil

    cfg = write_config(tmp_path / "c.yaml")
    out = tmp_path / "run"
    assert run_cli(cfg, "--prior", "cogvideox", "--prior-path", tmp_path / "nowhere",
                   "--out", out) == 2  # fmt: skip
    assert "no such directory" in _one_line_error(capsys)
    no_vae = tmp_path / "no-vae"
    shutil.copytree(dirs["modelscope"], no_vae)
    shutil.rmtree(no_vae / "vae")
    assert run_cli(cfg, "--prior", "modelscope", "--prior-path", no_vae, "--out", out) == 2
    line = _one_line_error(capsys)
    assert "vae" in line and "huggingface-cli download" in line
    assert run_cli(cfg, "--prior", "cogvideox", "--prior-path", dirs["modelscope"],
                   "--out", out) == 2  # fmt: skip
    line = _one_line_error(capsys)
    assert "CLIPTextModel" in line and "T5EncoderModel" in line
    assert not out.exists()  # checked before the run directory is written
    assert run_cli(cfg, "--guidance", 5, "--out", out) == 2
    assert "--guidance" in _one_line_error(capsys)


def test_subprocess_error_has_no_traceback(tmp_path):
    import os
    import subprocess
    import sys

    cfg = write_config(tmp_path / "c.yaml")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "motionphysics",
            "run",
            str(cfg),
            "--prior",
            "modelscope",
            "--prior-path",
            str(tmp_path / "missing"),
            "--out",
            str(tmp_path / "r"),
        ],  # fmt: skip
        capture_output=True,
        text=True,
        env={**os.environ},
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert len([x for x in proc.stderr.splitlines() if x.strip()]) == 1


def test_bench_targets_are_registered(capsys):
    # without --random-weights nothing may be downloaded: a user error before any work
    assert main(["bench", "prior", "--model", "cogvideox-2b"]) == 2
    assert "--random-weights" in _one_line_error(capsys)
    with pytest.raises(SystemExit) as exc:
        main(["bench", "iteration", "--help"])
    assert exc.value.code == 0
    assert "LMD iteration" in capsys.readouterr().out
