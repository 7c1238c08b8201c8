"""The splats of one frame, deformed exactly as the renderer deforms them.

:class:`FrameSource` turns a :class:`~motionphysics.viewer.rundata.RunData` and a
frame index into what the browser draws: centres, covariances ``F Σ Fᵀ``, colours
(SH evaluated along the rest-frame view direction ``Rᵀ d``) and opacities. It calls
:func:`motionphysics.render.deform.deform_splats`, the function the video is rendered
with, so the viewer shows what the video shows; it does not re-implement it.

A frame is computed when it is asked for and a few recent ones are kept (LRU); no
code path holds every frame. Runs with more than ``max_splats`` splats are
subsampled to a fixed, seeded subset (the same splats in every frame) so a frame
stays a few megabytes on the wire.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

__all__ = ["Frame", "FrameSource", "DEFAULT_MAX_SPLATS", "LARGE_RUN_SPLAT_FRAMES", "is_large"]

DEFAULT_MAX_SPLATS = 300_000
"""Splats sent to the browser per frame before subsampling (~10 MB per frame at 32 B each)."""
LARGE_RUN_SPLAT_FRAMES = 100_000 * 100
"""Splats x frames from which a run counts as large (said on stdout and in the panel)."""
CACHE_BYTES = 128 * 2**20
"""Memory the cache of computed frames may hold (a frame is 64 bytes per splat)."""


def is_large(num_splats: int, num_frames: int) -> bool:
    return num_splats * num_frames >= LARGE_RUN_SPLAT_FRAMES


@dataclass(frozen=True)
class Frame:
    """One frame as served (float32 numpy; M splats, M <= N after subsampling).

    Attributes:
        index: the frame index k.
        means: ``[M, 3]`` centres [m].
        covs: ``[M, 3, 3]`` covariances [m²].
        colors: ``[M, 3]`` RGB in [0, 1] (clamped as the renderer's composite is).
        opacities: ``[M, 1]`` in (0, 1).
    """

    index: int
    means: np.ndarray
    covs: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray


def _static_arrays(static, camera):
    """(means [S, 3], covs [S, 3, 3], colours [S, 3], opacities [S, 1]) float32 of the
    static splats of a region run as the video draws them, or None."""
    if static is None or static.num == 0:
        return None
    import torch

    from motionphysics.render.sh import sh_to_rgb

    with torch.no_grad():
        means = static.means.float()
        colors = sh_to_rgb(static.sh.float(), means - camera.position.to(means)).clamp(0, 1)
        return (
            means.numpy(),
            static.covariances().float().numpy(),
            colors.numpy(),
            static.opacities.float().numpy()[:, None],
        )


class FrameSource:
    """Deformed splats of a run, one frame at a time.

    Args:
        run: the run.
        camera: :class:`~motionphysics.render.camera.Camera` whose centre gives the
            view direction of view-dependent colour (the run's camera: the colours of
            the video).
        max_splats: subsample to this many splats (None: never).
        cache: frames kept at most (fewer when they would exceed ``CACHE_BYTES``).
        seed: of the subsample.
    """

    def __init__(
        self,
        run,
        camera,
        max_splats: int | None = DEFAULT_MAX_SPLATS,
        cache: int = 8,
        seed: int = 0,
    ):
        import torch

        self.run = run
        self.camera = camera
        n = run.num_splats
        if max_splats is not None and n > max_splats:
            rng = np.random.default_rng(seed)
            self.indices = np.sort(rng.choice(n, size=int(max_splats), replace=False))
        else:
            self.indices = None
        sel = slice(None) if self.indices is None else self.indices
        self._splats = run.splats.subset(
            sel if self.indices is None else torch.from_numpy(self.indices)
        )
        self._parent = torch.from_numpy(np.ascontiguousarray(run.parent[sel]))
        self._offset = torch.from_numpy(np.ascontiguousarray(run.offset[sel]))
        # Only the particles some shown splat follows are read from the trajectory.
        used, inverse = np.unique(self._parent.numpy(), return_inverse=True)
        self._used = used
        self._local_parent = torch.from_numpy(inverse.astype(np.int64))
        self._opacities = self._splats.opacities.detach().numpy().astype(np.float32)[:, None]
        self._static = _static_arrays(getattr(run, "static", None), camera)
        self._cache: OrderedDict[int, Frame] = OrderedDict()
        frame_bytes = 64 * max(self._splats.num, 1)  # means, covs, colours, opacity: float32
        self._cache_size = max(1, min(int(cache), CACHE_BYTES // frame_bytes))
        self._lock = threading.Lock()

    @property
    def num_shown(self) -> int:
        """Splats per served frame."""
        return self._splats.num

    @property
    def subsampled(self) -> bool:
        return self.indices is not None

    def frame(self, k: int) -> Frame:
        """Frame ``k`` (0 <= k < T); computed on demand, cached."""
        import torch

        from motionphysics.render.deform import deform_splats

        k = int(k)
        if not 0 <= k < self.run.num_frames:
            raise IndexError(f"frame {k} outside 0..{self.run.num_frames - 1}")
        with self._lock:
            hit = self._cache.get(k)
            if hit is not None:
                self._cache.move_to_end(k)
                return hit
            # Reading x[k][used] touches one frame of the memory map only.
            x = torch.from_numpy(np.ascontiguousarray(self.run.x[k][self._used], np.float32))
            F = torch.from_numpy(np.ascontiguousarray(self.run.F[k][self._used], np.float32))
            with torch.no_grad():
                means, covs, colors = deform_splats(
                    self._splats, x, F, self._local_parent, self._offset, self.camera
                )
            parts = [
                means.numpy().astype(np.float32, copy=False),
                covs.numpy().astype(np.float32, copy=False),
                colors.clamp(0.0, 1.0).numpy().astype(np.float32, copy=False),
                self._opacities,
            ]
            if self._static is not None:  # a region run: the static scene, unchanged
                parts = [np.concatenate([a, b]) for a, b in zip(parts, self._static, strict=True)]
            out = Frame(k, *parts)
            self._cache[k] = out
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
            return out
