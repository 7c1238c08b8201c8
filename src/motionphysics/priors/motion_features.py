"""What the motion prior sees: per-frame features of the simulated particles.

Every feature is a differentiable torch function of the particle positions ``x``
``[T, P, 3]`` [m] and deformation gradients ``F`` ``[T, P, 3, 3]`` of the observed
frames, the rest state ``x0`` ``[P, 3]`` [m] (frame 0: the state before anything moved),
the ground height [m] and the gravity vector [m/s^2]. None reads a colour, a texture
or a splat: recolouring a scene cannot change them. Object size and placement are
normalised out: lengths are over the object's size ``L`` (the largest side of the rest
state's bounding box, m) or over their rest value, positions relative to the rest
centroid and the ground, and horizontal directions enter only through magnitudes.

"Up" is ``-gravity / |gravity|`` (``+z`` when gravity is off); "horizontal" is the plane
orthogonal to it. ``c`` is the centroid (unweighted mean of the particles), ``h(c)`` its
height above the ground. Channels (all dimensionless):

=====  ===============  =============================================================
index  name             meaning
=====  ===============  =============================================================
0      height           h(c) / h(c0): centroid height above the ground over its rest
                        value (1 at rest, falls to ~0.5 on landing, rises on a bounce)
1      height_size      h(c) / L: centroid height over the object size (about 0.5
                        when a compact object rests on the ground, ~0 for a puddle)
2      bottom           h(lowest 10 % of particles, mean) / L: clearance of the
                        underside (0 = touching the ground)
3      drift            |horizontal displacement of c| / L
4      vertical         log(sigma_up / sigma_up0): the rms vertical extent about the
                        centroid over its rest value (< 0: flattened)
5      spread           log(r_h / r_h0): the rms horizontal radius about the centroid
                        over its rest value (> 0: spread out)
6      size             0.5 log(tr C / tr C0): overall extent (C: positional covariance)
7      shape            log(0.003 + d / L), d the rms distance of the particles from
                        the best rigid motion of the rest state (Kabsch, via a polar
                        decomposition): rotation-invariant shape change, on a log scale
                        so that the 1-5 % changes separating a rigid from a wobbly
                        landing are as visible as a splash's 100 %
8      strain           log(0.003 + e), e the mean over particles of ||F^T F - I||_F
                        (elastic strain, log scale as ``shape``)
9      volume           mean over particles of log det F (volume change)
10     time             log(1 + t sqrt(g0 / L)): the frame's time in units of the
                        object's free-fall time scale (g0 = 9.8 m/s^2, so it is
                        defined with gravity off)
11     gravity          |g| / g0 (constant over a clip)
12     rebound          (h(c) - m) / max(h(c0) - m, 0.05 L), m the lowest centroid
                        height so far: how far the centroid has risen again since its
                        lowest point, over the fall before it
13     peak_deform      log(0.003 + max over the frames so far of D / L), D the mean
                        distance of the particles from the best rigid motion of the
                        rest state (the captions' ``max_deform``; ``shape`` is the rms
                        distance at this frame)
14     low_vertical     the smallest ``vertical`` so far (how flat it got at its
                        flattest: the captions' ``min_height``)
15     peak_spread      the largest ``spread`` so far (the captions' ``max_spread``)
16     speed            log(0.003 + u / sqrt(g0 L)), u the mean particle speed between
                        this observed frame and the one before [m/s] (the first frame:
                        between it and the next); the Froude speed of the captions'
                        ``late_speed``
17     impact_rebound   the rebound ratio of the frames so far measured as
                        ``metrics.physical`` measures it: from the FIRST impact (the
                        first local minimum of h(c) at least half as deep below the
                        highest point before it as the deepest point so far), its
                        largest rise after it over the fall before it; 0 while no
                        fall of 3 % of the rest vertical extent was seen (the
                        captions' ``rebound``; piecewise in the choice of the impact
                        frame, differentiable in the heights)
18     wobbles          how many times the deformation D / L has reversed by more than
                        0.008 since it first exceeded 0.005 (the captions' ``wobble``
                        count; a step function: no gradient)
=====  ===============  =============================================================

Channels 13-18 (``FEATURES_VERSION`` 3) carry each measure the captions are written from
(``motion_data.motion_measures``) as its value over the frames seen so far, so the last
frame reads the measure itself: a classifier of the motion group needs no more than
the features (channels 0-12 alone held the running value, not the peaks the caption
rules threshold). A prior keeps the channels it was trained on (its checkpoint names
them): a 13-channel prior reads channels 0-12.

:func:`clip_features` turns the observed frames at arbitrary times (the supervised
frames of a run, or a training clip's frames) into the prior's fixed grid: the rest
frame is put first (time 0), and every channel is linearly interpolated onto
``num_frames`` uniform times from 0 to the last observed time.

This module imports only torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = [
    "FEATURE_NAMES",
    "G0",
    "NUM_FEATURES",
    "MotionScene",
    "clip_features",
    "frame_features",
    "polar_rotation",
]

FEATURE_NAMES = (
    "height",
    "height_size",
    "bottom",
    "drift",
    "vertical",
    "spread",
    "size",
    "shape",
    "strain",
    "volume",
    "time",
    "gravity",
    "rebound",
    "peak_deform",
    "low_vertical",
    "peak_spread",
    "speed",
    "impact_rebound",
    "wobbles",
)
NUM_FEATURES = len(FEATURE_NAMES)
G0 = 9.8
"""[m/s^2] The reference gravity of the time channel."""
_LOW_SHARE = 0.1
"""Share of the particles whose mean height is the underside (``bottom``)."""
LOG_FLOOR = 0.003
"""The floor of the log-scaled ``shape``, ``strain``, ``peak_deform`` and ``speed``
channels."""
VISIBLE_RISE = 0.03
"""``impact_rebound`` counts a fall only over this share of the rest vertical extent
(``metrics.physical.VISIBLE_RISE``)."""
WOBBLE_ON = 0.005
WOBBLE_SWING = 0.008
"""``wobbles``: reversals counted after D / L first exceeds ``WOBBLE_ON``, each a swing
over ``WOBBLE_SWING`` (``motion_data.motion_measures``)."""


@dataclass(frozen=True)
class MotionScene:
    """What the features are measured against (fixed for a run or a clip)."""

    rest: Tensor
    """[P, 3] rest positions x0 [m] (frame 0)."""
    ground: float | None
    """Height of the ground along "up" [m]; None: no ground (the rest state's lowest
    point is used as the reference height)."""
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.8)
    """[m/s^2]."""

    @property
    def up(self) -> Tensor:
        g = torch.tensor(self.gravity, dtype=torch.float64)
        n = float(g.norm())
        return -g / n if n > 0 else torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)

    @property
    def g(self) -> float:
        return float(math.sqrt(sum(float(v) ** 2 for v in self.gravity)))


def polar_rotation(M: Tensor, iterations: int = 14) -> Tensor:
    """The orthogonal polar factor of ``M`` [..., 3, 3] (Newton: R <- (R + R^-T) / 2),
    differentiable and defined for repeated singular values (where SVD's gradient is
    not). ``M`` should be invertible (1e-12 I is added against an exactly singular one)."""
    eye = torch.eye(3, dtype=M.dtype, device=M.device)
    scale = M.flatten(-2).norm(dim=-1).clamp_min(1e-30)[..., None, None]
    R = M / scale + 1e-12 * eye
    for _ in range(iterations):
        R = 0.5 * (R + torch.linalg.inv(R).transpose(-1, -2))
    return R


def _height(x: Tensor, up: Tensor) -> Tensor:
    return (x * up).sum(-1)


def frame_features(x: Tensor, F: Tensor, times: Tensor, scene: MotionScene) -> Tensor:
    """[T, NUM_FEATURES] features of frames ``x`` [T, P, 3], ``F`` [T, P, 3, 3] at
    ``times`` [T] s (see the module docstring for each channel). Differentiable in
    ``x`` and ``F``; computed in the dtype of ``x``."""
    dt = x.dtype
    rest = scene.rest.to(x.device, dt)
    up = scene.up.to(x.device, dt)
    P = rest.shape[0]
    L = float((rest.max(0).values - rest.min(0).values).max().clamp_min(1e-9))
    h_rest = _height(rest, up)
    ground = float(h_rest.min()) if scene.ground is None else float(scene.ground)
    c0 = rest.mean(0)
    a = rest - c0
    a_up = (a * up).sum(-1)
    a_h = a - a_up[:, None] * up
    sig_up0 = a_up.pow(2).mean().sqrt().clamp_min(1e-3 * L)
    r_h0 = a_h.pow(2).sum(-1).mean().sqrt().clamp_min(1e-3 * L)
    tr0 = a.pow(2).sum(-1).mean()
    h_c0 = max(float(c0 @ up) - ground, 0.05 * L)

    c = x.mean(1)  # [T, 3]
    h_c = (c * up).sum(-1) - ground
    d = x - c[:, None]
    d_up = (d * up).sum(-1)  # [T, P]
    d_h = d - d_up[..., None] * up
    k = max(1, int(round(_LOW_SHARE * P)))
    low = -torch.topk(-_height(x, up), k, dim=1).values.mean(1)  # mean of the lowest k
    disp = c - c0
    disp_h = disp - (disp * up).sum(-1, keepdim=True) * up
    eps = 1e-4
    drift = (disp_h.pow(2).sum(-1) / L**2 + eps**2).sqrt() - eps
    sig_up = (d_up.pow(2).mean(1) + (1e-6 * L) ** 2).sqrt()
    r_h = (d_h.pow(2).sum(-1).mean(1) + (1e-6 * L) ** 2).sqrt()
    tr = d.pow(2).sum(-1).mean(1)
    # best rigid motion of the rest state: R = polar(sum_p d_p a_p^T)
    M = torch.einsum("tpi,pj->tij", d, a) / P
    R = polar_rotation(M)
    resid2 = tr + tr0 - 2.0 * (R * M).sum((-1, -2))
    shape = (resid2.clamp_min(0.0) / L**2 + eps**2).sqrt() - eps
    C = F.transpose(-1, -2) @ F - torch.eye(3, dtype=F.dtype, device=F.device)
    strain = (C.pow(2).sum((-1, -2)) + 1e-12).sqrt().mean(1).to(dt)
    volume = torch.linalg.det(F).clamp_min(1e-6).log().mean(1).to(dt)
    tt = torch.as_tensor(times, dtype=dt, device=x.device)
    time_ch = torch.log1p(tt * math.sqrt(G0 / L))
    grav = torch.full_like(tt, scene.g / G0)
    lowest = torch.cummin(h_c, dim=0).values
    h_rest = float(c0 @ up) - ground
    rebound = (h_c - lowest) / torch.clamp(h_rest - lowest, min=0.05 * L)
    # the captions' measures over the frames so far (channels 13-18)
    fit = torch.einsum("tij,pj->tpi", R, a)
    D = ((d - fit).pow(2).sum(-1) + (1e-9 * L) ** 2).sqrt().mean(1) / L
    peak_deform = torch.log(LOG_FLOOR + torch.cummax(D, dim=0).values)
    vertical = torch.log(sig_up / sig_up0)
    spread = torch.log(r_h / r_h0)
    step = (x[1:] - x[:-1]).pow(2).sum(-1).add(1e-18).sqrt().mean(1)
    gap = (tt[1:] - tt[:-1]).clamp_min(1e-9)
    if step.numel():
        u = torch.cat([step[:1] / gap[:1], step / gap]) / math.sqrt(G0 * L)
    else:
        u = torch.zeros_like(h_c)
    hr = (rest * up).sum(-1)
    visible = VISIBLE_RISE * float(
        torch.quantile(hr.double(), 0.995) - torch.quantile(hr.double(), 0.005)
    )
    return torch.stack(
        [
            h_c / h_c0,
            h_c / L,
            (low - ground) / L,
            drift,
            vertical,
            spread,
            0.5 * torch.log(tr / tr0.clamp_min(1e-12 * L**2)),
            torch.log(LOG_FLOOR + shape),
            torch.log(LOG_FLOOR + strain),
            volume,
            time_ch,
            grav,
            rebound,
            peak_deform,
            torch.cummin(vertical, dim=0).values,
            torch.cummax(spread, dim=0).values,
            torch.log(LOG_FLOOR + u),
            impact_rebound(h_c, visible),
            wobble_count(D).to(dt),
        ],
        dim=-1,
    )


def _first_impact(h: list[float], visible: float) -> int:
    """Frame of the first impact of the heights ``h`` (``metrics.physical.first_impact``)."""
    peak, depth = [], []
    top = -math.inf
    for v in h:
        top = max(top, v)
        peak.append(top)
        depth.append(top - v)
    need = 0.5 * max(depth)
    k = max(range(len(h)), key=lambda i: depth[i])
    for i in range(1, len(h) - 1):
        if h[i] < h[i - 1] and h[i] <= h[i + 1] and depth[i] >= need and depth[i] > 0:
            if max(h[i:]) - h[i] >= visible:
                return i
    return k


def impact_rebound(h: Tensor, visible: float) -> Tensor:
    """[T] the rebound ratio of ``h[:j + 1]`` for every j (see channel 17): the largest
    rise after the first impact over the fall before it, 0 where that fall is at most
    ``visible`` [m]. The impact frame is chosen on the values; the ratio is
    differentiable in ``h``."""
    vals = [float(v) for v in h.detach().cpu()]
    out: list[Tensor] = []
    for j in range(len(vals)):
        k = _first_impact(vals[: j + 1], visible)
        top = h[: k + 1].max()
        fall = top - h[k]
        if float(fall.detach()) <= max(visible, 1e-6) or k >= j:
            out.append(h[j] * 0.0)
            continue
        out.append((h[k : j + 1].max() - h[k]) / fall)
    return torch.stack(out)


def wobble_count(D: Tensor) -> Tensor:
    """[T] reversals so far of the deformation series ``D`` [T] (channel 18)."""
    vals = [float(v) for v in D.detach().cpu()]
    counts = [0.0] * len(vals)
    on = next((i for i, v in enumerate(vals) if v > WOBBLE_ON), None)
    if on is not None:
        wob, last, direction = 0, vals[on], 0
        for i in range(on + 1, len(vals)):
            val = vals[i]
            if direction >= 0 and val < last - WOBBLE_SWING:
                wob += direction > 0
                direction, last = -1, val
            elif direction <= 0 and val > last + WOBBLE_SWING:
                wob += direction < 0
                direction, last = 1, val
            elif (direction >= 0 and val > last) or (direction <= 0 and val < last):
                last = val
            counts[i] = float(wob)
    return torch.tensor(counts, dtype=D.dtype, device=D.device)


def resample(values: Tensor, times: Tensor, num_frames: int) -> Tensor:
    """[S, C] values at ascending ``times`` [S] -> [num_frames, C] at ``num_frames``
    uniform times from ``times[0]`` to ``times[-1]`` (linear, differentiable)."""
    t = torch.as_tensor(times, dtype=torch.float64)
    if t.numel() == 1:
        return values.expand(num_frames, -1)
    grid = torch.linspace(float(t[0]), float(t[-1]), num_frames, dtype=torch.float64)
    j = torch.searchsorted(t, grid, right=True).clamp(1, t.numel() - 1)
    t0, t1 = t[j - 1], t[j]
    w = ((grid - t0) / (t1 - t0).clamp_min(1e-12)).clamp(0.0, 1.0).to(values.dtype)
    return values[j - 1] * (1 - w[:, None]) + values[j] * w[:, None]


def clip_features(
    x: Tensor,
    F: Tensor,
    times: Sequence[float] | Tensor,
    scene: MotionScene,
    num_frames: int = 16,
) -> Tensor:
    """[num_frames, NUM_FEATURES] features on the prior's grid.

    ``x`` [S, P, 3], ``F`` [S, P, 3, 3]: the observed frames at ``times`` [S] s (> 0,
    ascending); the rest frame (``scene.rest``, F = I) is put first at time 0, and the
    features are interpolated onto ``num_frames`` uniform times over [0, times[-1]]."""
    dt = x.dtype
    tt = torch.as_tensor(times, dtype=torch.float64).reshape(-1)
    if tt.numel() != x.shape[0]:
        raise ValueError(f"{x.shape[0]} frames but {tt.numel()} times")
    rest = scene.rest.to(x.device, dt)[None]
    eye = torch.eye(3, dtype=F.dtype, device=F.device).expand(1, rest.shape[1], 3, 3)
    if float(tt[0]) > 0:
        x = torch.cat([rest, x])
        F = torch.cat([eye, F])
        tt = torch.cat([torch.zeros(1, dtype=torch.float64), tt])
    feats = resample(frame_features(x, F, tt.to(dt), scene), tt, num_frames)
    # the time channel on the grid itself (interpolating its log would bend it)
    L = float((scene.rest.max(0).values - scene.rest.min(0).values).max().clamp_min(1e-9))
    grid = torch.linspace(0.0, float(tt[-1]), num_frames, dtype=torch.float64)
    time_ch = torch.log1p(grid * math.sqrt(G0 / L)).to(feats)
    i = FEATURE_NAMES.index("time")
    return torch.cat([feats[:, :i], time_ch[:, None], feats[:, i + 1 :]], dim=1)
