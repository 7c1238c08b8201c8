"""Training and measuring the embedded motion prior (``motionphysics prior train``).

Data: the clips of :mod:`.motion_data`; each clip's features (:mod:`.motion_features`)
are computed once from its stored states in several *views*: every frame, and the
every-second / every-third frame subsequences a boosted run shows the prior (resampled
onto the same 16-frame grid), cached in ``DATA/features-<version>.npz``. Captions come
from the clip's measured motion (:mod:`.captions`, ``CAPTIONS_PER_CLIP`` training
phrasings per clip, one drawn per step), encoded once as pooled MiniLM vectors.

Training: x0-prediction MSE on the standardised features (1000-step cosine schedule,
uniform t), classifier-free-guidance dropout (the caption replaced by ``""`` with
probability ``cond_dropout``), group-balanced clip order, AdamW with warm-up, an EMA of
the weights, and a caption contrast (``contrast``: for up to ``contrast_clips`` clips of a
batch with a motion group, a cross-entropy over the groups whose logits are the negative
log x0 errors under one training prompt of each group at the same noise and timestep:
the clip's own group's prompt must denoise it best): what caption discrimination and the
pairwise contrast of the losses use.

Resumable and deterministic per seed: the checkpoint holds the weights, EMA, optimiser,
the torch generator that draws every random number of the loop, the data position and
the log, written atomically every ``save_every`` steps, at the step or time budget and
on Ctrl-C; a resumed run continues exactly as an uninterrupted one (tested).

Measures: :func:`discrimination` (held-out shapes and phrasings: the group whose prompts
give the lowest x0 error) and :func:`feature_classifier` (a text-free classifier on the
features: do they separate the groups at all).
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.language.captions import (
    GROUPS,
    caption_clip,
    group_prompt,
    object_noun,
    training_phrasings,
)
from motionphysics.language.text import TEXT_DIM, sentence_embeddings
from motionphysics.priors.motion import (
    MotionDenoiser,
    MotionPrior,
    cosine_alphas_cumprod,
    net_config,
    normalise,
)
from motionphysics.priors.motion_features import FEATURE_NAMES, MotionScene, clip_features
from motionphysics.priors.motion_text import MotionText

__all__ = [
    "VIEWS",
    "MotionTrainOptions",
    "discrimination",
    "export_weights",
    "feature_classifier",
    "prepare",
    "train",
]

CAPTIONS_PER_CLIP = 6
NUM_FRAMES = 16
FEATURES_VERSION = "3"
VIEWS: tuple[tuple[int, int], ...] = ((1, 1), (2, 1), (2, 2), (3, 1), (3, 3))
"""(stride, first frame) of the observed subsequences a clip is seen through: every
frame; every second frame from frame 1 or 2; every third frame from frame 1 or 3."""


@dataclass
class MotionTrainOptions:
    budget_min: float = 30.0
    max_steps: int | None = None
    batch: int = 64
    lr: float = 1e-3
    warmup: int = 100
    ema_decay: float = 0.999
    cond_dropout: float = 0.1
    contrast: float = 0.5
    """Weight of the caption contrast (0: plain denoising): a cross-entropy over the motion
    groups whose logits are -log(x0 error) / ``contrast_temperature`` of the clip under one
    training prompt of every group (same noise and t), so that the clip's own group's
    prompt denoises it best (what the discrimination measures)."""
    contrast_temperature: float = 0.05
    """A 5 % lower x0 error is one unit of logit."""
    contrast_clips: int = 16
    """Grouped clips of a batch the contrast is computed on (each costs 8 forwards)."""
    sentence_dropout: float = 0.5
    """Probability that a caption's sentence vector is replaced by the unconditional one
    while its motion reading is kept (:mod:`.motion_text`), so that the reading alone
    carries the motion: what a phrasing the network has not seen relies on."""
    subject_swap: float = 0.5
    """Probability that a caption's sentence vector is replaced by that of another caption
    (any clip's, drawn uniformly) while its motion reading is kept: the words that name
    the thing ("thick honey") then cannot decide the motion, the reading must, as it must
    when a prompt contrasts two motions of one subject (``negative_prompt: auto``)."""
    seed: int = 0
    save_every: int = 200
    log_every: int = 100
    device: str = "cpu"
    size: str = "cpu"
    threads: int | None = None


# ---- data ----------------------------------------------------------------------------


def clip_views(x, F, t, ground, gravity) -> np.ndarray:
    """[len(VIEWS), NUM_FRAMES, C] float32 features of one clip's stored states."""
    x = torch.as_tensor(np.asarray(x), dtype=torch.float32)
    F = torch.as_tensor(np.asarray(F), dtype=torch.float32)
    t = torch.as_tensor(np.asarray(t), dtype=torch.float64)
    scene = MotionScene(rest=x[0], ground=float(ground), gravity=tuple(float(v) for v in gravity))
    out = []
    with torch.no_grad():
        for stride, first in VIEWS:
            idx = list(range(first, x.shape[0], stride))
            out.append(clip_features(x[idx], F[idx], t[idx], scene, NUM_FRAMES).numpy())
    return np.stack(out).astype(np.float32)


def _features(root: Path, data: dict[str, Any]) -> np.ndarray:
    """[N, V, T, C] features of every clip (cached per feature version and clip count)."""
    n = len(data["groups"])
    cache = root / f"features-{FEATURES_VERSION}.npz"
    if cache.exists():
        with np.load(cache) as z:
            if int(z["n"]) == n and list(z["names"]) == list(FEATURE_NAMES):
                return np.asarray(z["features"])
            done = np.asarray(z["features"]) if list(z["names"]) == list(FEATURE_NAMES) else None
    else:
        done = None
    k0 = 0 if done is None else min(done.shape[0], n)
    rows = [done[:k0]] if k0 else []
    for i in range(k0, n):
        rows.append(
            clip_views(
                data["x"][i], data["F"][i], data["t"][i], data["ground"][i], data["gravity"][i]
            )[None]
        )
    feats = (
        np.concatenate(rows) if rows else np.zeros((0, len(VIEWS), NUM_FRAMES, len(FEATURE_NAMES)))
    )
    tmp = cache.with_name(cache.stem + ".tmp.npz")
    np.savez(tmp, features=feats, n=np.array(n), names=np.array(FEATURE_NAMES))
    os.replace(tmp, cache)
    return feats


def prepare(root: str | Path, *, seed: int = 0, held_out: bool = False) -> dict[str, Any]:
    """Load the clips under ``root``, their features and captions.

    Returns ``{"features" float32 [N, V, T, C], "caption_idx" int [N, K], "texts",
    "text_emb" float32 [U, 384], "groups" [str|None], "specs", "measures"}``."""
    from motionphysics.priors.motion_data import load_clips

    root = Path(root)
    data = load_clips(root)
    feats = _features(root, data)
    texts: list[str] = []
    index: dict[str, int] = {}
    cap = np.zeros((len(data["specs"]), CAPTIONS_PER_CLIP), dtype=np.int64)
    for i, (m, s) in enumerate(zip(data["measures"], data["specs"], strict=True)):
        rng = np.random.default_rng([seed, 17, int(s.get("index", i))])
        for k in range(CAPTIONS_PER_CLIP):
            text, _ = caption_clip(m, s["cls"], s["shape"], rng, held_out=held_out)
            if text not in index:
                index[text] = len(texts)
                texts.append(text)
            cap[i, k] = index[text]
    return {
        "features": feats,
        "caption_idx": cap,
        "texts": texts,
        "text_emb": _embed(root, texts),
        "groups": data["groups"],
        "specs": data["specs"],
        "measures": data["measures"],
    }


def _embed(root: Path, texts: list[str]) -> np.ndarray:
    """Pooled MiniLM vectors of ``texts`` (cached in ``root/text-emb.npz``)."""
    cache = root / "text-emb.npz"
    known: dict[str, np.ndarray] = {}
    if cache.exists():
        with np.load(cache) as z:
            known = dict(zip([str(t) for t in z["texts"]], z["emb"], strict=True))
    new = [t for t in texts if t not in known]
    if new:
        for t, e in zip(new, sentence_embeddings(new).numpy(), strict=True):
            known[t] = e
        tmp = cache.with_name("text-emb.tmp.npz")
        np.savez(tmp, texts=np.array(list(known)), emb=np.stack(list(known.values())))
        os.replace(tmp, cache)
    if not texts:
        return np.zeros((0, 384), np.float32)
    return np.stack([known[t] for t in texts]).astype(np.float32)


def epoch_order(groups: list[str | None], seed: int, epoch: int) -> np.ndarray:
    """A seeded draw (with replacement) of one epoch's clips, each clip weighted by
    1 / (size of its motion group; no group counts as one more group)."""
    n = len(groups)
    rng = np.random.default_rng([seed, epoch, n])
    keys = [g if g is not None else "" for g in groups]
    sizes: dict[str, int] = {}
    for k in keys:
        sizes[k] = sizes.get(k, 0) + 1
    w = np.array([1.0 / sizes[k] for k in keys])
    return rng.choice(n, size=n, replace=True, p=w / w.sum())


class _GroupPrompts:
    """Pooled MiniLM vectors of every group's training phrasings (``training_phrasings``)
    with every shape's noun, as ``group_prompt`` writes them (the contrast term's prompts)."""

    def __init__(self, shapes, reader: MotionText) -> None:
        self.shapes = sorted(set(shapes))
        texts: list[str] = []
        self.rows: dict[tuple[int, int], list[int]] = {}
        for gi, g in enumerate(GROUPS):
            phrasings = training_phrasings(g)
            for si, sh in enumerate(self.shapes):
                self.rows[(gi, si)] = []
                for k in range(len(phrasings)):
                    self.rows[(gi, si)].append(len(texts))
                    obj = object_noun(sh, k)
                    texts.append(f"{'an' if obj[0] in 'aeiou' else 'a'} {obj} {phrasings[k]}")
        self.emb = reader.encode(texts, leave_out=True)

    def draw_all(self, shape: str, gen: torch.Generator) -> Tensor:
        """[len(GROUPS), D]: one random training prompt of every group for ``shape``."""
        si = self.shapes.index(shape)
        out = []
        for gi in range(len(GROUPS)):
            rows = self.rows[(gi, si)]
            out.append(self.emb[rows[int(torch.randint(0, len(rows), (1,), generator=gen))]])
        return torch.stack(out)


# ---- checkpoint ----------------------------------------------------------------------


def _atomic_save(obj: Any, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def export_weights(checkpoint: str | Path, dst: str | Path, meta: dict | None = None) -> Path:
    """Write the shippable file (kind, config, EMA weights, feature statistics, meta)."""
    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    out = {
        "kind": "motion",
        "config": ck["config"],
        "ema": {k: v.float() for k, v in ck["ema"].items()},
        "mean": ck["mean"],
        "std": ck["std"],
        "meta": {**ck.get("meta", {}), **(meta or {})},
    }
    dst = Path(dst)
    _atomic_save(out, dst)
    return dst


def prior_from_checkpoint(path: str | Path, device: str = "cpu") -> MotionPrior:
    """A :class:`MotionPrior` from a training checkpoint (its EMA weights)."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    net = MotionDenoiser(**ck["config"]["net"])
    net.load_state_dict(ck["ema"])
    return MotionPrior(
        net,
        mean=ck["mean"],
        std=ck["std"],
        num_frames=ck["config"]["num_frames"],
        device=device,
        meta=ck.get("meta"),
        feature_names=ck["config"].get("features"),
        text=ck["config"].get("text"),
    )


# ---- training ------------------------------------------------------------------------


def _lr(step: int, o: MotionTrainOptions) -> float:
    return o.lr * min(1.0, (step + 1) / max(1, o.warmup))


def train(
    data: str | Path,
    out: str | Path,
    options: MotionTrainOptions,
    *,
    resume: bool = False,
    log=print,
) -> dict[str, Any]:
    """Train (or resume) the motion prior on the clips under ``data``; checkpoint at ``out``.

    Stops after ``options.budget_min`` minutes of this invocation or at ``max_steps``
    total steps. Returns the final log record."""
    o = options
    if o.threads:
        torch.set_num_threads(int(o.threads))
    out = Path(out)
    device = torch.device(o.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserInputError("--device cuda: CUDA is not available in this torch build")
    ds = prepare(data, seed=o.seed)
    feats = ds["features"]
    n = feats.shape[0]
    if n == 0:
        raise UserInputError(f"{data}: the shards hold no clips")
    _, V, T, C = feats.shape
    flat = torch.from_numpy(feats.reshape(-1, C)).double()
    mean, std = flat.mean(0).float(), flat.std(0).clamp_min(1e-3).float()
    z_all = normalise(torch.from_numpy(feats), mean, std)  # [N, V, T, C]
    reader = MotionText.default()
    text_emb = reader.encode(ds["texts"], leave_out=True)
    uncond = reader.encode([""])[0]
    cfg = {
        "net": net_config(o.size),
        "num_frames": int(T),
        "features": list(FEATURE_NAMES),
        "text": reader.config(),
    }
    if cfg["net"]["frames"] != T or cfg["net"]["features"] != C:
        raise UserInputError(
            f"{data}: clips of {T} frames x {C} features; the network expects "
            f"{cfg['net']['frames']} x {cfg['net']['features']}"
        )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(o.seed)  # the initial weights depend on the seed only
        net = MotionDenoiser(**cfg["net"]).to(device)
    ema = MotionDenoiser(**cfg["net"]).to(device)
    ema.load_state_dict(net.state_dict())
    ema.requires_grad_(False)
    opt = torch.optim.AdamW(net.parameters(), lr=o.lr, weight_decay=0.01)
    gen = torch.Generator().manual_seed(o.seed)
    state: dict[str, Any] = {"step": 0, "epoch": 0, "offset": 0, "elapsed_s": 0.0, "log": []}
    if resume and out.exists():
        ck = torch.load(out, map_location="cpu", weights_only=False)
        if ck["config"] != cfg:
            raise UserInputError(f"{out}: checkpoint was trained with another network; use --out")
        net.load_state_dict(ck["model"])
        ema.load_state_dict(ck["ema"])
        opt.load_state_dict(ck["opt"])
        gen.set_state(ck["rng"])
        state = ck["state"]
        mean, std = ck["mean"], ck["std"]
        z_all = normalise(torch.from_numpy(feats), mean, std)
        log(f"resumed from {out} at step {state['step']}")
    elif out.exists():
        raise UserInputError(f"{out}: exists; pass --resume to continue it or another --out")
    ac = cosine_alphas_cumprod().to(device)
    n_params = sum(p.numel() for p in net.parameters())
    contrast = _GroupPrompts([s["shape"] for s in ds["specs"]], reader) if o.contrast > 0 else None
    gidx = [GROUPS.index(g) if g is not None else -1 for g in ds["groups"]]
    order = epoch_order(ds["groups"], o.seed, state["epoch"])

    def save() -> None:
        meta = {
            "clips": int(n),
            "data": str(data),
            "steps": int(state["step"]),
            "train_time_s": float(state["elapsed_s"]),
            "parameters": int(n_params),
            "options": asdict(o),
        }
        _atomic_save(
            {
                "kind": "motion",
                "config": cfg,
                "model": net.state_dict(),
                "ema": ema.state_dict(),
                "opt": opt.state_dict(),
                "rng": gen.get_state(),
                "state": state,
                "mean": mean,
                "std": std,
                "meta": meta,
            },
            out,
        )

    interrupted = {"flag": False}

    def on_sigint(*_):
        interrupted["flag"] = True

    main = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGINT, on_sigint) if main else None
    t_start = time.perf_counter()
    base_elapsed = state["elapsed_s"]
    run_loss: list[float] = []
    run_hinge: list[float] = []
    log(f"training {n_params} parameters on {n} clips ({V} views x {T} x {C}), device {device}")
    try:
        while True:
            if o.max_steps is not None and state["step"] >= o.max_steps:
                break
            if time.perf_counter() - t_start > 60.0 * o.budget_min or interrupted["flag"]:
                break
            if state["offset"] + o.batch > n:
                state["epoch"] += 1
                state["offset"] = 0
                order = epoch_order(ds["groups"], o.seed, state["epoch"])
            idx = order[state["offset"] : state["offset"] + o.batch]
            state["offset"] += o.batch
            b = len(idx)
            view = torch.randint(0, V, (b,), generator=gen)
            z0 = z_all[torch.from_numpy(idx), view]  # [B, T, C]
            pick = torch.randint(0, CAPTIONS_PER_CLIP, (b,), generator=gen).numpy()
            txt = text_emb[torch.from_numpy(ds["caption_idx"][idx, pick])]
            drop = torch.rand(b, generator=gen) < o.cond_dropout
            txt = torch.where(drop[:, None], uncond[None], txt)
            if o.subject_swap > 0:
                swap = (torch.rand(b, generator=gen) < o.subject_swap) & ~drop
                other = text_emb[torch.randint(0, len(text_emb), (b,), generator=gen)]
                txt[:, :TEXT_DIM] = torch.where(
                    swap[:, None], other[:, :TEXT_DIM], txt[:, :TEXT_DIM]
                )
            if o.sentence_dropout > 0:
                plain = torch.rand(b, generator=gen) < o.sentence_dropout
                txt[:, :TEXT_DIM] = torch.where(
                    plain[:, None], uncond[None, :TEXT_DIM], txt[:, :TEXT_DIM]
                )
            t = torch.randint(0, 1000, (b,), generator=gen)
            noise = torch.randn(z0.shape, generator=gen)
            z0, txt, t, noise = z0.to(device), txt.to(device), t.to(device), noise.to(device)
            a = ac[t].view(-1, 1, 1)
            zt = a.sqrt() * z0 + (1 - a).sqrt() * noise
            for gp in opt.param_groups:
                gp["lr"] = _lr(state["step"], o)
            loss = ((net(zt, t, txt) - z0) ** 2).mean()
            total = loss
            hinge = None
            if contrast is not None:
                rows = [r for r in range(b) if gidx[idx[r]] >= 0][: o.contrast_clips]
                if rows:
                    n_g = len(GROUPS)
                    prompts = torch.cat(
                        [contrast.draw_all(ds["specs"][idx[r]]["shape"], gen) for r in rows]
                    ).to(device)
                    sel = torch.tensor(rows).repeat_interleave(n_g).to(device)
                    err = ((net(zt[sel], t[sel], prompts) - z0[sel]) ** 2).mean(dim=(1, 2))
                    logits = -torch.log(err.reshape(len(rows), n_g) + 1e-8)
                    target = torch.tensor([gidx[idx[r]] for r in rows], device=device)
                    hinge = torch.nn.functional.cross_entropy(
                        logits / o.contrast_temperature, target
                    )
                    total = loss + o.contrast * hinge
            opt.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            d = min(o.ema_decay, (1 + state["step"]) / (10 + state["step"]))
            with torch.no_grad():
                for pe, pn in zip(ema.parameters(), net.parameters(), strict=True):
                    pe.mul_(d).add_(pn.detach(), alpha=1 - d)
            state["step"] += 1
            state["elapsed_s"] = base_elapsed + time.perf_counter() - t_start
            run_loss.append(float(loss.detach()))
            if hinge is not None:
                run_hinge.append(float(hinge.detach()))
            if state["step"] % o.log_every == 0:
                rec = {
                    "step": state["step"],
                    "loss": float(np.mean(run_loss[-o.log_every :])),
                    "time_s": round(state["elapsed_s"], 3),
                    "epoch": state["epoch"],
                }
                if run_hinge:
                    rec["contrast"] = float(np.mean(run_hinge[-o.log_every :]))
                state["log"].append(rec)
                log(json.dumps(rec))
            if state["step"] % o.save_every == 0:
                save()
        rec = {"step": state["step"], "time_s": round(state["elapsed_s"], 3)}
        state["log"].append(rec)
        save()
        log(json.dumps({"final": rec, "checkpoint": str(out)}))
        return rec
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)


# ---- measuring -----------------------------------------------------------------------


def discrimination(
    prior: MotionPrior,
    ds: dict[str, Any],
    *,
    timesteps: tuple[int, ...] = (200, 400, 600),
    noise_draws: int = 4,
    held_out: bool = True,
    view: int = 0,
    seed: int = 0,
    prompts_per_group: int = 2,
    max_clips: int | None = None,
) -> dict[str, Any]:
    """Caption discrimination over the motion groups.

    For every clip of ``ds`` (:func:`prepare`) with a motion group, each group's prompts
    (the ``held_out`` phrasings with the clip's object noun, no material noun) are scored
    by the x0 error of the denoised features under the same noise and timesteps, averaged
    over the group's prompts; the predicted group has the lowest. Returns accuracy, the
    confusion matrix (rows = true group) and per-group counts."""
    g = torch.Generator().manual_seed(seed)
    rows = [(i, grp) for i, grp in enumerate(ds["groups"]) if grp is not None]
    if max_clips is not None:
        rows = rows[:max_clips]
    n_g = len(GROUPS)
    conf = np.zeros((n_g, n_g), dtype=np.int64)
    ts = torch.tensor(timesteps).repeat_interleave(noise_draws)
    cache: dict[str, Tensor] = {}
    for i, grp in rows:
        shape = ds["specs"][i]["shape"]
        if shape not in cache:
            prompts = [
                group_prompt(gn, shape, k, held_out=held_out)
                for gn in GROUPS
                for k in range(prompts_per_group)
            ]
            cache[shape] = prior.embed_texts(prompts)
        f = torch.from_numpy(ds["features"][i, view])
        if f.shape[-1] != len(prior.feature_names):
            f = f[:, [FEATURE_NAMES.index(n) for n in prior.feature_names]]
        z0 = normalise(f, prior.mean, prior.std)
        z0 = z0[None, :, :, None, None].to(prior.device)
        noise = torch.randn((len(ts), *z0.shape[1:]), generator=g).to(prior.device)
        losses = prior.denoising_loss(z0, cache[shape].to(prior.device), ts.to(prior.device), noise)
        per = losses.reshape(n_g, prompts_per_group).mean(1)
        conf[GROUPS.index(grp), int(per.argmin())] += 1
    total = int(conf.sum())
    return {
        "clips": total,
        "accuracy": float(np.trace(conf) / total) if total else float("nan"),
        "chance": 1.0 / n_g,
        "groups": list(GROUPS),
        "per_group": {GROUPS[k]: int(conf[k].sum()) for k in range(n_g)},
        "correct": {GROUPS[k]: int(conf[k, k]) for k in range(n_g)},
        "confusion": conf.tolist(),
    }


def feature_classifier(
    train_ds: dict[str, Any],
    test_ds: dict[str, Any],
    *,
    seed: int = 0,
    steps: int = 1500,
    hidden: int = 128,
) -> dict[str, Any]:
    """A text-free classifier of the motion group from the features (an MLP on the
    standardised full-view features of the training clips), scored on ``test_ds``:
    whether the features separate the groups at all."""

    def xy(ds):
        keep = [i for i, g in enumerate(ds["groups"]) if g is not None]
        x = torch.from_numpy(ds["features"][keep, 0]).reshape(len(keep), -1)
        y = torch.tensor([GROUPS.index(ds["groups"][i]) for i in keep])
        return x, y

    xtr, ytr = xy(train_ds)
    xte, yte = xy(test_ds)
    mu, sd = xtr.mean(0), xtr.std(0).clamp_min(1e-3)
    xtr, xte = (xtr - mu) / sd, (xte - mu) / sd
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = torch.nn.Sequential(
            torch.nn.Linear(xtr.shape[1], hidden),
            torch.nn.GELU(),
            torch.nn.Linear(hidden, len(GROUPS)),
        )
        opt = torch.optim.AdamW(model.parameters(), lr=3e-3, weight_decay=1e-2)
        counts = torch.bincount(ytr, minlength=len(GROUPS)).float().clamp_min(1)
        w = (1.0 / counts) / (1.0 / counts).mean()
        for _ in range(steps):
            opt.zero_grad()
            torch.nn.functional.cross_entropy(model(xtr), ytr, weight=w).backward()
            opt.step()
    with torch.no_grad():
        pred = model(xte).argmax(1)
    conf = np.zeros((len(GROUPS), len(GROUPS)), dtype=np.int64)
    for a, b in zip(yte.tolist(), pred.tolist(), strict=True):
        conf[a, b] += 1
    return {
        "train_clips": int(len(ytr)),
        "clips": int(len(yte)),
        "accuracy": float((pred == yte).float().mean()) if len(yte) else float("nan"),
        "confusion": conf.tolist(),
    }


def write_snapshot(ds: dict[str, Any], path: str | Path, per_group: int = 8) -> Path:
    """A small fixed sample of ``ds``'s clips (up to ``per_group`` of each motion group, in
    data order; full view only) for a quick check of shipped weights: ``features``
    [N, 1, T, C], ``groups``, ``shapes``."""
    picked: dict[str, list[int]] = {}
    for i, g in enumerate(ds["groups"]):
        if g is not None and len(picked.setdefault(g, [])) < per_group:
            picked[g].append(i)
    idx = sorted(i for rows in picked.values() for i in rows)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path,
        features=ds["features"][idx, :1].astype(np.float32),
        groups=np.array([ds["groups"][i] for i in idx]),
        shapes=np.array([ds["specs"][i]["shape"] for i in idx]),
    )
    return path


def read_snapshot(path: str | Path) -> dict[str, Any]:
    """What :func:`write_snapshot` wrote, in the layout :func:`discrimination` reads."""
    with np.load(path) as z:
        return {
            "features": np.asarray(z["features"]),
            "groups": [str(g) for g in z["groups"]],
            "specs": [{"shape": str(s)} for s in z["shapes"]],
        }
