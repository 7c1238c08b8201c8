"""motionphysics view RUN_DIR [RUN_DIR ...]: a web viewer of the deformed splats over time.

Serves the runs with viser (the ``viewer`` extra) at http://HOST:PORT (127.0.0.1 by
default): a frame slider, play / pause and speed, the ground and colliders, the run's
camera as the start view, and a side panel with the prompt, the material, the loss
and parameter curves and the metrics. Frames are streamed one at a time. Ctrl-C stops
it (exit status 0).
"""

from __future__ import annotations

import signal
import sys


def _main(args) -> int:
    from motionphysics.errors import UserInputError

    try:
        import viser  # noqa: F401  (the optional extra)
    except ImportError:
        raise UserInputError(
            "view: the viewer needs viser; install it with `pip install 'motionphysics[viewer]'`"
        ) from None
    from motionphysics.viewer.server import start_view

    if args.max_splats is not None and args.max_splats < 1:
        raise UserInputError(f"--max-splats: expected a positive count, got {args.max_splats}")
    viewer = None
    previous = signal.getsignal(signal.SIGTERM)

    def _terminate(_signum, _frame):  # SIGTERM stops as cleanly as Ctrl-C
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, _terminate)
        viewer = start_view(
            args.run_dirs,
            host=args.host,
            port=args.port,
            frame=args.frame,
            max_splats=args.max_splats,
            object_name=args.object,
        )
        viewer.wait()
    except KeyboardInterrupt:
        pass
    finally:
        try:
            if viewer is not None:
                viewer.stop()
                print("motionphysics view: stopped", file=sys.stderr)
        finally:
            signal.signal(signal.SIGTERM, previous)
    return 0


def register(subparsers) -> None:
    from motionphysics.viewer.frames import DEFAULT_MAX_SPLATS

    p = subparsers.add_parser(
        "view",
        help="web viewer of run directories (viser)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("run_dirs", metavar="RUN_DIR", nargs="+", help="run directories to show")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8080, help="port to listen on (default 8080)")
    p.add_argument(
        "--frame", type=int, default=0, metavar="K", help="frame shown first (default 0)"
    )
    p.add_argument(
        "--max-splats",
        type=int,
        default=DEFAULT_MAX_SPLATS,
        metavar="N",
        help="show at most N splats per frame (a fixed random subset of larger runs)",
    )
    p.add_argument(
        "--object",
        default=None,
        metavar="NAME",
        help="a run of several objects: show only this object (its name in objects:)",
    )
    p.set_defaults(func=_main)
