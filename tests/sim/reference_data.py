"""Published reference data and analytic formulas for the simulator's physics tests.

Nothing in this file was tuned to our simulator: every number is either digitised from
the cited publication or a closed-form result of the cited theory. Tests compare
against these at tolerances stated (with their physical reason) where they are used.
"""

from __future__ import annotations

import math

import numpy as np

# --------------------------------------------------------------------------------------
# Dam break: Martin, J.C. & Moyce, W.J. (1952). "Part IV. An experimental study of the
# collapse of liquid columns on a rigid horizontal plane." Phil. Trans. R. Soc. Lond. A
# 244 (882), 312-324. doi:10.1098/rsta.1952.0006.
#
# Rectangular water column of width a and height n^2 a released against a wall; the surge
# front is at distance x from the wall. Nondimensional front Z = x / a versus
# T = n t sqrt(g / a); for n^2 = 2 this is T = t sqrt(2 g / a).
# The points are those of the paper's Fig. 3 for n^2 = 2, as digitised by the PySPH
# project (examples/db_exp_data.py, BSD licence; the same points Koshizuka & Oka 1996,
# Nucl. Sci. Eng. 123, 421-434, compare against). Columns: T, Z.
# --------------------------------------------------------------------------------------
MARTIN_MOYCE_N2_2_A_2_25IN = np.array(
    [
        [0.832, 1.217],
        [1.219, 1.474],
        [1.997, 2.292],
        [2.547, 2.995],
        [3.345, 4.134],
        [4.034, 4.944],
        [4.418, 5.881],
        [5.091, 6.980],
        [5.685, 7.945],
        [6.306, 8.966],
        [6.822, 9.986],
        [7.439, 10.963],
        [8.031, 11.977],
        [8.633, 13.005],
        [9.237, 13.970],
    ]
)
"""Martin & Moyce (1952) Fig. 3, n^2 = 2, a = 2.25 in: columns T = t sqrt(2g/a), Z = x/a."""

MARTIN_MOYCE_N2_2_A_1_125IN = np.array(
    [
        [0.849, 1.245],
        [1.212, 1.443],
        [1.602, 1.884],
        [2.283, 2.689],
        [2.950, 3.728],
        [3.598, 4.528],
        [3.905, 4.999],
        [4.592, 5.841],
        [4.961, 6.271],
        [5.316, 6.717],
    ]
)
"""Martin & Moyce (1952) Fig. 3, n^2 = 2, a = 1.125 in: columns T, Z."""


# --------------------------------------------------------------------------------------
# Granular column collapse.
# Planar (quasi-two-dimensional, channel) collapse: Lube, G., Huppert, H.E., Sparks, R.S.J.
# & Freundt, A. (2005). "Collapses of two-dimensional granular columns." Phys. Rev. E 72,
# 041301: (d_inf - d_i) / d_i = 1.2 a for a < 2.3 and 1.9 a^(2/3) for a > 2.3, where a =
# h_i / d_i is the initial aspect ratio, d_i the initial length and d_inf the final run-out
# measured from the back wall.
# Axisymmetric collapse: Lube, G., Huppert, H.E., Sparks, R.S.J. & Hallworth, M.A. (2004).
# "Axisymmetric collapses of granular columns." J. Fluid Mech. 508, 175-199:
# (r_inf - r_i) / r_i = 1.24 a for a < 1.7 and 1.6 a^(1/2) for a > 1.7.
# Both laws were found independent of the grain material (and so of its friction angle).
# --------------------------------------------------------------------------------------


def lube_planar_runout(a: float) -> float:
    """Normalised run-out (d_inf - d_i)/d_i of a planar column of aspect ratio a (Lube 2005)."""
    return 1.2 * a if a < 2.3 else 1.9 * a ** (2.0 / 3.0)


def lube_axisymmetric_runout(a: float) -> float:
    """Normalised run-out (r_inf - r_i)/r_i of a cylinder of aspect ratio a (Lube 2004)."""
    return 1.24 * a if a < 1.7 else 1.6 * math.sqrt(a)


# --------------------------------------------------------------------------------------
# Elastic bar: longitudinal vibration of a free-free thin bar (e.g. Graff, K.F. (1975),
# "Wave Motion in Elastic Solids", ch. 2; Timoshenko, S. & Goodier, J.N.). Mode m has
# frequency f_m = m c / (2 L) with the bar wave speed c = sqrt(E / rho). The thin-bar
# theory neglects lateral inertia (Rayleigh-Love correction of relative size
# (m pi nu r_g / L)^2 / 2, zero for nu = 0), so tests use nu = 0 where it is exact for the
# continuum.
# --------------------------------------------------------------------------------------


def bar_axial_frequency(E: float, rho: float, length: float, mode: int = 1) -> float:
    """Natural frequency [Hz] of axial mode ``mode`` of a free-free bar: m sqrt(E/rho)/(2L)."""
    return mode * math.sqrt(E / rho) / (2.0 * length)


# --------------------------------------------------------------------------------------
# Yield-stress fluid slump: Pashias, N., Boger, D.V., Summers, J., & Glenister, D.J.
# (1996). "A fifty cent rheometer for yield stress measurement." J. Rheol. 40(6),
# 1179-1189 (after Murata 1984). A cylinder of height H of a material with shear yield
# stress tau_y slumps by s with s/H = 1 - 2 tau' (1 - ln(2 tau')), tau' = tau_y/(rho g H);
# no material yields (s = 0) when tau' >= 1/2, i.e. when the largest shear stress,
# rho g H / 2 at the base, stays below tau_y. For a von Mises yield surface with uniaxial
# yield stress sigma_Y, the shear yield stress is tau_y = sigma_Y / sqrt(3).
# --------------------------------------------------------------------------------------


def slump_fraction(tau_y: float, rho: float, g: float, height: float) -> float:
    """Predicted slump s/H of a yield-stress cylinder (Pashias et al. 1996); 0 below yield."""
    t = tau_y / (rho * g * height)
    if t >= 0.5:
        return 0.0
    return 1.0 - 2.0 * t * (1.0 - math.log(2.0 * t))
