"""The ``motionphysics bench render`` target: time the rasteriser on random splats.

Scene: ``N`` splats with centres uniform in a unit ball 4 m in front of an orbit camera
(45 degree vertical fov, so the ball fills about 60% of the image height), log-uniform
scales in [0.008, 0.04] m, random orientations, opacities uniform in [0.2, 1], random
colours. Times one forward (and, with ``--backward``, one backward of a random linear
loss of the image) per run, after one untimed warm-up run (kernel load, allocator).
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time

from motionphysics.errors import UserInputError


def random_splats(n: int, seed: int = 0, dtype=None):
    """(means [n,3], covs [n,3,3], colors [n,3], opacities [n]) of the benchmark scene."""
    import torch

    from motionphysics.scene.gaussians import quat_to_rotmat

    dtype = dtype or torch.float32
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    d = d / d.norm(dim=1, keepdim=True)
    r = torch.rand(n, 1, generator=g, dtype=torch.float64) ** (1.0 / 3.0)
    means = d * r
    log_s = math.log(0.008) + torch.rand(n, 3, generator=g, dtype=torch.float64) * math.log(5.0)
    R = quat_to_rotmat(torch.randn(n, 4, generator=g, dtype=torch.float64))
    covs = (R * torch.exp(2 * log_s)[:, None, :]) @ R.transpose(1, 2)
    colors = torch.rand(n, 3, generator=g, dtype=torch.float64)
    opac = 0.2 + 0.8 * torch.rand(n, generator=g, dtype=torch.float64)
    return tuple(t.to(dtype) for t in (means, covs, colors, opac))


def bench_camera(size: int):
    from motionphysics.render.camera import orbit_camera

    return orbit_camera(30.0, 20.0, 4.0, (0.0, 0.0, 0.0), 45.0, size, size)


def time_render(
    n: int,
    size: int,
    backward: bool,
    repeats: int,
    backend: str = "auto",
    threads: int | None = None,
    seed: int = 0,
) -> dict:
    """Run the benchmark; returns the JSON-ready result dict (seconds per run)."""
    import torch

    from motionphysics.render.rasterize import rasterize, resolve_backend
    from motionphysics.runtime import set_threads

    threads = set_threads(threads)
    means, covs, colors, opac = random_splats(n, seed)
    cam = bench_camera(size)
    g = torch.Generator().manual_seed(seed + 1)
    weight = torch.rand(size, size, 3, generator=g)
    runs, cpu = [], []
    for k in range(repeats + 1):
        leaves = [t.clone().requires_grad_(backward) for t in (means, covs, colors, opac)]
        t0, c0 = time.perf_counter(), time.process_time()
        out = rasterize(*leaves, cam, (1.0, 1.0, 1.0), backend=backend)
        if backward:
            out.rgb.backward(weight)  # the backward of the linear loss sum(weight * rgb)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if k > 0:  # the first run loads kernels and warms the allocator
            runs.append(dt)
            cpu.append(dc)
    return {
        "target": "render",
        "backend": resolve_backend(backend, means.device),
        "splats": n,
        "size": size,
        "backward": backward,
        "threads": threads,
        "repeats": repeats,
        "seconds_median": statistics.median(runs),
        "seconds_min": min(runs),
        "seconds": runs,
        # CPU time of this process (all its threads): what the render costs, even when
        # other processes make the wall clock wait.
        "cpu_seconds_median": statistics.median(cpu),
        "load_average": list(os.getloadavg()),
        "coverage": float(out.alpha.detach().mean()),
    }


def _run(args) -> int:
    if args.splats < 1 or args.size < 8 or args.repeats < 1:
        raise UserInputError("bench render: --splats >= 1, --size >= 8 and --repeats >= 1 expected")
    if args.threads is not None and args.threads < 1:
        raise UserInputError(f"--threads: expected a positive count, got {args.threads}")
    import contextlib
    import sys

    # Warp's load messages go to stdout; keep stdout for the result (--json is parsed).
    with contextlib.redirect_stdout(sys.stderr):
        res = time_render(
            args.splats, args.size, args.backward, args.repeats, args.backend, args.threads
        )
    if args.json:
        print(json.dumps(res))
    else:
        what = "forward+backward" if res["backward"] else "forward"
        print(
            f"render {what}: {res['splats']} splats, {res['size']}x{res['size']}, "
            f"{res['backend']}, {res['threads']} thread(s): median {res['seconds_median']:.4f} s "
            f"(min {res['seconds_min']:.4f} s, {res['repeats']} runs; CPU {res['cpu_seconds_median']:.4f} s; "
            f"load {res['load_average'][0]:.1f})"
        )
    return 0


def register_target(sub) -> None:
    p = sub.add_parser(
        "render",
        help="time the splat rasteriser on random splats",
        description="Time the splat rasteriser on N random splats: centres uniform in a unit "
        "ball 4 m in front of an orbit camera (45 degree vertical field of view), log-uniform "
        "scales in [0.008, 0.04] m, random orientations, opacities uniform in [0.2, 1], random "
        "colours. Each timed run is one forward pass (with --backward, also one backward pass "
        "of a random linear loss of the image), after one untimed warm-up run.",
    )
    p.add_argument("--splats", type=int, default=20000, help="number of splats (default 20000)")
    p.add_argument("--size", type=int, default=256, help="image is SIZE x SIZE (default 256)")
    p.add_argument("--backward", action="store_true", help="time forward + backward")
    p.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: all cores, <= 8)"
    )
    p.add_argument("--repeats", type=int, default=5, help="timed runs (default 5)")
    p.add_argument(
        "--backend",
        default="auto",
        choices=["auto", "torch", "warp", "gsplat"],
        help="rasteriser backend (default auto: warp on CPU, gsplat on CUDA)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)
