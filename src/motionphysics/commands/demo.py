"""motionphysics demo: the main job on a bundled scene with embedded defaults.

The demo's config is an ordinary run config, ``examples/demo.yaml`` (a copy ships in
the package as ``motionphysics/commands/demo.yaml`` so an installed package finds it):
copy it, edit it, and pass it to ``motionphysics run``. The material is estimated
offline (``kb``); nothing is downloaded. Running the demo again into the same folder
replaces the previous demo run there (any other run is refused as usual).
"""

from __future__ import annotations

import json
from pathlib import Path

from motionphysics.commands.run import add_display_options

PACKAGED = Path(__file__).with_name("demo.yaml")


def demo_config_path() -> Path:
    """``examples/demo.yaml`` of a source checkout when present, else the packaged copy."""
    repo = Path(__file__).resolve().parents[3] / "examples" / "demo.yaml"
    return repo if repo.is_file() else PACKAGED


def _previous_demo(out: Path) -> bool:
    try:
        return json.loads((out / "params.json").read_text()).get("command") == "demo"
    except (OSError, ValueError, AttributeError):
        return False


def _main(args) -> int:
    from motionphysics.pipeline import load_run_config, print_summary, run_pipeline
    from motionphysics.progress import Progress

    path = demo_config_path()
    cfg = load_run_config(path, {"device": args.device})
    out = Path(args.out) if args.out else Path("runs") / "demo"
    if not args.quiet:
        print(f"demo config: {path} (copy and edit it, then: motionphysics run YOUR.yaml)")
    with Progress(quiet=args.quiet, verbose=args.verbose) as prog:
        result = run_pipeline(
            cfg,
            out,
            init_backend="kb",
            optimise=True,
            force=args.force or _previous_demo(out),
            progress=prog,
            config_origin=str(path),
            command="demo",
        )
    if not args.quiet:
        print_summary(result)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="main job on a bundled scene (elastic bird dropped on the ground)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--out", metavar="DIR", help="run directory (default: runs/demo)")
    p.add_argument("--device", choices=["cpu", "cuda"], help="where to simulate and render")
    p.add_argument(
        "--force", action="store_true", help="overwrite a (non-demo) run already in --out"
    )
    add_display_options(p)
    p.set_defaults(func=_main)
