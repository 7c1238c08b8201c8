"""Physical diagnostics of a simulated trajectory (what ``metrics.json`` holds).

Everything here is computed from ``trajectory.npz`` alone (positions per frame, the
volume ratio det F, particle masses, gravity), so ``motionphysics eval RUN_DIR`` can
recompute it for any finished run:

- kinetic energy per frame, from the simulated particle velocities ``v`` when the
  trajectory holds them, else from central differences of the positions [J];
- gravitational potential energy per frame relative to frame 0 [J];
- elastic (strain) energy per frame, sum of V0_p psi(F_p) with the stored energy
  density psi of the material's constitutive model (``sim.constitutive``) at the
  SIMULATION parameter values (the ones the trajectory was integrated with), when the
  caller gives the material and the trajectory holds ``F`` and ``volume``; then
  ``total_energy`` = kinetic + potential + elastic. Without them ``total_energy`` is
  kinetic + potential and ``total_energy_terms`` / ``elastic_energy_reason`` say so
  (``kinetic_plus_potential`` is always written). Viscous and plastic dissipation are
  not stored energy: the total may fall, never rise, in a correct simulation;
- volume ratio det F per frame (mean, min, max) and overall;
- displacement per frame (mean and max distance from the rest position) [m];
- vertical extent (99.5th - 0.5th percentile along up) per frame and its final /
  initial ratio ``final_extent_ratio`` (``height`` / ``final_height_ratio`` are the
  same numbers under their old names, kept for readers of older metrics files: they
  are extents, not heights above the ground);
- spread (RMS horizontal distance from the centroid, final over initial);
- the centroid height above the floor (``floor``: the run's ground collider when the
  caller knows it, else the lowest point any particle reached) and its final / initial
  ratio;
- centroid height per frame; the rebound ratio (rise of the centroid after the first
  impact over the fall before it: ~0 for a splat or a dent, larger for a bounce; see
  :func:`first_impact`); and
  the dominant oscillation frequency and damping of the object's extent signal; the
  frequency is reported only when it is resolved (at most a quarter of the frame rate
  and at least two periods in the clip), otherwise null with ``frequency_reason``.

Up is the direction opposite to gravity (+z when gravity is zero). The statistics
use all simulated particles, interior fill included (they carry the mass).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "physical_metrics",
    "velocities",
    "oscillation",
    "up_axis",
    "elastic_energy",
    "energy_density",
]


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


def oscillation(
    signal: np.ndarray, dt: float, *, min_samples_per_period: float = 4.0, min_periods: float = 2.0
) -> dict[str, Any]:
    """Dominant frequency [Hz] and damping of a 1-D signal sampled every ``dt`` s.

    The signal is detrended (linear fit removed); the frequency is the peak of its
    Hann-windowed spectrum (excluding DC). It is reported only when RESOLVED: at most
    ``1 / (min_samples_per_period dt)`` (a quarter of the frame rate by default: a peak
    at or near Nyquist, 1 / (2 dt), is aliasing, not a measurement) and at least
    ``min_periods`` periods inside the clip (a spectrum peak at one or two bins is the
    clip length, not an oscillation); otherwise ``frequency_hz`` is None and
    ``frequency_reason`` says why (``frequency_peak_hz`` keeps the raw peak).
    Damping is measured on the free decay: the positive peaks from the largest one on
    (what comes before it is the excitation: a fall, a landing), their mean logarithmic
    decrement converted to a damping ratio ``zeta = delta / sqrt(4 pi^2 + delta^2)``.
    It is ``None`` with ``damping_reason`` when the frequency is not resolved, when
    fewer than two peaks follow the largest, or when those peaks do not decay steadily
    (one grows by more than 5 %: a driven swing, or a body that rocks onto another face
    and changes its resting shape; there is no free decay to measure, where a negative
    ratio used to be reported).
    Returns ``{"frequency_hz", "damping_ratio", "damping_reason", "amplitude",
    "frequency_reason", "frequency_peak_hz", "nyquist_hz"}`` (amplitude: half the
    peak-to-peak of the detrended signal, in the signal's unit).
    """
    y = np.asarray(signal, dtype=np.float64)
    n = y.size
    out: dict[str, Any] = {
        "frequency_hz": None,
        "damping_ratio": None,
        "damping_reason": "the frequency is not resolved",
        "amplitude": 0.0,
        "frequency_reason": None,
        "frequency_peak_hz": None,
        "nyquist_hz": 0.5 / dt,
    }
    if n < 4 or not np.all(np.isfinite(y)):
        out["frequency_reason"] = f"too few frames ({n}) for a spectrum"
        return out
    tt = np.arange(n) * dt
    coef = np.polyfit(tt, y, 1)
    r = y - np.polyval(coef, tt)
    amp = 0.5 * float(r.max() - r.min())
    out["amplitude"] = amp
    if amp <= 1e-9 * max(1.0, float(np.abs(y).max())):
        out["frequency_reason"] = "no oscillation (constant signal after detrending)"
        return out
    spec = np.abs(np.fft.rfft(r * np.hanning(n)))
    freqs = np.fft.rfftfreq(n, dt)
    k = int(np.argmax(spec[1:]) + 1) if spec.size > 1 else 0
    f = float(freqs[k]) if k > 0 else None
    out["frequency_peak_hz"] = f
    f_max = 1.0 / (min_samples_per_period * dt)
    duration = n * dt
    if f is None:
        out["frequency_reason"] = "no spectral peak"
        return out
    if f > f_max:
        out["frequency_reason"] = (
            f"not resolved: the peak at {f:.3g} Hz is above {f_max:.3g} Hz "
            f"({min_samples_per_period:g} frames per period; Nyquist {0.5 / dt:.3g} Hz): aliasing"
        )
        return out
    if f * duration < min_periods:
        out["frequency_reason"] = (
            f"not resolved: {f * duration:.2g} periods in the {duration:.3g} s clip "
            f"(at least {min_periods:g} needed)"
        )
        return out
    out["frequency_hz"] = f
    peaks = [i for i in range(1, n - 1) if r[i] > r[i - 1] and r[i] >= r[i + 1] and r[i] > 0]
    if peaks:
        top = max(range(len(peaks)), key=lambda j: r[peaks[j]])
        peaks = peaks[top:]  # the free decay starts at the largest swing
    if len(peaks) < 2:
        out["damping_reason"] = (
            f"not measurable: {len(peaks)} peak after the largest swing (2 needed)"
            if peaks
            else "not measurable: no peak"
        )
        return out
    vals = np.array([r[i] for i in peaks])
    logs = np.log(vals[:-1] / np.maximum(vals[1:], 1e-12))
    delta = float(np.mean(logs))
    if delta <= 0.0 or np.any(logs < -0.05):  # 5 %: peaks equal within sampling noise
        out["damping_reason"] = (
            "not measurable: the peaks after the largest swing do not decay steadily ("
            + ", ".join(f"{v:.3g}" for v in vals[:4])
            + (", ..." if len(vals) > 4 else "")
            + "): the swing is driven or the body changed its resting shape, not a free decay"
        )
        return out
    out["damping_ratio"] = delta / math.sqrt(4 * math.pi**2 + delta**2)
    out["damping_reason"] = None
    return out


SIG_MIN = 0.05
"""Singular-value clamp before the Hencky log (as ``sim.constitutive.SIG_MIN``)."""
J_MIN = 0.05
"""det F clamp of the fluid model (as ``sim.constitutive.J_MIN``)."""
_HENCKY = ("plasticine", "metal", "foam", "sand")


def _lame(E: float, nu: float) -> tuple[float, float]:
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def energy_density(F: np.ndarray, cls: str, sim: dict[str, float]) -> np.ndarray:
    """Stored elastic energy per unit rest volume psi(F) [J/m^3 = Pa] for ``F`` [..., 3, 3].

    The potentials whose Kirchhoff stresses ``sim.constitutive`` integrates (``sim``:
    simulation parameter values, as in params.json ``sim``):

    - elastic (fixed corotated): ``mu ||F - R||_F^2 + lambda / 2 (J - 1)^2``;
    - plasticine, metal, foam, sand (StVK-Hencky of the elastic part, which is what the
      state keeps after the return map): ``mu ||eps||^2 + lambda / 2 tr(eps)^2``,
      ``eps = log(max(sigma, SIG_MIN))``;
    - non_newtonian: the same Hencky energy with the shear modulus ``mu`` and
      ``lambda = max(kappa - 2 mu / 3, 0)``;
    - newtonian: the volumetric potential of ``tau = kappa / 2 (J^2 - 1) I``:
      ``kappa / 4 (J^2 - 1 - 2 ln J)``, J clamped at J_MIN (zero at J = 1).
    """
    F = np.asarray(F, dtype=np.float64)
    if cls == "newtonian":
        J = np.maximum(np.linalg.det(F), J_MIN)
        return 0.25 * float(sim["kappa"]) * (J * J - 1.0 - 2.0 * np.log(J))
    if cls == "elastic":
        mu, lam = _lame(float(sim["E"]), float(sim["nu"]))
        U, sig, Vt = np.linalg.svd(F)
        R = U @ Vt
        # det(U V^T) = -1 (a reflected F): flip the smallest singular direction, as the
        # solver's polar decomposition does
        flip = np.linalg.det(R) < 0
        if np.any(flip):
            U = U.copy()
            U[flip, :, 2] *= -1.0
            R = U @ Vt
        J = np.linalg.det(F)
        return mu * ((F - R) ** 2).sum((-2, -1)) + 0.5 * lam * (J - 1.0) ** 2
    if cls in _HENCKY:
        mu, lam = _lame(float(sim["E"]), float(sim["nu"]))
    elif cls == "non_newtonian":
        mu = float(sim["mu"])
        lam = max(float(sim["kappa"]) - 2.0 / 3.0 * mu, 0.0)
    else:
        raise ValueError(f"no stored energy known for material class {cls!r}")
    sig = np.linalg.svd(F, compute_uv=False)
    eps = np.log(np.maximum(sig, SIG_MIN))
    return mu * (eps * eps).sum(-1) + 0.5 * lam * eps.sum(-1) ** 2


def elastic_energy(
    traj: dict[str, np.ndarray], material: dict[str, Any] | None
) -> tuple[np.ndarray | None, str | None]:
    """Stored elastic energy per frame [T] J = sum_p volume_p psi(F_p), or (None, reason).

    ``material``: ``{"class": str, "sim": {name: value}}`` (params.json's ``class`` and
    ``sim``); ``traj`` must hold ``F [T, P, 3, 3]`` and ``volume [P]`` m^3 (rest volumes).
    """
    if material is None or not material.get("class"):
        return None, "no material given (params.json class and sim values)"
    if "F" not in traj:
        return None, "trajectory.npz has no deformation gradients F"
    if "volume" not in traj:
        return None, "trajectory.npz has no particle rest volumes 'volume'"
    cls, sim = str(material["class"]), dict(material.get("sim") or {})
    try:
        F = np.asarray(traj["F"], dtype=np.float64)
        vol = np.asarray(traj["volume"], dtype=np.float64).reshape(F.shape[1])
        psi = energy_density(F, cls, sim)
    except (KeyError, ValueError, TypeError) as err:
        return None, f"cannot evaluate the {cls} energy ({err})"
    return (psi * vol[None, :]).sum(1), None


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


VISIBLE_RISE = 0.03
"""A rise after an impact counts as a bounce when it is at least this fraction of the
object's initial vertical extent (a steel block settling 1.5 mm on a 15 cm block, 1 %,
is no bounce to a viewer; the demo bird's 9 cm on 23 cm is)."""


def first_impact(com_h, visible: float = 0.0) -> tuple[int, float, float]:
    """``(frame, fall, rise)`` of the first impact of a centroid height series ``com_h``
    [T] (m): the first local minimum that is at least half as deep below the highest
    point before it as the deepest point of the clip is, and after which the centroid
    rises by at least ``visible`` (m); the fall from that highest point and the largest
    rise after it. Without such a minimum (no visible bounce), the deepest point.

    The first impact, not the lowest point of the clip: an object that bounces and then
    settles lower (a toy that lands on a wing, leaps 9 cm and comes to rest on its side)
    has its lowest point after the bounce, and a rise measured from there reads the bounce
    as none (the demo's bird: 0.04 of the fall against 0.33 from its first impact). The
    depth rule skips a shallow dip in the fall (none under gravity alone; a push, a
    wobble of the shape); ``visible`` skips a settling too small to see."""
    h = np.asarray(com_h, dtype=np.float64)
    T = h.shape[0]
    if T < 2:
        return 0, 0.0, 0.0
    peak = np.maximum.accumulate(h)
    depth = peak - h  # how far below the highest point so far
    need = 0.5 * float(depth.max())
    k = int(np.argmax(depth))  # the deepest frame: the fallback
    for i in range(1, T - 1):
        if h[i] < h[i - 1] and h[i] <= h[i + 1] and depth[i] >= need and depth[i] > 0:
            if float(h[i:].max() - h[i]) >= visible:
                k = i
                break
    fall = float(peak[k] - h[k])
    rise = float(h[k:].max() - h[k]) if k < T - 1 else 0.0
    return k, fall, rise


def physical_metrics(
    traj: dict[str, np.ndarray],
    material: dict[str, Any] | None = None,
    *,
    floor: float | None = None,
) -> dict[str, Any]:
    """Diagnostics of one trajectory (the ``physical`` block of ``metrics.json``).

    ``traj`` holds ``x [T, P, 3]`` m and ``t [T]`` s, and optionally ``v [T, P, 3]`` m/s,
    ``det_F [T, P]``, ``F [T, P, 3, 3]``, ``volume [P]`` m^3,
    ``mass [P]`` kg (default: equal masses summing to 1 kg, energies then per kg) and
    ``gravity [3]`` m/s^2 (default ``[0, 0, -9.8]``). ``material`` (``{"class", "sim"}``)
    enables the elastic energy; ``floor`` is the ground height along up [m] (None: the
    lowest point any particle reached).
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
    heights = np.array([_extent(x[i], up) for i in range(T)])  # vertical extents [T] m
    floor_src = "given (ground collider)"
    if floor is None:
        floor = float(np.percentile(x @ up, 0.1, axis=1).min())
        floor_src = "lowest point reached by the particles (no ground collider known)"
    above = com_h - float(floor)  # centroid height above the floor [T] m
    el, el_reason = elastic_energy(traj, material)
    if "mass" not in traj:
        el, el_reason = None, "no particle masses: energies are per kg, strain energy is not"
    spreads = np.array([_spread(x[i], up, m) for i in range(T)])
    h0 = max(heights[0], 1e-9)
    s0 = max(spreads[0], 1e-9)
    dt = float(t[1] - t[0]) if T > 1 else 1.0

    visible = VISIBLE_RISE * float(heights[0])
    k, fall, rise = first_impact(com_h, visible)
    # no bounce without a fall a viewer sees: an object resting on the floor settles by
    # a fraction of a millimetre and rises back by round-off (a resting donut read 0.30)
    rebound = rise / fall if fall > max(visible, 1e-6) else 0.0

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
        "elastic_energy": el.tolist() if el is not None else None,
        "kinetic_plus_potential": (ke + pe).tolist(),
        "total_energy": (ke + pe + (el if el is not None else 0.0)).tolist(),
        "total_energy_terms": ["kinetic", "potential"] + (["elastic"] if el is not None else []),
        "max_kinetic_energy": float(ke.max()),
        "final_kinetic_energy": float(ke[-1]),
        "displacement_mean": disp.mean(1).tolist(),
        "displacement_max": disp.max(1).tolist(),
        "final_displacement_mean": float(disp[-1].mean()),
        "max_displacement": float(disp.max()),
        "centroid_height": com_h.tolist(),
        "centroid_drop": float(com_h[0] - com_h[-1]),
        "rebound_ratio": float(rebound),
        "floor_height": float(floor),
        "floor_source": floor_src,
        "centroid_height_above_floor": above.tolist(),
        "initial_centroid_height_above_floor": float(above[0]),
        "final_centroid_height_above_floor": float(above[-1]),
        "final_centroid_height_ratio": float(above[-1] / max(above[0], 1e-9)),
        "vertical_extent": heights.tolist(),
        "initial_vertical_extent": float(heights[0]),
        "final_vertical_extent": float(heights[-1]),
        "final_extent_ratio": float(heights[-1] / h0),
        "min_extent_ratio": float(heights.min() / h0),
        # old names of the four extent figures above (kept for existing readers)
        "height": heights.tolist(),
        "initial_height": float(heights[0]),
        "final_height": float(heights[-1]),
        "final_height_ratio": float(heights[-1] / h0),
        "min_height_ratio": float(heights.min() / h0),
        "spread": spreads.tolist(),
        "spread_ratio": float(spreads[-1] / s0),
        "max_spread_ratio": float(spreads.max() / s0),
        "max_speed": float(np.linalg.norm(v, axis=-1).max()),
        "height_oscillation": oscillation(heights, dt),  # of the vertical extent
        "centroid_oscillation": oscillation(com_h, dt),
    }
    if el is None:
        out["elastic_energy_reason"] = el_reason
    if "object_id" in traj:  # (an object's own slice has none)
        out.update(object_metrics(traj, floor=floor if floor_src.startswith("given") else None))
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


_PER_PARTICLE = ("v", "det_F", "F", "volume", "mass", "active")
"""Trajectory arrays with a particle axis (axis 1 for [T, P, ...], axis 0 for [P])."""


def object_slices(traj: dict[str, np.ndarray]) -> list[tuple[str, dict[str, Any]]]:
    """``[(name, trajectory of that object's particles)]`` of a trajectory with
    ``object_id [P]`` (names from ``object_names [K]``, else ``object0`` ...)."""
    oid = np.asarray(traj["object_id"]).astype(np.int64).reshape(-1)
    k = int(oid.max()) + 1
    names = [str(n) for n in np.asarray(traj.get("object_names", []))]
    if len(names) != k:
        names = [f"object{i}" for i in range(k)]
    out = []
    for i, name in enumerate(names):
        sel = oid == i
        sub: dict[str, Any] = {}
        for key, value in traj.items():
            if key in ("object_id", "object_names", "object_mass"):
                continue
            a = np.asarray(value)
            if key == "x" or (key in _PER_PARTICLE and a.ndim >= 2 and a.shape[1] == oid.size):
                sub[key] = a[:, sel]
            elif key in _PER_PARTICLE and a.ndim == 1 and a.shape[0] == oid.size:
                sub[key] = a[sel]
            else:
                sub[key] = value
        out.append((name, sub))
    return out


def object_metrics(traj: dict[str, np.ndarray], floor: float | None = None) -> dict[str, Any]:
    """Per-object diagnostics of a scene of several objects (``object_id [P]`` in ``traj``).

    ``objects``: ``{name: physical_metrics of its particles}`` (the same keys as the
    whole scene); ``object_centroid_distance``: ``{"a|b": [T] m}`` between the mass
    centroids of every pair (contact: approach, then separation). ``floor`` [m] is shared
    (None: the lowest point the whole scene reached, so every object uses the same one)."""
    x = np.asarray(traj["x"], dtype=np.float64)
    if floor is None:
        up = up_axis(np.asarray(traj.get("gravity", (0.0, 0.0, -9.8)), dtype=np.float64))
        floor = float(np.percentile(x @ up, 0.1, axis=1).min())
    parts = object_slices(traj)
    per = {name: physical_metrics(sub, floor=floor) for name, sub in parts}
    cents = {}
    for name, sub in parts:
        xs = np.asarray(sub["x"], dtype=np.float64)
        m = np.asarray(sub.get("mass", np.ones(xs.shape[1])), dtype=np.float64)
        cents[name] = (m[None, :, None] * xs).sum(1) / m.sum()
    names = list(cents)
    dist = {
        f"{a}|{b}": np.linalg.norm(cents[a] - cents[b], axis=-1).tolist()
        for i, a in enumerate(names)
        for b in names[i + 1 :]
    }
    return {"objects": per, "object_centroid_distance": dist}
