"""Physical diagnostics of a simulated trajectory (what ``metrics.json`` holds).

Everything here is computed from ``trajectory.npz`` alone (positions per frame, the
volume ratio det F, particle masses, gravity), so ``motionphysics eval RUN_DIR`` can
recompute it for any finished run:

- kinetic energy per frame, from the simulated particle velocities ``v`` when the
  trajectory holds them, else from central differences of the positions [J];
- gravitational potential energy per frame relative to frame 0 [J];
- volume ratio det F per frame (mean, min, max) and overall;
- displacement per frame (mean and max distance from the rest position) [m];
- final height over initial height (extent along the up axis) and spread (RMS
  horizontal distance from the centroid, final over initial);
- centroid height per frame; the rebound ratio (rise of the centroid after its lowest
  point over the fall before it: ~0 for a splat or a dent, larger for a bounce); and
  the dominant oscillation frequency and damping of the object's height signal.

Up is the direction opposite to gravity (+z when gravity is zero). The statistics
use all simulated particles, interior fill included (they carry the mass).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["physical_metrics", "velocities", "oscillation", "up_axis"]


def up_axis(gravity: np.ndarray | None) -> np.ndarray:
    """Unit vector opposite to gravity [3]; +z when gravity is absent or zero."""
    if gravity is None:
        return np.array([0.0, 0.0, 1.0])
    g = np.asarray(gravity, dtype=np.float64).reshape(3)
    n = np.linalg.norm(g)
    return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])


def velocities(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Particle velocities [T, P, 3] m/s from positions ``x`` [T, P, 3] m at times ``t`` [T] s.

    Central differences inside, one-sided at the ends; zeros for a single frame.
    """
    x = np.asarray(x, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if x.shape[0] < 2:
        return np.zeros_like(x)
    return np.gradient(x, t, axis=0)


def oscillation(signal: np.ndarray, dt: float) -> dict[str, float | None]:
    """Dominant frequency [Hz] and damping of a 1-D signal sampled every ``dt`` s.

    The signal is detrended (linear fit removed); the frequency is the peak of its
    Hann-windowed spectrum (excluding DC). Damping is the mean logarithmic decrement
    of successive positive peaks converted to a damping ratio
    ``zeta = delta / sqrt(4 pi^2 + delta^2)``; ``None`` when fewer than two peaks.
    Returns ``{"frequency_hz", "damping_ratio", "amplitude"}`` (amplitude: half the
    peak-to-peak of the detrended signal, in the signal's unit).
    """
    y = np.asarray(signal, dtype=np.float64)
    n = y.size
    out: dict[str, float | None] = {"frequency_hz": None, "damping_ratio": None, "amplitude": 0.0}
    if n < 4 or not np.all(np.isfinite(y)):
        return out
    tt = np.arange(n) * dt
    coef = np.polyfit(tt, y, 1)
    r = y - np.polyval(coef, tt)
    amp = 0.5 * float(r.max() - r.min())
    out["amplitude"] = amp
    if amp <= 1e-9 * max(1.0, float(np.abs(y).max())):
        return out
    spec = np.abs(np.fft.rfft(r * np.hanning(n)))
    freqs = np.fft.rfftfreq(n, dt)
    k = int(np.argmax(spec[1:]) + 1) if spec.size > 1 else 0
    out["frequency_hz"] = float(freqs[k]) if k > 0 else None
    peaks = [i for i in range(1, n - 1) if r[i] > r[i - 1] and r[i] >= r[i + 1] and r[i] > 0]
    if len(peaks) >= 2:
        vals = np.array([r[i] for i in peaks])
        ratios = vals[:-1] / np.maximum(vals[1:], 1e-12)
        ratios = ratios[ratios > 0]
        if ratios.size:
            delta = float(np.mean(np.log(ratios)))
            out["damping_ratio"] = delta / math.sqrt(4 * math.pi**2 + delta**2)
    return out


def _extent(p: np.ndarray, axis: np.ndarray) -> float:
    """Robust extent of points ``p`` [P, 3] along ``axis`` [3]: 99.5th - 0.5th percentile [m]."""
    h = p @ axis
    lo, hi = np.percentile(h, [0.5, 99.5])
    return float(hi - lo)


def _spread(p: np.ndarray, axis: np.ndarray, w: np.ndarray) -> float:
    """RMS distance [m] of points ``p`` [P, 3] from their weighted centroid, perpendicular to ``axis``."""
    c = (w[:, None] * p).sum(0) / w.sum()
    d = p - c
    d = d - (d @ axis)[:, None] * axis[None, :]
    return float(np.sqrt((w * (d * d).sum(1)).sum() / w.sum()))


def physical_metrics(traj: dict[str, np.ndarray]) -> dict[str, Any]:
    """Diagnostics of one trajectory (the ``physical`` block of ``metrics.json``).

    ``traj`` holds ``x [T, P, 3]`` m and ``t [T]`` s, and optionally ``v [T, P, 3]`` m/s,
    ``det_F [T, P]``,
    ``mass [P]`` kg (default: equal masses summing to 1 kg, energies then per kg) and
    ``gravity [3]`` m/s^2 (default ``[0, 0, -9.8]``).
    """
    x = np.asarray(traj["x"], dtype=np.float64)
    t = np.asarray(traj["t"], dtype=np.float64)
    T, P, _ = x.shape
    if "mass" in traj:
        m = np.asarray(traj["mass"], dtype=np.float64).reshape(P)
        mass_note = "kg"
    else:
        m = np.full(P, 1.0 / P)
        mass_note = "unit total mass (no 'mass' in the trajectory): energies are per kg"
    g = np.asarray(traj.get("gravity", (0.0, 0.0, -9.8)), dtype=np.float64).reshape(3)
    up = up_axis(g)

    if "v" in traj:
        v = np.asarray(traj["v"], dtype=np.float64).reshape(T, P, 3)
        v_note = "simulated particle velocities"
    else:
        v = velocities(x, t)
        v_note = "central differences of positions"
    ke = 0.5 * (m[None, :] * (v * v).sum(-1)).sum(1)  # [T] J
    pe = -((m[None, :, None] * (x - x[:1])) @ g).sum(1)  # [T] J, relative to frame 0
    disp = np.linalg.norm(x - x[:1], axis=-1)  # [T, P] m
    com = (m[None, :, None] * x).sum(1) / m.sum()  # [T, 3] m
    com_h = com @ up  # [T] m
    heights = np.array([_extent(x[i], up) for i in range(T)])
    spreads = np.array([_spread(x[i], up, m) for i in range(T)])
    h0 = max(heights[0], 1e-9)
    s0 = max(spreads[0], 1e-9)
    dt = float(t[1] - t[0]) if T > 1 else 1.0

    # Rebound: how far the centroid rises again after its lowest point, relative to the
    # fall before it (0: stays down / no fall; ~1: an ideal bounce back to the start).
    k = int(np.argmin(com_h))
    fall = float(com_h[0] - com_h[k])
    rise = float(com_h[k:].max() - com_h[k]) if k < T - 1 else 0.0
    # the lowest point must be a real contact, not the last frame of a fall
    rebound = rise / fall if fall > 1e-6 else 0.0

    out: dict[str, Any] = {
        "frames": int(T),
        "particles": int(P),
        "duration_s": float(t[-1] - t[0]) if T > 1 else 0.0,
        "mass_unit": mass_note,
        "velocity_source": v_note,
        "total_mass": float(m.sum()),
        "up_axis": up.tolist(),
        "kinetic_energy": ke.tolist(),
        "potential_energy": pe.tolist(),
        "total_energy": (ke + pe).tolist(),
        "max_kinetic_energy": float(ke.max()),
        "final_kinetic_energy": float(ke[-1]),
        "displacement_mean": disp.mean(1).tolist(),
        "displacement_max": disp.max(1).tolist(),
        "final_displacement_mean": float(disp[-1].mean()),
        "max_displacement": float(disp.max()),
        "centroid_height": com_h.tolist(),
        "centroid_drop": float(com_h[0] - com_h[-1]),
        "rebound_ratio": float(rebound),
        "height": heights.tolist(),
        "initial_height": float(heights[0]),
        "final_height": float(heights[-1]),
        "final_height_ratio": float(heights[-1] / h0),
        "min_height_ratio": float(heights.min() / h0),
        "spread": spreads.tolist(),
        "spread_ratio": float(spreads[-1] / s0),
        "max_spread_ratio": float(spreads.max() / s0),
        "max_speed": float(np.linalg.norm(v, axis=-1).max()),
        "height_oscillation": oscillation(heights, dt),
        "centroid_oscillation": oscillation(com_h, dt),
    }
    if "det_F" in traj:
        J = np.asarray(traj["det_F"], dtype=np.float64).reshape(T, P)
        out["volume_ratio"] = {
            "mean": J.mean(1).tolist(),
            "min": J.min(1).tolist(),
            "max": J.max(1).tolist(),
            "overall_min": float(J.min()),
            "overall_max": float(J.max()),
            "final_mean": float(J[-1].mean()),
            "max_abs_deviation": float(np.abs(J - 1.0).max()),
        }
    return out
