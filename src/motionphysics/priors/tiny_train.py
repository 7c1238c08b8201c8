"""Training and measuring the embedded tiny prior (``motionphysics prior train``).

Training is ε-prediction MSE on clips of :mod:`.tiny_data`, conditioned on MiniLM
token embeddings of captions from :mod:`.captions` (``CAPTIONS_PER_CLIP`` training
phrasings per clip, one drawn per step), with classifier-free-guidance dropout (the
caption replaced by ``""`` with probability ``cond_dropout``), random horizontal flips,
AdamW and an EMA of the weights.

Resumable: the checkpoint holds the weights, EMA, optimiser, the torch generator that
draws every random number of the loop (timesteps, noise, dropout, flips), the data
position (epoch and offset in that epoch's seeded permutation) and the log, written
atomically every ``save_every`` steps, at the time budget and on Ctrl-C. A run resumed
from a checkpoint continues exactly as the uninterrupted run would have (tested).

This module must not import diffusers.
"""

from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from motionphysics.errors import UserInputError
from motionphysics.priors.captions import GROUPS, caption_clip, group_prompt, motion_group
from motionphysics.priors.tiny import (
    MAX_TOKENS,
    TinyPrior,
    TinyVideoUNet,
    model_config,
    scaled_linear_alphas_cumprod,
    text_tokens,
)

__all__ = [
    "TrainOptions",
    "discrimination",
    "export_weights",
    "prepare_dataset",
    "train",
]

CAPTIONS_PER_CLIP = 4


@dataclass
class TrainOptions:
    budget_min: float = 30.0
    max_steps: int | None = None
    batch: int = 8
    lr: float = 1e-3
    warmup: int = 50
    ema_decay: float = 0.995
    """EMA horizon ~200 steps: a CPU budget is ~10^3 steps, a longer one would lag."""
    cond_dropout: float = 0.1
    seed: int = 0
    save_every: int = 100
    eval_every: int = 250
    device: str = "cpu"
    size: str = "cpu"
    threads: int | None = None
    balance: bool = True
    """Draw each epoch's clips with probability inversely proportional to the size of
    their motion group (clips with no group count as one more group), with replacement,
    so that rare motions (oozes, keeps its shape) are seen as often as splashes."""
    contrast: float = 0.0
    """Weight of the caption-contrast term: for ``contrast_share`` of each batch, the
    ε-MSE under a prompt of the clip's own motion group must be lower, by
    ``contrast_margin`` (relative), than under a prompt of another group, at the same
    noise and timestep (a hinge; the prompts are the training phrasings with the clip's
    object noun). It trains what caption discrimination and the pairwise-contrast
    distillation use: the text must change the loss. 0: plain denoising."""
    contrast_share: float = 0.5
    contrast_margin: float = 0.05
    reload_data: bool = False
    """Re-read DATA at each epoch boundary when shards were added (training while the
    generator still runs; a resumed run is then exact only if the shards did not change)."""
    extra: dict[str, Any] = field(default_factory=dict)


# ---- data ----------------------------------------------------------------------------


def prepare_dataset(root: str | Path, *, seed: int = 0, held_out: bool = False) -> dict[str, Any]:
    """Load the shards under ``root`` and caption every clip.

    Returns ``{"frames": uint8 [N,T,H,W,3], "caption_idx": int [N, K], "texts": [str],
    "tokens": float16 [U, L, 384], "groups": [str|None], "specs", "measures"}``. The
    caption token table is cached in ``root/captions-<K>-<seed>.pt`` (MiniLM runs once).
    """
    from motionphysics.priors.tiny_data import load_shards

    frames, measures, specs = load_shards(root)
    texts: list[str] = []
    index: dict[str, int] = {}
    cap_idx = np.zeros((len(specs), CAPTIONS_PER_CLIP), dtype=np.int64)
    groups: list[str | None] = []
    for i, (m, s) in enumerate(zip(measures, specs, strict=True)):
        g = None
        rng = np.random.default_rng([seed, 17, int(s.get("index", i))])  # per clip
        for k in range(CAPTIONS_PER_CLIP):
            text, g = caption_clip(m, s["cls"], s["shape"], rng, held_out=held_out)
            if text not in index:
                index[text] = len(texts)
                texts.append(text)
            cap_idx[i, k] = index[text]
        groups.append(g)
    cache = Path(root) / f"captions-{CAPTIONS_PER_CLIP}-{seed}-{int(held_out)}.pt"
    known: dict[str, torch.Tensor] = {}
    if cache.exists():  # texts encoded before (MiniLM is the slow part of loading)
        c = torch.load(cache, weights_only=True)
        known = dict(zip(c["texts"], c["tokens"], strict=True))
    new = [t for t in texts if t not in known]
    for i in range(0, len(new), 256):
        for t, e in zip(new[i : i + 256], text_tokens(new[i : i + 256]).half(), strict=True):
            known[t] = e
    tokens = torch.stack([known[t] for t in texts]) if texts else torch.zeros(0, MAX_TOKENS, 384)
    if new:
        tmp = cache.with_suffix(".tmp")
        torch.save({"texts": list(known), "tokens": torch.stack(list(known.values()))}, tmp)
        os.replace(tmp, cache)
    return {
        "frames": frames,
        "caption_idx": cap_idx,
        "texts": texts,
        "tokens": tokens,
        "groups": groups,
        "specs": specs,
        "measures": measures,
    }


