"""The tiny prior's trainer: an interrupted run resumes to the same weights."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from motionphysics.errors import UserInputError
from motionphysics.priors.tiny_train import TrainOptions, epoch_order, train


def _fake_shard(root, n=6, T=16, S=32, seed=0):
    """A shard in the generator's on-disk layout (random pixels, simple falling blobs)."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    frames = rng.integers(0, 256, (n, T, S, S, 3), dtype=np.uint8)
    t = np.arange(T) * 0.05
    body = rng.uniform(-0.1, 0.1, (64, 3))
    xs = []
    for i in range(n):
        z = np.maximum(0.0, 0.3 - 4.9 * t**2) * (1 + 0.1 * i)
        xs.append(body[None] + np.stack([np.zeros(T), np.zeros(T), z], -1)[:, None])
    x = np.stack(xs).astype(np.float16)
    v = np.gradient(x.astype(np.float64), 0.05, axis=1).astype(np.float16)
    specs = [{"index": i, "cls": "elastic", "shape": "sphere"} for i in range(n)]
    np.savez(
        root / "shard-00000.npz",
        frames=frames,
        traj_x=x,
        traj_v=v,
        t=t,
        measures=np.array("[]"),
        specs=np.array(json.dumps(specs)),
        failed=np.array("[]"),
    )
    return root


def _opts(steps, contrast=0.0):
    return TrainOptions(
        contrast=contrast,
        contrast_share=1.0,
        max_steps=steps,
        budget_min=10.0,
        batch=2,
        warmup=2,
        save_every=2,
        eval_every=0,
        threads=1,
        seed=5,
        size="test",
    )


@pytest.mark.parametrize("contrast", [0.0, 1.0], ids=["denoising", "caption-contrast"])
def test_interrupted_training_resumes_to_the_same_weights(tmp_path, contrast):
    """Also with the caption-contrast term (its prompt draws come from the loop's
    generator, so they resume too; the fake clips all fall in a motion group)."""
    data = _fake_shard(tmp_path / "data")
    full = tmp_path / "full.pt"
    part = tmp_path / "part.pt"
    quiet = lambda *_: None  # noqa: E731
    train(data, full, _opts(5, contrast), log=quiet)  # 5 steps: crosses an epoch (6 clips / 2)
    train(data, part, _opts(2, contrast), log=quiet)
    rec = train(data, part, _opts(5, contrast), resume=True, log=quiet)
    assert rec["step"] == 5
    a = torch.load(full, weights_only=False)
    b = torch.load(part, weights_only=False)
    assert a["state"]["step"] == b["state"]["step"] == 5
    assert a["state"]["epoch"] == b["state"]["epoch"] >= 1
    for key in ("model", "ema"):
        for name, ta in a[key].items():
            assert torch.equal(ta, b[key][name]), f"{key}.{name} differs after resume"
    # the weights moved (the comparison is not between two untouched initialisations)
    c = torch.load(tmp_path / "part.pt", weights_only=False)
    fresh = train(data, tmp_path / "one.pt", _opts(1, contrast), log=quiet)
    assert fresh["step"] == 1
    d = torch.load(tmp_path / "one.pt", weights_only=False)
    assert any(not torch.equal(c["model"][k], d["model"][k]) for k in c["model"])


def test_existing_checkpoint_needs_resume(tmp_path):
    data = _fake_shard(tmp_path / "data")
    out = tmp_path / "ck.pt"
    train(data, out, _opts(1), log=lambda *_: None)
    with pytest.raises(UserInputError, match="--resume"):
        train(data, out, _opts(2), log=lambda *_: None)


def test_empty_data_directory_is_a_user_error(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserInputError, match="no shard"):
        train(tmp_path / "empty", tmp_path / "x.pt", _opts(1), log=lambda *_: None)


def test_caption_contrast_changes_the_update():
    """The contrast term is not a no-op: one step with it gives other weights than one
    step without it, from the same seed and data."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        data = _fake_shard(root / "data")
        quiet = lambda *_: None  # noqa: E731
        train(data, root / "a.pt", _opts(1, 0.0), log=quiet)
        train(data, root / "b.pt", _opts(1, 1.0), log=quiet)
        a = torch.load(root / "a.pt", weights_only=False)["model"]
        b = torch.load(root / "b.pt", weights_only=False)["model"]
        assert any(not torch.equal(a[k], b[k]) for k in a)


def test_balanced_epoch_order_evens_out_the_motion_groups():
    groups = ["splashes"] * 90 + ["oozes"] * 8 + [None] * 2
    a = epoch_order(groups, seed=3, epoch=0, balance=True)
    assert np.array_equal(a, epoch_order(groups, seed=3, epoch=0, balance=True))
    assert not np.array_equal(a, epoch_order(groups, seed=3, epoch=1, balance=True))
    picks = np.concatenate([epoch_order(groups, 3, e, True) for e in range(200)])
    share = {
        "splashes": np.mean(picks < 90),
        "oozes": np.mean((picks >= 90) & (picks < 98)),
        "none": np.mean(picks >= 98),
    }
    # each of the three (None counts as a group) is drawn a third of the time: 20,000
    # draws give a binomial standard error of 0.0033, the tolerance is 6 of them
    for k, v in share.items():
        assert v == pytest.approx(1 / 3, abs=0.02), k
    plain = epoch_order(groups, 3, 0, False)
    assert sorted(plain.tolist()) == list(range(100))  # a permutation without balance
