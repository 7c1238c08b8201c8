"""motionphysics render SCENE --out FILE: render a scene to an image or an orbit video.

The camera is an orbit camera framed on the scene's bounding box unless --radius
is given (then it looks at the box centre from that distance). --orbit sweeps the
azimuth through 360 degrees over --frames frames into an .mp4 or .gif. The folder of
--out must exist and be writable (checked before rendering).
"""

from __future__ import annotations

import argparse
import sys

from motionphysics.errors import UserInputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
VIDEO_SUFFIXES = (".mp4", ".gif")


def register(subparsers) -> None:
    from motionphysics.render.core import RENDER_BACKENDS

    p = subparsers.add_parser(
        "render",
        help="render a scene (builtin:NAME, 3DGS .ply, mesh) to a PNG or an orbit video",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "scene", metavar="SCENE", help="builtin:NAME, an INRIA 3DGS .ply, or a mesh file"
    )
    p.add_argument(
        "--out", required=True, help="output .png/.jpg (still) or .mp4/.gif (with --orbit)"
    )
    p.add_argument("--orbit", action="store_true", help="render a 360-degree orbit video")
    p.add_argument("--frames", type=int, default=48, help="frames of the orbit (default 48)")
    p.add_argument("--fps", type=float, default=24.0, help="orbit video frame rate (default 24)")
    p.add_argument(
        "--azimuth", type=float, default=30.0, help="degrees CCW from +x about z (default 30)"
    )
    p.add_argument(
        "--elevation", type=float, default=20.0, help="degrees above the horizon (default 20)"
    )
    p.add_argument(
        "--radius",
        type=float,
        default=None,
        help="camera distance [m] (default: frame the scene's bounding box)",
    )
    p.add_argument("--width", type=int, default=256, help="image width [px] (default 256)")
    p.add_argument("--height", type=int, default=256, help="image height [px] (default 256)")
    p.add_argument(
        "--fov", type=float, default=45.0, help="vertical field of view [deg] (default 45)"
    )
    p.add_argument(
        "--background",
        type=float,
        nargs=3,
        default=(1.0, 1.0, 1.0),
        metavar=("R", "G", "B"),
        help="background colour in [0, 1] (default white)",
    )
    p.add_argument(
        "--backend",
        default="auto",
        choices=RENDER_BACKENDS.names(),
        help="rasteriser backend (default auto)",
    )
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.set_defaults(func=run)


def _validate(args) -> str:
    from pathlib import Path

    suffix = Path(args.out).suffix.lower()
    if args.orbit and suffix not in VIDEO_SUFFIXES:
        raise UserInputError(f"--out {args.out}: with --orbit expected a .mp4 or .gif file")
    if not args.orbit and suffix not in IMAGE_SUFFIXES:
        raise UserInputError(
            f"--out {args.out}: expected a .png or .jpg file (or pass --orbit for video)"
        )
    if args.frames < 1:
        raise UserInputError(f"--frames: expected a positive count, got {args.frames}")
    if not (8 <= args.width <= 4096 and 8 <= args.height <= 4096):
        raise UserInputError(
            f"--width/--height: expected 8..4096 pixels, got {args.width}x{args.height}"
        )
    if not 1 < args.fov < 179:
        raise UserInputError(f"--fov: expected degrees in (1, 179), got {args.fov}")
    if args.radius is not None and not args.radius > 0:
        raise UserInputError(f"--radius: expected a positive distance [m], got {args.radius}")
    if not all(0.0 <= c <= 1.0 for c in args.background):
        raise UserInputError(
            f"--background: expected three numbers in [0, 1], got {list(args.background)}"
        )
    if not args.fps > 0:
        raise UserInputError(f"--fps: expected a positive rate, got {args.fps}")
    return suffix


def scene_bounds(scene):
    """Box ``(lo [3], hi [3])`` of the splat centres (list of floats) [m]."""
    m = scene.means.detach().double()
    return m.min(0).values.tolist(), m.max(0).values.tolist()


def run(args) -> int:
    from pathlib import Path

    from motionphysics.io.paths import check_output_file, writing

    _validate(args)
    # Before any work: an unwritable or missing output folder is one line, status 2.
    check_output_file(args.out, "--out")
    import torch

    from motionphysics.io.video import write_image, write_video
    from motionphysics.render.camera import frame_bounds
    from motionphysics.render.deform import render_scene
    from motionphysics.runtime import check_device
    from motionphysics.scene import load_scene

    device = check_device(args.device)
    scene = load_scene(args.scene)
    if scene.num == 0:
        raise UserInputError(f"{args.scene}: the scene has no splats")
    scene = scene.to(device)
    lo, hi = scene_bounds(scene)
    azimuths = (
        [args.azimuth + 360.0 * k / args.frames for k in range(args.frames)]
        if args.orbit
        else [args.azimuth]
    )
    frames = []
    show = sys.stderr.isatty() and not getattr(args, "quiet", False) and len(azimuths) > 1
    with torch.no_grad():
        for k, az in enumerate(azimuths):
            cam = frame_bounds(
                lo, hi, az, args.elevation, args.fov, args.width, args.height, radius=args.radius
            )
            out = render_scene(scene, cam, tuple(args.background), args.backend)
            frames.append(out.rgb.clamp(0, 1).cpu())
            if show:
                print(f"\rrendering frame {k + 1}/{len(azimuths)}", end="", file=sys.stderr)
    if show:
        print(file=sys.stderr)
    out = Path(args.out)
    partial = out.with_name(
        f".{out.stem}.partial{out.suffix.lower() if args.orbit else out.suffix}"
    )
    with writing(out, "--out", partial=partial):
        if args.orbit:
            write_video(torch.stack(frames), out, fps=args.fps)
        else:
            write_image(frames[0], out)
    if not getattr(args, "quiet", False):
        print(f"wrote {args.out}")
    return 0