def epoch_order(groups: list[str | None], seed: int, epoch: int, balance: bool) -> np.ndarray:
    """The clip order of one epoch: a seeded permutation, or with ``balance`` a seeded
    draw with replacement weighted by 1 / (size of the clip's motion group)."""
    n = len(groups)
    rng = np.random.default_rng([seed, epoch, n])
    if not balance:
        return rng.permutation(n)
    keys = [g if g is not None else "" for g in groups]
    sizes: dict[str, int] = {}
    for k in keys:
        sizes[k] = sizes.get(k, 0) + 1
    w = np.array([1.0 / sizes[k] for k in keys])
    return rng.choice(n, size=n, replace=True, p=w / w.sum())


class _ContrastPrompts:
    """Token embeddings of ``group_prompt(group, shape, k, held_out=False)`` for every
    group, training shape and training phrasing (encoded once)."""

    def __init__(self, shapes) -> None:
        from motionphysics.priors.captions import TRAIN

        self.shapes = sorted(set(shapes))
        texts = []
        self.rows: dict[tuple[int, int], list[int]] = {}
        for gi, g in enumerate(GROUPS):
            for si, sh in enumerate(self.shapes):
                rows = []
                for k in range(len(TRAIN[g])):
                    rows.append(len(texts))
                    texts.append(group_prompt(g, sh, k, held_out=False))
                self.rows[(gi, si)] = rows
        self.tokens = torch.cat(
            [text_tokens(texts[i : i + 256]) for i in range(0, len(texts), 256)]
        )

    def draw(self, group: int, shape: str, gen: torch.Generator) -> tuple[Tensor, Tensor]:
        """(own-group prompt, other-group prompt) token embeddings for one clip."""
        si = self.shapes.index(shape)
        other = int(torch.randint(0, len(GROUPS) - 1, (1,), generator=gen))
        other += other >= group
        pos, neg = self.rows[(group, si)], self.rows[(other, si)]
        i = pos[int(torch.randint(0, len(pos), (1,), generator=gen))]
        j = neg[int(torch.randint(0, len(neg), (1,), generator=gen))]
        return self.tokens[i], self.tokens[j]


def _to_latent(frames_u8: np.ndarray) -> torch.Tensor:
    """uint8 [B, T, H, W, 3] -> float32 [B, T, 3, H, W] in [-1, 1] (TinyPrior.encode's map)."""
    x = torch.from_numpy(np.ascontiguousarray(frames_u8)).float() / 127.5 - 1.0
    return x.permute(0, 1, 4, 2, 3).contiguous()


# ---- checkpoint ----------------------------------------------------------------------


