"""Warp kernels for the CPU rasteriser: per-pixel front-to-back compositing and its backward.

The image formation is exactly :mod:`motionphysics.render.rasterize`'s (smooth 1/255
cut, 0.99 clamp, 1e-4 stop). Forward: one thread per pixel walks its tile's depth-
sorted splat list and stops early, recording how far it went. Backward: the standard
3DGS reverse traversal, recovering ``T_i = T_{i+1} / (1 - a'_i)`` (safe: a' <= 0.99) and
the colour accumulated behind each splat, accumulating gradients of the screen-space
inputs with atomics (Warp CPU runs a launch on one thread, so they are plain adds).
Pixels are split into bands of tiles, one per torch thread, launched concurrently from
Python threads (a Warp CPU launch releases the GIL); each band writes its own gradient
buffer, summed after. Tile lists are built by a one-thread counting sort in Warp that
visits splats front to back (same lists as ``rasterize.bin_tiles``, 5x faster).

Kernels are built per float dtype (float32 for speed, float64 for gradient checks) and
tile size. :func:`rasterize_warp` is the entry point (one autograd node for the whole
render); kernels are private.
"""

# No `from __future__ import annotations`: Warp evaluates kernel annotations in closures.

import os
from concurrent.futures import ThreadPoolExecutor
from functools import cache

import torch

from motionphysics.render.core import (
    ALPHA_MAX,
    ALPHA_MIN,
    T_MIN,
    TileBins,
    features,
    finish,
    project_gaussians,
)
from motionphysics.runtime import single_thread

C = 5  # channels composited: r, g, b, depth, 1 (sum of weights, for the depth normalisation)


