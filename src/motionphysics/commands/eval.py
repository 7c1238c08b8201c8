"""motionphysics eval RUN_DIR: (re)compute metrics.json from a run's files.

ECMS (optical flow of video.mp4), CLIPSIM and OC (when their local weights are given;
null with the reason otherwise), motion adherence of the prompt (or of ``--prompt``)
measured from trajectory.npz, and the physical diagnostics; prints a short table.
"""

from __future__ import annotations


def _main(args) -> int:
    from motionphysics.evaluation.evaluate import evaluate_run, summary_lines
    from motionphysics.metrics.ecms import ECMSConfig

    ecfg = ECMSConfig(
        bracketing=args.ecms_bracketing,
        flow_height=None if args.flow_height == 0 else args.flow_height,
        eps=args.ecms_eps,
    ).check()
    m = evaluate_run(
        args.run_dir,
        prompt=args.prompt,
        clip=args.clip,
        viclip=args.viclip,
        viclip_bpe=args.viclip_bpe,
        raft=args.raft,
        flow=args.flow,
        ecms_config=ecfg,
        device=args.device,
        object_name=args.object,
    )
    if not args.quiet:
        from pathlib import Path

        name = "metrics.json" if args.object is None else f"metrics_{args.object}.json"
        print(f"metrics:   {Path(args.run_dir) / name}")
        print(f"frames {m['frames']}, particles {m['particles']}, duration {m['duration_s']:.3g} s")
        for line in summary_lines(m):
            print(line)
    return 0


def register(subparsers) -> None:
    from motionphysics.commands.run import add_display_options

    p = subparsers.add_parser(
        "eval", help="write metrics.json for a run directory", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory (holds trajectory.npz)")
    p.add_argument("--prompt", default=None, help="score this sentence instead of the run's prompt")
    p.add_argument(
        "--clip", default=None, metavar="DIR", help="local transformers CLIP ViT-L/14 folder"
    )
    p.add_argument(
        "--viclip", default=None, metavar="PATH", help="local ViClip-InternVid-10M-FLT.pth"
    )
    p.add_argument(
        "--viclip-bpe",
        default=None,
        metavar="PATH",
        help="BPE merges for ViCLIP (bpe_simple_vocab_16e6.txt.gz or merges.txt; default: beside --viclip)",
    )
    p.add_argument(
        "--raft", default=None, metavar="PATH", help="local RAFT-large weights (--flow raft)"
    )
    p.add_argument(
        "--flow", default="dis", choices=("dis", "farneback", "raft"), help="optical flow for ECMS"
    )
    p.add_argument(
        "--flow-height",
        type=int,
        default=256,
        metavar="ROWS",
        help="frames are resized to this many rows before the flow (0: native size)",
    )
    p.add_argument(
        "--ecms-bracketing",
        default="paper",
        choices=("paper", "reciprocal_sum"),
        help="paper: 1/(A+eps)+B+C as typeset; reciprocal_sum: 1/(A+B+C+eps)",
    )
    p.add_argument(
        "--ecms-eps",
        type=float,
        default=1e-3,
        help="added to the motion sum (finite for a still video)",
    )
    p.add_argument("--device", default="cpu", help="torch device for CLIP / ViCLIP / RAFT")
    p.add_argument(
        "--object",
        default=None,
        metavar="NAME",
        help="a run of several objects: this object's metrics (its particles, its phrase of "
        "the prompt) to metrics_NAME.json",
    )
    add_display_options(p)
    p.set_defaults(func=_main)