def _atomic_save(obj: Any, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def export_weights(checkpoint: str | Path, dst: str | Path, meta: dict | None = None) -> Path:
    """Write the shippable file (config, EMA weights, meta) of a training checkpoint."""
    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    out = {
        "config": ck["config"],
        "ema": {k: v.float() for k, v in ck["ema"].items()},
        "meta": {**ck.get("meta", {}), **(meta or {})},
    }
    dst = Path(dst)
    _atomic_save(out, dst)
    return dst


# ---- training ------------------------------------------------------------------------


def _lr(step: int, o: TrainOptions) -> float:
    return o.lr * min(1.0, (step + 1) / max(1, o.warmup))


def train(
    data: str | Path,
    out: str | Path,
    options: TrainOptions,
    *,
    resume: bool = False,
    eval_data: str | Path | None = None,
    log=print,
) -> dict[str, Any]:
    """Train (or resume) the tiny prior on the shards under ``data``; checkpoint at ``out``.

    Stops at ``options.budget_min`` minutes of this invocation or ``max_steps`` total
    steps. ``eval_data``: shards of held-out clips (default: none, held-out metric off).
    Returns the final log record.
    """
    o = options
    if o.threads:
        torch.set_num_threads(int(o.threads))
    out = Path(out)
    device = torch.device(o.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserInputError("--device cuda: CUDA is not available in this torch build")
    n_shards = _n_shards(data)
    ds = prepare_dataset(data, seed=o.seed)
    n = ds["frames"].shape[0]
    if n == 0:
        raise UserInputError(f"{data}: the shards hold no clips")
    T, H, W = ds["frames"].shape[1:4]
    tokens = ds["tokens"]
    uncond = text_tokens([""]).half()[0]
    ev = prepare_dataset(eval_data, seed=o.seed, held_out=True) if eval_data else None

    cfg = {
        "net": model_config(o.size),
        "num_frames": int(T),
        "height": int(H),
        "width": int(W),
        "max_tokens": MAX_TOKENS,
    }
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(o.seed)  # the initial weights depend on the seed only
        net = TinyVideoUNet(**cfg["net"]).to(device)
    ema = TinyVideoUNet(**cfg["net"]).to(device)
    ema.load_state_dict(net.state_dict())
    for p in ema.parameters():
        p.requires_grad_(False)
    opt = torch.optim.AdamW(net.parameters(), lr=o.lr, weight_decay=0.01)
    gen = torch.Generator().manual_seed(o.seed)
    state = {"step": 0, "epoch": 0, "offset": 0, "elapsed_s": 0.0, "log": []}
    if resume and out.exists():
        ck = torch.load(out, map_location="cpu", weights_only=False)
        if ck["config"] != cfg:
            raise UserInputError(
                f"{out}: checkpoint was trained with another network or clip layout "
                f"({ck['config']}); use --out for a new file"
            )
        net.load_state_dict(ck["model"])
        ema.load_state_dict(ck["ema"])
        opt.load_state_dict(ck["opt"])
        gen.set_state(ck["rng"])
        state = ck["state"]
        log(f"resumed from {out} at step {state['step']}")
    elif out.exists() and not resume:
        raise UserInputError(f"{out}: exists; pass --resume to continue it or another --out")
    ac = scaled_linear_alphas_cumprod().to(device)
    n_params = sum(p.numel() for p in net.parameters())

    def perm(epoch: int) -> np.ndarray:
        return epoch_order(ds["groups"], o.seed, epoch, o.balance)

    contrast = _ContrastPrompts([sp["shape"] for sp in ds["specs"]]) if o.contrast > 0 else None

    order = perm(state["epoch"])

    def save(final: bool = False) -> None:
        meta = {
            "clips": int(n),
            "data": str(data),
            "steps": int(state["step"]),
            "train_time_s": float(state["elapsed_s"]),
            "parameters": int(n_params),
            "batch": o.batch,
            "options": asdict(o),
        }
        _atomic_save(
            {
                "config": cfg,
                "model": net.state_dict(),
                "ema": ema.state_dict(),
                "opt": opt.state_dict(),
                "rng": gen.get_state(),
                "state": state,
                "meta": meta,
            },
            out,
        )

    def held_out_mse() -> float:
        if ev is None:
            return float("nan")
        g = torch.Generator().manual_seed(1234)
        k = min(32, ev["frames"].shape[0])
        z0 = _to_latent(ev["frames"][:k]).to(device)
        t = torch.randint(0, 1000, (k,), generator=g).to(device)
        noise = torch.randn(z0.shape, generator=g).to(device)
        txt = ev["tokens"][ev["caption_idx"][:k, 0]].float().to(device)
        a = ac[t].view(-1, 1, 1, 1, 1)
        with torch.no_grad():
            pred = ema(a.sqrt() * z0 + (1 - a).sqrt() * noise, t, txt)
        return float(((pred - noise) ** 2).mean())

    interrupted = {"flag": False}

    def on_sigint(*_):
        interrupted["flag"] = True

    old = signal.signal(signal.SIGINT, on_sigint) if _main_thread() else None
    t_start = time.perf_counter()
    base_elapsed = state["elapsed_s"]
    run_loss: list[float] = []
    run_hinge: list[float] = []
    log(f"training {n_params} parameters on {n} clips ({T}x{H}x{W}), device {device}")
    try:
        while True:
            if o.max_steps is not None and state["step"] >= o.max_steps:
                break
            if time.perf_counter() - t_start > 60.0 * o.budget_min or interrupted["flag"]:
                break
            if state["offset"] + o.batch > n:
                state["epoch"] += 1
                state["offset"] = 0
                if o.reload_data and _n_shards(data) != n_shards:
                    ds = prepare_dataset(data, seed=o.seed)
                    n, tokens, n_shards = ds["frames"].shape[0], ds["tokens"], _n_shards(data)
                    if contrast is not None:
                        contrast = _ContrastPrompts([sp["shape"] for sp in ds["specs"]])
                    log(f"data reloaded: {n} clips")
                order = perm(state["epoch"])
            idx = order[state["offset"] : state["offset"] + o.batch]
            state["offset"] += o.batch
            b = len(idx)
            z0 = _to_latent(ds["frames"][idx])
            flip = torch.rand(b, generator=gen) < 0.5
            z0 = torch.where(flip.view(-1, 1, 1, 1, 1), z0.flip(-1), z0)
            pick = torch.randint(0, CAPTIONS_PER_CLIP, (b,), generator=gen).numpy()
            txt = tokens[ds["caption_idx"][idx, pick]].float()
            drop = torch.rand(b, generator=gen) < o.cond_dropout
            txt = torch.where(drop.view(-1, 1, 1), uncond.float()[None], txt)
            t = torch.randint(0, 1000, (b,), generator=gen)
            noise = torch.randn(z0.shape, generator=gen)
            z0, txt, t, noise = z0.to(device), txt.to(device), t.to(device), noise.to(device)
            a = ac[t].view(-1, 1, 1, 1, 1)
            zt = a.sqrt() * z0 + (1 - a).sqrt() * noise
            for gparam in opt.param_groups:
                gparam["lr"] = _lr(state["step"], o)
            loss = ((net(zt, t, txt) - noise) ** 2).mean()
            hinge = None
            if contrast is not None:
                rows = [
                    r
                    for r in range(b)
                    if ds["groups"][idx[r]] is not None
                    and torch.rand(1, generator=gen).item() < o.contrast_share
                ]
                if rows:
                    pairs = [
                        contrast.draw(
                            GROUPS.index(ds["groups"][idx[r]]), ds["specs"][idx[r]]["shape"], gen
                        )
                        for r in rows
                    ]
                    both = torch.stack([p_ for pr in pairs for p_ in pr]).float().to(device)
                    sel = torch.tensor(rows).repeat_interleave(2).to(device)
                    err = ((net(zt[sel], t[sel], both) - noise[sel]) ** 2).mean(dim=(1, 2, 3, 4))
                    pos, neg = err[0::2], err[1::2]
                    hinge = torch.relu(pos - neg + o.contrast_margin * pos.detach()).mean()
                    loss_total = loss + o.contrast * hinge
            opt.zero_grad(set_to_none=True)
            (loss_total if hinge is not None else loss).backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            d = min(o.ema_decay, (1 + state["step"]) / (10 + state["step"]))
            with torch.no_grad():
                for pe, pn in zip(ema.parameters(), net.parameters(), strict=True):
                    pe.mul_(d).add_(pn.detach(), alpha=1 - d)
                for be, bn in zip(ema.buffers(), net.buffers(), strict=True):
                    be.copy_(bn)
            state["step"] += 1
            state["elapsed_s"] = base_elapsed + time.perf_counter() - t_start
            run_loss.append(float(loss.detach()))
            if hinge is not None:
                run_hinge.append(float(hinge.detach()))
            if state["step"] % 50 == 0:
                rec = {
                    "step": state["step"],
                    "loss": float(np.mean(run_loss[-50:])),
                    "time_s": round(state["elapsed_s"], 1),
                    "epoch": state["epoch"],
                }
                if run_hinge:
                    rec["contrast_hinge"] = float(np.mean(run_hinge[-50:]))
                if o.eval_every and state["step"] % o.eval_every == 0:
                    rec["held_out_mse"] = held_out_mse()
                state["log"].append(rec)
                log(json.dumps(rec))
            if state["step"] % o.save_every == 0:
                save()
        rec = {"step": state["step"], "time_s": round(state["elapsed_s"], 1)}
        if ev is not None:
            rec["held_out_mse"] = held_out_mse()
        state["log"].append(rec)
        save(final=True)
        log(json.dumps({"final": rec, "checkpoint": str(out)}))
        return rec
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)


def _n_shards(root) -> int:
    return len(list(Path(root).glob("shard-*[0-9].npz")))


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


# ---- measuring -----------------------------------------------------------------------


def discrimination(
    prior: TinyPrior,
    frames: np.ndarray,
    measures: list[dict],
    specs: list[dict],
    *,
    timesteps: tuple[int, ...] = (100, 250, 400),
    noise_draws: int = 2,
    held_out: bool = True,
    mode: str = "absolute",
    seed: int = 0,
    max_clips: int | None = None,
    prompts_per_group: int = 2,
) -> dict[str, Any]:
    """Caption discrimination over the motion groups.

    For every clip with a motion group, score each group's prompts (the ``held_out``
    phrasings, the clip's object noun, no material noun) by the denoising ε-MSE under
    the same noise and timesteps, average over the group's prompts, and pick the group
    with the lowest score. ``mode="contrast"`` scores ``mse(cond) - mse(uncond)``
    (identical ranking; reported for the size of the text effect). Returns accuracy,
    per-group counts, the confusion matrix (rows = true group) and the mean loss gap
    between the true and the best wrong group.
    """
    g = torch.Generator().manual_seed(seed)
    rows = []
    for i, (m, s) in enumerate(zip(measures, specs, strict=True)):
        mm = dict(m)
        mm["granular"] = 1.0 if s["cls"] == "sand" else 0.0
        grp = motion_group(mm)
        if grp is not None:
            rows.append((i, grp, s["shape"]))
    if max_clips is not None:
        rows = rows[:max_clips]
    n_g = len(GROUPS)
    conf = np.zeros((n_g, n_g), dtype=np.int64)
    gaps = []
    ts = torch.tensor(timesteps).repeat_interleave(noise_draws)
    for i, grp, shape in rows:
        ks = range(prompts_per_group)
        prompts = [group_prompt(gn, shape, k, held_out=held_out) for gn in GROUPS for k in ks]
        emb = text_tokens(prompts + [""]).to(prior.device)
        z0 = prior.encode(torch.from_numpy(frames[i]).float() / 255.0)
        noise = torch.randn((len(ts), *z0.shape[1:]), generator=g).to(prior.device)
        losses = prior.denoising_loss(z0, emb, ts.to(prior.device), noise)
        per = losses[:-1].reshape(n_g, prompts_per_group).mean(1)
        if mode == "contrast":
            per = per - losses[-1]
        pred = int(per.argmin())
        true = GROUPS.index(grp)
        conf[true, pred] += 1
        wrong = torch.cat([per[:true], per[true + 1 :]])
        gaps.append(float((wrong.min() - per[true]) / losses[-1]))
    total = int(conf.sum())
    return {
        "clips": total,
        "accuracy": float(np.trace(conf) / total) if total else float("nan"),
        "chance": 1.0 / n_g,
        "groups": list(GROUPS),
        "per_group": {GROUPS[k]: int(conf[k].sum()) for k in range(n_g)},
        "confusion": conf.tolist(),
        "mean_relative_gap": float(np.mean(gaps)) if gaps else float("nan"),
    }


def prompt_scores(
    prior: TinyPrior,
    clips: list[np.ndarray],
    prompts: list[str],
    *,
    timesteps: tuple[int, ...] = (100, 250, 400, 600),
    noise_draws: int = 3,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """Denoising ε-MSE of each clip under each prompt and under ``""``.

    ``clips``: uint8 ``[T, H, W, 3]`` each. The same noise and timesteps for every clip
    and prompt (common random numbers, so differences between clips are not noise).
    Returns ``{"cond": [n_clips, n_prompts], "uncond": [n_clips]}``; the classifier-score
    contrast of prompt k is ``cond[:, k] - uncond`` (lower: the prompt explains the clip
    better than no prompt).
    """
    g = torch.Generator().manual_seed(seed)
    ts = torch.tensor(timesteps).repeat_interleave(noise_draws)
    emb = text_tokens(list(prompts) + [""]).to(prior.device)
    shape = (len(ts), prior.num_frames, 3, prior.height, prior.width)
    noise = torch.randn(shape, generator=g).to(prior.device)
    rows = []
    for clip in clips:
        z0 = prior.encode(torch.from_numpy(np.asarray(clip)).float() / 255.0)
        rows.append(prior.denoising_loss(z0, emb, ts.to(prior.device), noise).cpu().numpy())
    arr = np.stack(rows)
    return {"cond": arr[:, :-1], "uncond": arr[:, -1]}