@cache
def _kernels(dtype_name: str, tile: int):
    from motionphysics.runtime import init_warp

    wp = init_warp()
    ft = wp.float32 if dtype_name == "float32" else wp.float64
    npix = tile * tile
    vf = wp.types.vector(C, ft)
    v8 = wp.types.vector(8, ft)
    v12 = wp.types.vector(12, ft)

    @wp.kernel(enable_backward=False, module="unique")
    def forward(
        pk: wp.array(dtype=v8),  # [M] per list entry: mx, my, ca, cb, cc, o, log(τ/o), 0
        ids: wp.array(
            dtype=wp.int32
        ),  # [M] splat index of each entry (tiles' lists, front to back)
        feats: wp.array(dtype=vf),  # [N] rgb, depth, 1
        offsets: wp.array(dtype=wp.int32),  # [tiles + 1]
        tiles_x: int,
        width: int,
        height: int,
        tile0: int,  # first tile of this band
        out_acc: wp.array(dtype=vf),  # [H*W]
        out_t: wp.array(dtype=ft),  # [H*W]
        out_last: wp.array(dtype=wp.int32),  # [H*W] list position after the last splat used
    ):
        tid = wp.tid()
        t = tile0 + tid // npix
        local = tid - (tid // npix) * npix
        x = (t - (t // tiles_x) * tiles_x) * tile + local - (local // tile) * tile
        y = (t // tiles_x) * tile + local // tile
        if x >= width or y >= height:
            return
        px = ft(x) + ft(0.5)
        py = ft(y) + ft(0.5)
        T = ft(1.0)
        acc = vf()
        start = offsets[t]
        last = start
        for k in range(start, offsets[t + 1]):
            e = pk[k]
            dx = e[0] - px
            dy = e[1] - py
            p = ft(-0.5) * (e[2] * dx * dx + e[4] * dy * dy) - e[3] * dx * dy
            if p <= e[6]:  # o exp(p) <= 1/255: zero weight (the smooth cut is 0 there)
                continue
            a = wp.min(ft(ALPHA_MAX), e[5] * wp.exp(wp.min(p, ft(0.0))))
            u = wp.min((a - ft(ALPHA_MIN)) / ft(ALPHA_MIN), ft(1.0))
            if u <= ft(0.0):
                continue
            a = a * u * u * (ft(3.0) - ft(2.0) * u)
            test_t = T * (ft(1.0) - a)
            if test_t < ft(T_MIN):
                break
            acc = acc + (a * T) * feats[ids[k]]
            T = test_t
            last = k + 1
        pix = y * width + x
        out_acc[pix] = acc
        out_t[pix] = T
        out_last[pix] = last

    @wp.kernel(enable_backward=False, module="unique")
    def backward(
        pk: wp.array(dtype=v8),
        ids: wp.array(dtype=wp.int32),
        feats: wp.array(dtype=vf),
        offsets: wp.array(dtype=wp.int32),
        tiles_x: int,
        width: int,
        height: int,
        tile0: int,
        t_final: wp.array(dtype=ft),  # [H*W]
        last: wp.array(dtype=wp.int32),  # [H*W]
        g_acc: wp.array(dtype=vf),  # [H*W] dL/d acc
        g_t: wp.array(dtype=ft),  # [H*W] dL/d T_final
        g_out: wp.array(dtype=v12),  # [N] out (accumulated): d/d (mx, my, ca, cb, cc, o, f0..f4), 0
    ):
        tid = wp.tid()
        t = tile0 + tid // npix
        local = tid - (tid // npix) * npix
        x = (t - (t // tiles_x) * tiles_x) * tile + local - (local // tile) * tile
        y = (t // tiles_x) * tile + local // tile
        if x >= width or y >= height:
            return
        pix = y * width + x
        px = ft(x) + ft(0.5)
        py = ft(y) + ft(0.5)
        tf = t_final[pix]
        T = tf
        gT = g_t[pix]
        g = g_acc[pix]
        # features accumulated behind the current splat: S = sum_{j>i} f_j a_j T_j
        behind = vf()
        start = offsets[t]
        k = last[pix] - 1
        while k >= start:
            e = pk[k]
            s = ids[k]
            k -= 1
            dx = e[0] - px
            dy = e[1] - py
            ca = e[2]
            cb = e[3]
            cc = e[4]
            p = ft(-0.5) * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
            if p <= e[6]:
                continue
            live_p = ft(1.0)
            if p > ft(0.0):
                p = ft(0.0)
                live_p = ft(0.0)
            gauss = wp.exp(p)
            a_raw = e[5] * gauss
            clamped = ft(0.0)
            if a_raw > ft(ALPHA_MAX):
                a_raw = ft(ALPHA_MAX)
                clamped = ft(1.0)
            u = (a_raw - ft(ALPHA_MIN)) / ft(ALPHA_MIN)
            if u <= ft(0.0):
                continue
            taper = ft(1.0)
            dtaper = ft(1.0)
            if u < ft(1.0):
                taper = u * u * (ft(3.0) - ft(2.0) * u)
                dtaper = taper + a_raw * ft(6.0) * u * (ft(1.0) - u) / ft(ALPHA_MIN)
            a = a_raw * taper
            one_m = ft(1.0) - a
            T = T / one_m  # transmittance in front of this splat
            w = a * T
            f = feats[s]
            # d acc / d a = f T - S / (1 - a); d T_final / d a = -T_final / (1 - a)
            ga = wp.dot(g, f * T - behind / one_m) - gT * tf / one_m
            behind = behind + w * f
            g_raw = ga * dtaper * (ft(1.0) - clamped)
            gp = g_raw * a_raw * live_p
            gf = w * g
            # one vector atomic instead of eleven scalar ones (measured as fast or faster)
            wp.atomic_add(
                g_out,
                s,
                v12(
                    -gp * (ca * dx + cb * dy),
                    -gp * (cc * dy + cb * dx),
                    ft(-0.5) * gp * dx * dx,
                    -gp * dx * dy,
                    ft(-0.5) * gp * dy * dy,
                    g_raw * gauss,
                    gf[0],
                    gf[1],
                    gf[2],
                    gf[3],
                    gf[4],
                    ft(0.0),
                ),
            )

    # Load before any band threads launch, so they do not compile the module twice.
    wp.load_module(forward.module, device="cpu")
    wp.load_module(backward.module, device="cpu")
    return wp, forward, backward


@cache
def _bin_kernel():
    from motionphysics.runtime import init_warp

    wp = init_warp()

    @wp.kernel(enable_backward=False, module="unique")
    def bin_sequential(
        order: wp.array(dtype=wp.int32),  # [n] splat ids, front to back
        x0: wp.array(dtype=wp.int32),  # [n] tile ranges (inclusive) of their boxes, same order
        x1: wp.array(dtype=wp.int32),
        y0: wp.array(dtype=wp.int32),
        y1: wp.array(dtype=wp.int32),
        n: int,
        tiles_x: int,
        n_tiles: int,
        offsets: wp.array(dtype=wp.int32),  # [n_tiles + 1] out, zeroed
        cursor: wp.array(dtype=wp.int32),  # [n_tiles] scratch
        ids: wp.array(dtype=wp.int32),  # [<= box entries] out
    ):
        # One thread on purpose: visiting splats in depth order keeps every tile's list
        # front to back (a counting sort), whatever the launch order of threads would be.
        for i in range(n):
            for ty in range(y0[i], y1[i] + 1):
                for tx in range(x0[i], x1[i] + 1):
                    offsets[ty * tiles_x + tx + 1] += 1
        for t in range(n_tiles):
            offsets[t + 1] += offsets[t]
            cursor[t] = offsets[t]
        for i in range(n):
            s = order[i]
            for ty in range(y0[i], y1[i] + 1):
                for tx in range(x0[i], x1[i] + 1):
                    t = ty * tiles_x + tx
                    ids[cursor[t]] = s
                    cursor[t] += 1

    wp.load_module(bin_sequential.module, device="cpu")
    return wp, bin_sequential


def bin_tiles_warp(proj, width: int, height: int, tile: int):
    """The lists of ``rasterize.bin_tiles`` (int32 ``TileBins``) by a counting sort in Warp.

    (Also tried: listing a tile only when the splat's 1/255 ellipse reaches it, not just
    its box: 27% fewer entries at tile 4 but no faster overall, the test costing what
    the kernels saved.)
    """
    import math

    wp, kernel = _bin_kernel()
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    n_tiles = tiles_x * tiles_y
    with torch.no_grad():
        ext = proj.extents
        idx = torch.nonzero(ext[:, 0] > 0).squeeze(1)
        idx = idx[torch.argsort(proj.depths[idx], stable=True)]
        m2 = proj.means2d[idx]
        e = ext[idx]
        x0 = ((m2[:, 0] - e[:, 0]) / tile).floor().clamp(0, tiles_x - 1).int()
        x1 = ((m2[:, 0] + e[:, 0]) / tile).floor().clamp(0, tiles_x - 1).int()
        y0 = ((m2[:, 1] - e[:, 1]) / tile).floor().clamp(0, tiles_y - 1).int()
        y1 = ((m2[:, 1] + e[:, 1]) / tile).floor().clamp(0, tiles_y - 1).int()
        total = int(((x1 - x0 + 1).long() * (y1 - y0 + 1).long()).sum())
        offsets = torch.zeros(n_tiles + 1, dtype=torch.int32)
        if total == 0:
            return TileBins(torch.zeros(0, dtype=torch.int32), offsets, tiles_x, tiles_y, tile)
        ids = torch.empty(total, dtype=torch.int32)
        cursor = torch.empty(n_tiles, dtype=torch.int32)
        arrs = [wp.from_torch(a.contiguous()) for a in (idx.int(), x0, x1, y0, y1)]
        wp.launch(
            kernel,
            dim=1,
            inputs=[*arrs, idx.numel(), tiles_x, n_tiles],
            outputs=[wp.from_torch(offsets), wp.from_torch(cursor), wp.from_torch(ids)],
            device="cpu",
        )
    return TileBins(ids, offsets, tiles_x, tiles_y, tile)


def _threads() -> int:
    import torch as _t

    return max(1, min(_t.get_num_threads(), os.cpu_count() or 1))


def _bands(n_tiles: int, parts: int) -> list[tuple[int, int]]:
    parts = max(1, min(parts, n_tiles))
    edges = [round(i * n_tiles / parts) for i in range(parts + 1)]
    return [(edges[i], edges[i + 1]) for i in range(parts) if edges[i + 1] > edges[i]]


@cache
def _pool(workers: int) -> ThreadPoolExecutor:
    # Kept for the process: creating threads on every launch costs more than small renders.
    return ThreadPoolExecutor(workers, thread_name_prefix="mp-render")


def _run_bands(fn, bands):
    if len(bands) == 1:
        return [fn(*bands[0])]
    return list(_pool(len(bands)).map(lambda b: fn(*b), bands))


class _RasterWarp(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx,
        means2d,
        conics,
        opac,
        feats,
        ids,
        offsets,
        tiles_x,
        tiles_y,
        width,
        height,
        tile,
        bands=None,
    ):  # noqa: D102
        dtype = means2d.dtype
        wp, fwd, _ = _kernels(str(dtype).removeprefix("torch."), tile)
        n = means2d.shape[0]
        with torch.no_grad():
            op = opac.detach()
            pmin = torch.log(ALPHA_MIN / op.clamp_min(1e-30))
            pk = torch.cat(
                [
                    means2d.detach(),
                    conics.detach(),
                    op[:, None],
                    pmin[:, None],
                    torch.zeros_like(pmin[:, None]),
                ],
                -1,
            )[ids.long()].contiguous()  # [M, 8]
            ft = feats.detach().contiguous()
            # Warp arrays cannot be empty: pad (offsets keep the padding unread).
            if ids.numel() == 0:
                pk = torch.zeros(1, 8, dtype=dtype)
                ids = torch.zeros(1, dtype=torch.int32)
            if n == 0:
                ft = torch.zeros(1, C, dtype=dtype)
        acc = torch.zeros(height * width, C, dtype=dtype)
        t_out = torch.ones(height * width, dtype=dtype)
        last = torch.zeros(height * width, dtype=torch.int32)
        vf = wp.types.vector(C, wp.float64 if dtype == torch.float64 else wp.float32)
        v8 = wp.types.vector(8, wp.float64 if dtype == torch.float64 else wp.float32)
        wa = [
            wp.from_torch(pk, dtype=v8),
            wp.from_torch(ids),
            wp.from_torch(ft, dtype=vf),
            wp.from_torch(offsets),
        ]
        w_out = [wp.from_torch(acc, dtype=vf), wp.from_torch(t_out), wp.from_torch(last)]

        def band(t0, t1):
            wp.launch(
                fwd,
                dim=(t1 - t0) * tile * tile,
                inputs=[*wa, tiles_x, width, height, t0],
                outputs=w_out,
                device="cpu",
            )

        _run_bands(band, _bands(tiles_x * tiles_y, bands or _threads()))
        ctx.save_for_backward(pk, ids, ft, offsets, t_out, last)
        ctx.dims = (tiles_x, tiles_y, width, height, n, tile)
        return acc.reshape(height, width, C), t_out.reshape(height, width)

    @staticmethod
    def backward(ctx, g_acc, g_t, bands=None):  # noqa: D102
        pk, ids, ft, offsets, t_out, last = ctx.saved_tensors
        tiles_x, tiles_y, width, height, n, tile = ctx.dims
        dtype = pk.dtype
        if n == 0:
            z = torch.zeros(0, dtype=dtype)
            return (z.reshape(0, 2), z.reshape(0, 3), z, z.reshape(0, C), *([None] * 8))
        wp, _, bwd = _kernels(str(dtype).removeprefix("torch."), tile)
        g_acc = (
            torch.zeros(height * width, C, dtype=dtype)
            if g_acc is None
            else g_acc.contiguous().reshape(-1, C)
        )
        g_t = (
            torch.zeros(height * width, dtype=dtype)
            if g_t is None
            else g_t.contiguous().reshape(-1)
        )
        vf = wp.types.vector(C, wp.float64 if dtype == torch.float64 else wp.float32)
        v8 = wp.types.vector(8, wp.float64 if dtype == torch.float64 else wp.float32)
        wa = [
            wp.from_torch(pk, dtype=v8),
            wp.from_torch(ids),
            wp.from_torch(ft, dtype=vf),
            wp.from_torch(offsets),
        ]
        wb = [
            wp.from_torch(t_out),
            wp.from_torch(last),
            wp.from_torch(g_acc, dtype=vf),
            wp.from_torch(g_t),
        ]

        v12 = wp.types.vector(12, wp.float64 if dtype == torch.float64 else wp.float32)

        def band(t0, t1):
            out = torch.zeros(n, 12, dtype=dtype)
            wp.launch(
                bwd,
                dim=(t1 - t0) * tile * tile,
                inputs=[*wa, tiles_x, width, height, t0, *wb],
                outputs=[wp.from_torch(out, dtype=v12)],
                device="cpu",
            )
            return out

        parts = _run_bands(band, _bands(tiles_x * tiles_y, bands or _threads()))
        g = parts[0] if len(parts) == 1 else sum(parts)
        return (
            g[:, 0:2],
            g[:, 2:5],
            g[:, 5],
            g[:, 6:11],
            None,
            None,
            None,
            None,
            None,
            None,
            None,
            None,
        )


_single_thread = single_thread
"""The renderer's torch work is many small ops: one thread (the Warp kernels use their own
bands)."""


class _RenderWarp(torch.autograd.Function):
    """Whole CPU render (projection, binning, kernels, background) as one autograd node.

    Forward runs without a graph; backward recomputes the cheap torch parts with
    autograd around the hand-written kernel backward, all on one torch thread.
    """

    @staticmethod
    def forward(ctx, means, covs, colors, opacities, camera, background, tile):  # noqa: D102
        with _single_thread() as n_threads, torch.no_grad():
            proj = project_gaussians(means, covs, opacities, camera)
            bins = bin_tiles_warp(proj, camera.width, camera.height, tile)
            feats = features(colors, proj.depths)
            acc, t_final = _RasterWarp.forward(
                ctx,
                proj.means2d,
                proj.conics,
                opacities,
                feats,
                *_ids_offsets(bins),
                bins.tiles_x,
                bins.tiles_y,
                camera.width,
                camera.height,
                tile,
                bands=n_threads,
            )
            out = finish(acc, t_final, background)
        ctx.render = (camera, background, acc, t_final, n_threads)
        ctx.inputs = (means, covs, colors, opacities)
        return out.rgb, out.alpha, out.depth

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_depth):  # noqa: D102
        camera, background, acc, t_final, n_threads = ctx.render
        with _single_thread(), torch.enable_grad():
            acc_ = acc.detach().requires_grad_()
            t_ = t_final.detach().requires_grad_()
            out = finish(acc_, t_, background)
            pairs = [
                (o, g)
                for o, g in zip(
                    (out.rgb, out.alpha, out.depth), (g_rgb, g_alpha, g_depth), strict=True
                )
                if g is not None
            ]
            g_acc, g_t = torch.autograd.grad(
                [o for o, _ in pairs], (acc_, t_), [g for _, g in pairs], allow_unused=True
            )
            g_m2, g_con, g_op, g_feats = _RasterWarp.backward(ctx, g_acc, g_t, bands=n_threads)[:4]
            leaves = [
                t.detach().requires_grad_(need)
                for t, need in zip(ctx.inputs, ctx.needs_input_grad[:4], strict=True)
            ]
            means, covs, colors, opacities = leaves
            proj = project_gaussians(means, covs, opacities, camera)
            feats = features(colors, proj.depths)
            outs = [proj.means2d, proj.conics, feats]
            gouts = [g_m2, g_con, g_feats]
            if opacities.requires_grad:
                outs.append(opacities)
                gouts.append(g_op)
            need = [t for t in leaves if t.requires_grad]
            grads = torch.autograd.grad(outs, need, gouts, allow_unused=True) if need else []
        it = iter(grads)
        full = [next(it) if t.requires_grad else None for t in leaves]
        full = [
            torch.zeros_like(t) if (g is None and t.requires_grad) else g
            for g, t in zip(full, leaves, strict=True)
        ]
        return (*full, None, None, None)


def _ids_offsets(bins):
    return bins.ids.to(torch.int32).contiguous(), bins.offsets.to(torch.int32).contiguous()


def rasterize_warp(means, covs, colors, opacities, camera, background, tile: int):
    """CPU render through the Warp kernels; returns ``(rgb [H,W,3], alpha [H,W], depth [H,W])``."""
    dtype = means.dtype
    return _RenderWarp.apply(
        means, covs.to(dtype), colors.to(dtype), opacities.to(dtype), camera, background, tile
    )
