"""motionphysics prior data|train|eval|export: build the embedded motion prior.

The motion prior is a diffusion model over per-frame motion features of simulated clips
(--prior motion, the only choice: the pixel prior that --prior tiny built was removed,
and asking for it is refused with the reason).

prior data OUT       simulate training clips (the states of a particle subset) into
                     shards under OUT; deterministic per --seed, resumable (shards
                     already there are kept), parallel over --workers.
prior train DATA     train the prior on those shards for --budget-min minutes or
                     --steps steps; --resume continues a checkpoint exactly (weights,
                     EMA, optimiser, RNG, data position).
prior eval CKPT DATA caption discrimination over the motion groups on held-out clips
                     with held-out phrasings (and, with --train-data, a text-free
                     classifier on the features); prints JSON.
prior export CKPT DST  the shippable weights of a checkpoint (EMA, statistics).

The shipped weights and their measured limits are described in the model card
beside them in the package (priors/, the model card file).
"""

from __future__ import annotations

import argparse
import json
import sys


def _positive(kind):
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not v > 0:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        return v

    return parse


def _check_prior(args) -> None:
    """Refuse a removed prior (``--prior tiny``) in one line, before any work."""
    from motionphysics.errors import UserInputError
    from motionphysics.priors import removed_prior

    refused = removed_prior(args.prior)
    if refused:
        raise UserInputError(refused)


def _data(args) -> int:
    from motionphysics.errors import UserInputError
    from motionphysics.priors.motion_data import (
        HELD_OUT_SHAPES,
        TRAIN_SHAPES,
        generate,
        shard_summary,
    )
    from motionphysics.progress import Progress

    _check_prior(args)
    shapes = HELD_OUT_SHAPES if args.held_out_shapes else TRAIN_SHAPES
    with Progress(quiet=args.quiet, verbose=args.verbose) as progress:
        n_shards = None
        with progress.stage("simulate clips") as st:

            def on_shard(done, total, _n):
                nonlocal n_shards
                if n_shards is None:
                    n_shards = total
                    st.set_total(total)
                st.advance()

            meta = generate(
                args.out,
                args.clips,
                workers=args.workers,
                seed=args.seed,
                shapes=shapes,
                on_shard=on_shard,
            )
    held = shard_summary(args.out)
    line = f"{args.out}: {held['clips']} clips (seed {meta['seed']}, shapes {', '.join(shapes)})"
    if held["failed"]:
        why, count = max(held["reasons"].items(), key=lambda kv: kv[1])
        line += (
            f"; {held['failed']} of {held['clips'] + held['failed']} failed to simulate "
            f"and were left out (most often, {count}x: {why})"
        )
    print(line)
    if held["clips"] == 0:
        raise UserInputError(
            f"{args.out}: no clip simulated, so there is nothing to train on "
            f"(first failure: {next(iter(held['reasons']), 'none recorded')})"
        )
    return 0


def _train(args) -> int:
    from pathlib import Path

    from motionphysics.priors.motion_train import MotionTrainOptions, train

    _check_prior(args)
    out = Path(args.out) if args.out else Path(args.data) / "motion_prior.pt"
    opts = MotionTrainOptions(
        budget_min=args.budget_min,
        max_steps=args.steps,
        batch=args.batch,
        seed=args.seed,
        device=args.device,
        size="cuda" if args.device == "cuda" else "cpu",
        threads=args.threads,
        contrast=args.contrast,
        sentence_dropout=args.sentence_dropout,
        subject_swap=args.subject_swap,
    )

    def log(text: str) -> None:
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    rec = train(args.data, out, opts, resume=args.resume, log=log)
    print(json.dumps({"checkpoint": str(out), **rec}))
    return 0


def _eval(args) -> int:
    import torch

    from motionphysics.priors.motion import MotionPrior
    from motionphysics.priors.motion_train import discrimination, feature_classifier, prepare

    _check_prior(args)
    torch.set_num_threads(args.threads or torch.get_num_threads())
    prior = MotionPrior.from_pretrained(args.checkpoint)
    held = prepare(args.data, held_out=True)
    res = {
        "discrimination": discrimination(
            prior, held, held_out=not args.train_phrasings, max_clips=args.max_clips
        )
    }
    if args.train_data:
        res["feature_classifier"] = feature_classifier(prepare(args.train_data), held)
    if args.snapshot:
        from motionphysics.priors.motion_train import read_snapshot, write_snapshot

        snap = read_snapshot(write_snapshot(held, args.snapshot))
        res["snapshot"] = {"path": args.snapshot, **discrimination(prior, snap)}
    print(json.dumps(res, indent=1))
    return 0


