"""Renderer benchmark grid for BENCHMARKS.md, and the gradient-bias measurement of the alpha cut.

    python benchmarks/bench_render.py              # timing table (markdown) to stdout
    python benchmarks/bench_render.py --bias       # FD vs autograd, hard vs smooth 1/255 cut

Timings: ``motionphysics.render.bench.time_render`` (the ``motionphysics bench render``
target) over splats x size x {forward, forward+backward} x threads; medians of
``--repeats`` runs after one warm-up. Load on the shared machine is printed with the table.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys


def timing_table(splats, sizes, threads, repeats, backend):
    from motionphysics.render.bench import time_render

    rows = []
    for n in splats:
        for size in sizes:
            for t in threads:
                cells = []
                for backward in (False, True):
                    with contextlib.redirect_stdout(sys.stderr):
                        res = time_render(n, size, backward, repeats, backend, t)
                    cells += [res["seconds_median"], res["cpu_seconds_median"]]
                rows.append((n, size, t, *cells, res["backend"]))
                print(f"  {n} {size} t={t}: {cells}", file=sys.stderr)
    print(f"load average (1, 5, 15 min) before: {fmt(LOAD0)}, after: {fmt(os.getloadavg())}")
    print()
    print(
        "| splats | size | threads | forward: wall [s] | (CPU [s]) | forward+backward: wall [s] | (CPU [s]) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n, size, t, f, fc, fb, fbc, _b in rows:
        print(f"| {n} | {size}² | {t} | {f:.3f} | ({fc:.3f}) | {fb:.3f} | ({fbc:.3f}) |")


def fmt(load):
    return ", ".join(f"{x:.1f}" for x in load)


def bias(h_values=(2e-3, 5e-4, 1e-4, 2e-5)):
    """Relative error |autograd - FD| / |FD| of d(sum rgb)/d means, hard vs smooth cut."""
    import torch

    from motionphysics.render.camera import orbit_camera
    from motionphysics.render.rasterize import rasterize_reference

    g = torch.Generator().manual_seed(5)
    n = 12
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 0.7
    A = torch.randn(n, 3, 3, generator=g, dtype=torch.float64) * 0.05
    covs = A @ A.transpose(1, 2) + 1e-4 * torch.eye(3, dtype=torch.float64)
    colors = torch.rand(n, 3, generator=g, dtype=torch.float64)
    opac = 0.3 + 0.6 * torch.rand(n, generator=g, dtype=torch.float64)
    cam = orbit_camera(20.0, 30.0, 2.0, (0, 0, 0), 50.0, 40, 32)
    print("| FD step [m] (px) | hard cut: rel. error | smooth cut: rel. error |")
    print("|---:|---:|---:|")
    grads = {}
    for h in h_values:
        errs = {}
        for cut in ("hard", "smooth"):

            def loss(m, cut=cut):
                return rasterize_reference(m, covs, colors, opac, cam, (1, 1, 1), cut=cut).rgb.sum()

            leaf = means.clone().requires_grad_()
            loss(leaf).backward()
            grads[cut] = leaf.grad
            fd = torch.zeros_like(means)
            for i in range(means.numel()):
                d = torch.zeros(means.numel(), dtype=torch.float64)
                d[i] = h
                d = d.reshape(means.shape)
                fd.reshape(-1)[i] = (loss(means + d) - loss(means - d)) / (2 * h)
            errs[cut] = ((leaf.grad - fd).norm() / fd.norm()).item()
        px = h * cam.fy / 2.0
        print(f"| {h:g} ({px:.3f}) | {errs['hard']:.2e} | {errs['smooth']:.2e} |")
    diff = ((grads["hard"] - grads["smooth"]).norm() / grads["smooth"].norm()).item()
    print(f"\nrelative difference of the two autograd gradients: {diff:.2e}")


LOAD0 = os.getloadavg()

if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--bias", action="store_true")
    ap.add_argument("--splats", type=int, nargs="+", default=[5000, 20000, 50000])
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 256])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backend", default="auto")
    a = ap.parse_args()
    if a.bias:
        bias()
    else:
        timing_table(a.splats, a.sizes, a.threads, a.repeats, a.backend)