def _export(args) -> int:
    from motionphysics.priors.motion_train import export_weights

    meta = None
    if args.eval:
        from pathlib import Path

        meta = {"evaluation": json.loads(Path(args.eval).read_text())}
    dst = export_weights(args.checkpoint, args.dst, meta)
    print(f"{dst}: {dst.stat().st_size / 1e6:.2f} MB")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "prior",
        help="build the embedded motion prior (data, train, eval, export)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="prior_command", metavar="STEP")
    sub.required = True

    d = sub.add_parser(
        "data",
        help="simulate training clips into shards",
        description="Simulate training clips into shards (deterministic per seed, resumable).",
    )
    _which(d)
    d.add_argument("out", metavar="OUT", help="output directory (shards are added/kept)")
    d.add_argument("--clips", type=_positive(int), default=1000, help="number of clips")
    d.add_argument("--workers", type=_positive(int), default=1, help="processes")
    d.add_argument("--seed", type=int, default=0, help="data-set seed")
    d.add_argument(
        "--held-out-shapes",
        action="store_true",
        help="draw only the held-out shapes (duck, torus, bird_simple): an evaluation set",
    )
    d.set_defaults(func=_data)

    t = sub.add_parser(
        "train",
        help="train the motion prior on shards",
        description="Train the prior on shards, time- or step-budgeted and resumable.",
    )
    _which(t)
    t.add_argument("data", metavar="DATA", help="directory of shards (`prior data`)")
    t.add_argument("--budget-min", type=_positive(float), default=30.0, help="minutes to train")
    t.add_argument("--steps", type=_positive(int), default=None, help="stop at this many steps")
    t.add_argument("--batch", type=_positive(int), default=64, help="clips per step")
    t.add_argument("--seed", type=int, default=0, help="training seed (init, noise, order)")
    t.add_argument("--resume", action="store_true", help="continue the checkpoint at --out")
    t.add_argument(
        "--out",
        metavar="PATH",
        help="checkpoint file (default DATA/motion_prior.pt)",
    )
    t.add_argument(
        "--device", choices=("cpu", "cuda"), default="cpu", help="cuda trains a bigger model"
    )
    t.add_argument("--threads", type=_positive(int), default=None, help="torch CPU threads")
    t.add_argument(
        "--contrast",
        type=float,
        default=0.5,
        metavar="W",
        help="weight of the caption contrast (a cross-entropy over the motion groups: the "
        "clip's own group's prompt must denoise it best, at the same noise); 0 = plain "
        "denoising",
    )
    t.add_argument(
        "--sentence-dropout",
        type=float,
        default=0.5,
        metavar="P",
        help="probability that a caption's sentence vector is replaced by the empty "
        "prompt's while its motion reading is kept (the reading alone must carry the "
        "motion, as it must for words the prior never saw); 0 = never",
    )
    t.add_argument(
        "--subject-swap",
        type=float,
        default=0.5,
        metavar="P",
        help="probability that a caption's sentence vector is another caption's while its "
        "motion reading is kept (the material words cannot decide the motion); 0 = never",
    )
    t.set_defaults(func=_train)

    e = sub.add_parser(
        "eval",
        help="caption discrimination on held-out clips",
        description="Caption discrimination over the motion groups on held-out clips (JSON).",
    )
    _which(e)
    e.add_argument("checkpoint", metavar="CKPT", help="weights file (`prior train`)")
    e.add_argument("data", metavar="DATA", help="held-out shards")
    e.add_argument(
        "--max-clips", type=_positive(int), default=None, help="evaluate at most this many"
    )
    e.add_argument("--train-phrasings", action="store_true", help="use training phrasings")
    e.add_argument("--threads", type=_positive(int), default=None, help="torch CPU threads")
    e.add_argument(
        "--train-data",
        metavar="DIR",
        help="training shards: adds a text-free classifier on the features",
    )
    e.add_argument(
        "--snapshot",
        metavar="FILE",
        help="write 8 held-out clips per group (features) there and score them",
    )
    e.set_defaults(func=_eval)

    x = sub.add_parser(
        "export",
        help="shippable weights of a checkpoint",
        description="Write the shippable weights (EMA, feature statistics, meta) of a checkpoint.",
    )
    x.add_argument("checkpoint", metavar="CKPT", help="training checkpoint (`prior train`)")
    x.add_argument("dst", metavar="DST", help="weights file to write")
    x.add_argument("--eval", metavar="JSON", help="`prior eval` output to record in the meta")
    x.set_defaults(func=_export)


def _which(p) -> None:
    from motionphysics.priors import PRIORS
    from motionphysics.registry import Choices

    p.add_argument(
        "--prior",
        choices=Choices(("motion",), PRIORS.removed),
        default="motion",
        help="which embedded prior: motion, the only one (kept so scripts that name it work)",
    )
