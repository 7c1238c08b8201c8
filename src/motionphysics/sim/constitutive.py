"""Constitutive models of the MPM solver, as Warp functions (one per material class).

Each model maps the trial deformation gradient of one substep, ``F_trial = (I + dt C) F``,
to ``(F_elastic, plastic_strain, tau)``: the elastic deformation gradient kept in the
state after the return mapping, the accumulated plastic strain, and the Kirchhoff
stress ``tau = P F^T`` [Pa] used by the P2G transfer. Every function is differentiable
(Warp records its adjoint); the only non-smooth points are the yield surfaces.

Material dispatch by class id happens in exactly one place, the table :data:`MODELS`.
Class ids follow ``motionphysics.config.MATERIAL_CLASSES``.

All parameters are simulation values (``materials.simmap`` owns the physical → sim
map). Lamé parameters from Young's modulus E [Pa] and Poisson's ratio nu [-]:
``mu = E / (2 (1 + nu))``, ``lambda = E nu / ((1 + nu)(1 - 2 nu))``.
This module must not launch kernels or allocate arrays.
"""

from __future__ import annotations

from motionphysics.runtime import init_warp

wp = init_warp()

ELASTIC = wp.constant(0)
PLASTICINE = wp.constant(1)
METAL = wp.constant(2)
FOAM = wp.constant(3)
SAND = wp.constant(4)
NEWTONIAN = wp.constant(5)
NON_NEWTONIAN = wp.constant(6)

SIG_MIN = wp.constant(0.05)
"""Singular values are clamped below at this value before taking logs (Hencky strain),
so a nearly collapsed particle cannot produce an infinite stress."""
J_MIN = wp.constant(0.05)
"""Lower clamp of det F for the fluid models (avoids J^(1/3) of a negative number)."""
PLASTICINE_SOFTENING = wp.constant(2.0)
"""xi in the plasticine yield law tau_Y(ep) = tau_Y exp(-xi ep): the yield stress halves
after about 35 % accumulated plastic strain (damage / softening, d tau_Y / d ep < 0)."""
FOAM_DEFAULT_YIELD_FRACTION = 0.05
"""Foam has no yield stress among its paper parameters (E, nu, eta); when none is
given the builder uses tau_Y = 0.05 E (yield at a few percent strain)."""


@wp.func
def lame(E: float, nu: float):
    """Lamé parameters (mu, lambda) [Pa] from Young's modulus E [Pa] and Poisson's ratio nu."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


@wp.func
def _safe_norm(a: wp.vec3):
    # sqrt(|a|^2 + tiny): finite adjoint at a = 0 (wp.length divides by |a|).
    return wp.sqrt(wp.dot(a, a) + 1.0e-24)


@wp.func
def _diag(d: wp.vec3):
    return wp.mat33(d[0], 0.0, 0.0, 0.0, d[1], 0.0, 0.0, 0.0, d[2])


@wp.func
def _hencky_strain(sig: wp.vec3):
    """Principal logarithmic strain eps = log(max(sigma, SIG_MIN))."""
    return wp.vec3(
        wp.log(wp.max(sig[0], SIG_MIN)),
        wp.log(wp.max(sig[1], SIG_MIN)),
        wp.log(wp.max(sig[2], SIG_MIN)),
    )


@wp.func
def _hencky_tau(U: wp.mat33, eps: wp.vec3, mu: float, lam: float):
    """StVK-Hencky Kirchhoff stress tau = U [2 mu eps + lambda tr(eps) I] U^T."""
    tr = eps[0] + eps[1] + eps[2]
    d = 2.0 * mu * eps + wp.vec3(lam * tr, lam * tr, lam * tr)
    return U * _diag(d) * wp.transpose(U)


@wp.func
def _from_strain(U: wp.mat33, eps: wp.vec3, V: wp.mat33):
    """F = U diag(exp(eps)) V^T."""
    s = wp.vec3(wp.exp(eps[0]), wp.exp(eps[1]), wp.exp(eps[2]))
    return U * _diag(s) * wp.transpose(V)


@wp.func
def _deviator(eps: wp.vec3):
    m = (eps[0] + eps[1] + eps[2]) / 3.0
    return eps - wp.vec3(m, m, m)


@wp.func
def _polar_rotation(F: wp.mat33):
    """Proper rotation R = U V^T of the polar decomposition F = R S (via the SVD).

    Its adjoint is empty on purpose: :func:`_corotated_tau`, its only user, accounts for
    dR/dF analytically (cheaper than Warp's SVD adjoint, which would otherwise dominate
    the backward pass)."""
    U = wp.mat33()
    sig = wp.vec3()
    V = wp.mat33()
    wp.svd3(F, U, sig, V)
    return U * wp.transpose(V)


@wp.func_grad(_polar_rotation)
def _adj_polar_rotation(F: wp.mat33, adj_ret: wp.mat33):
    # dR/dF is folded into _adj_corotated_tau (see there); nothing flows through here.
    wp.adjoint[F] += wp.mat33() * 0.0


@wp.func
def _corotated_tau(F: wp.mat33, R: wp.mat33, mu: float, lam: float):
    """Fixed corotated Kirchhoff stress 2 mu (F - R) F^T + lambda J (J - 1) I, R = polar(F)."""
    J = wp.determinant(F)
    return 2.0 * mu * (F - R) * wp.transpose(F) + wp.identity(n=3, dtype=float) * (
        lam * J * (J - 1.0)
    )


@wp.func
def _vee(A: wp.mat33):
    return wp.vec3(A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1])


@wp.func_grad(_corotated_tau)
def _adj_corotated_tau(F: wp.mat33, R: wp.mat33, mu: float, lam: float, adj_tau: wp.mat33):
    # Analytic adjoint, R = R(F) included. With A = adj_tau, J = det F:
    #   2 mu F F^T        -> a_F += 2 mu (A + A^T) F
    #   -2 mu R F^T       -> a_F += -2 mu A^T R,  a_R = -2 mu A F
    #   lam J (J-1) I     -> a_F += tr(A) lam (2J - 1) J F^-T
    #   polar rotation    -> a_F += R [y]x,  y = (tr(S) I - S)^-1 vee(R^T a_R),  S = R^T F
    # (dR = R [w]x with (tr(S) I - S) w = vee(R^T dF); tests/sim/test_kernels.py checks it
    # against finite differences.)
    A = adj_tau
    J = wp.determinant(F)
    Ft = wp.transpose(F)
    trA = A[0, 0] + A[1, 1] + A[2, 2]
    aF = 2.0 * mu * (A + wp.transpose(A)) * F - 2.0 * mu * wp.transpose(A) * R
    aF = aF + (trA * lam * (2.0 * J - 1.0) * J) * wp.transpose(wp.inverse(F))
    aR = -2.0 * mu * A * F
    S0 = wp.transpose(R) * F
    S = 0.5 * (S0 + wp.transpose(S0))
    trS = S[0, 0] + S[1, 1] + S[2, 2]
    G = wp.identity(n=3, dtype=float) * trS - S
    y = wp.inverse(G) * _vee(wp.transpose(R) * aR)
    Y = wp.mat33(0.0, -y[2], y[1], y[2], 0.0, -y[0], -y[1], y[0], 0.0)
    aF = aF + R * Y
    wp.adjoint[F] += aF
    wp.adjoint[mu] += wp.ddot(A, 2.0 * (F - R) * Ft)
    wp.adjoint[lam] += trA * J * (J - 1.0)


@wp.func
def fixed_corotated(F: wp.mat33, ep: float, E: float, nu: float):
    """Elastic: fixed corotated elasticity, identity return map.

    P = 2 mu (F - R) + lambda J (J - 1) F^-T with R the polar rotation of F (R = U V^T);
    Kirchhoff tau = P F^T = 2 mu (F - R) F^T + lambda J (J - 1) I. F is kept as is.
    """
    mu, lam = lame(E, nu)
    tau = _corotated_tau(F, _polar_rotation(F), mu, lam)
    return F, ep, tau


@wp.func
def _von_mises_return(
    F: wp.mat33, ep: float, E: float, nu: float, yield_stress: float, eta: float, dt: float
):
    """StVK-Hencky elasticity with a (viscously regularised) von Mises radial return.

    eps = log(Sigma) (F = U Sigma V^T), s = dev(tau) = 2 mu dev(eps).
    Yield when ||s|| > sqrt(2/3) yield_stress; then
    dgamma = (||dev eps|| - sqrt(2/3) yield_stress / (2 mu)) / (1 + eta / (2 mu dt)) and
    eps <- eps - dgamma dev(eps)/||dev eps|| (volume kept). ep accumulates dgamma.
    eta = 0 is the plain radial return (the division by 1.0 is exact).
    """
    U = wp.mat33()
    sig = wp.vec3()
    V = wp.mat33()
    wp.svd3(F, U, sig, V)
    mu, lam = lame(E, nu)
    eps = _hencky_strain(sig)
    dev = _deviator(eps)
    norm = _safe_norm(dev)
    over = norm - wp.sqrt(2.0 / 3.0) * yield_stress / (2.0 * mu)
    Fe = F
    ep_out = ep
    if over > 0.0:
        dgamma = over / (1.0 + eta / (2.0 * mu * dt))
        eps = eps - (dgamma / norm) * dev
        Fe = _from_strain(U, eps, V)
        ep_out = ep + dgamma
    return Fe, ep_out, _hencky_tau(U, eps, mu, lam)


@wp.func
def von_mises_metal(F: wp.mat33, ep: float, E: float, nu: float, tau_Y: float):
    """Metal: StVK-Hencky elasticity with von Mises plasticity (radial return, constant tau_Y)."""
    return _von_mises_return(F, ep, E, nu, tau_Y, 0.0, 1.0)


@wp.func
def von_mises_damage(F: wp.mat33, ep: float, E: float, nu: float, tau_Y: float):
    """Plasticine: StVK-Hencky with von Mises plasticity and damage (softening).

    As :func:`von_mises_metal` with a yield stress that decreases with accumulated
    plastic strain ep: tau_Y(ep) = tau_Y exp(-xi ep), xi = PLASTICINE_SOFTENING.
    """
    return _von_mises_return(F, ep, E, nu, tau_Y * wp.exp(-PLASTICINE_SOFTENING * ep), 0.0, 1.0)


@wp.func
def viscoplastic_foam(
    F: wp.mat33, ep: float, E: float, nu: float, tau_Y: float, eta: float, dt: float
):
    """Foam: StVK-Hencky with the viscoplastic (viscously regularised von Mises) return map.

    The paper's formula: s = s_trial - y / (1 + eta / (2 mu dt)) s_trial/||s_trial||, with
    the over-stress y = ||s_trial|| - sqrt(2/3) tau_Y > 0. In strain space (s = 2 mu dev eps):
    dgamma = (||dev eps|| - sqrt(2/3) tau_Y/(2 mu)) / (1 + eta/(2 mu dt)).
    """
    return _von_mises_return(F, ep, E, nu, tau_Y, eta, dt)


@wp.func
def drucker_prager_sand(F: wp.mat33, ep: float, E: float, nu: float, theta_fric: float):
    """Sand: StVK-Hencky with Drucker-Prager plasticity (Klar et al. 2016), no cohesion.

    theta_fric is the friction angle in DEGREES; alpha = sqrt(2/3) 2 sin(phi) / (3 - sin(phi)).
    In log-strain: tr(eps) >= 0 (expansion) projects to the cone tip (eps = 0, Sigma = I);
    otherwise dgamma = ||dev eps|| + (3 lambda + 2 mu)/(2 mu) tr(eps) alpha and, when
    dgamma > 0, eps <- eps - dgamma dev(eps)/||dev eps||. ep accumulates dgamma.
    """
    U = wp.mat33()
    sig = wp.vec3()
    V = wp.mat33()
    wp.svd3(F, U, sig, V)
    mu, lam = lame(E, nu)
    sin_phi = wp.sin(theta_fric * (wp.pi / 180.0))
    alpha = wp.sqrt(2.0 / 3.0) * 2.0 * sin_phi / (3.0 - sin_phi)
    eps = _hencky_strain(sig)
    tr = eps[0] + eps[1] + eps[2]
    dev = _deviator(eps)
    norm = _safe_norm(dev)
    Fe = F
    ep_out = ep
    if tr >= 0.0:
        ep_out = ep + _safe_norm(eps)
        eps = wp.vec3(0.0, 0.0, 0.0)
        Fe = U * wp.transpose(V)
    else:
        dgamma = norm + (3.0 * lam + 2.0 * mu) / (2.0 * mu) * tr * alpha
        if dgamma > 0.0:
            eps = eps - (dgamma / norm) * dev
            Fe = _from_strain(U, eps, V)
            ep_out = ep + dgamma
    return Fe, ep_out, _hencky_tau(U, eps, mu, lam)


@wp.func
def weakly_compressible_fluid(F: wp.mat33, C: wp.mat33, ep: float, mu: float, kappa: float):
    """Newtonian fluid: weakly compressible fluid (the paper's compressible neo-Hookean).

    mu is the dynamic viscosity [Pa s], kappa the bulk modulus [Pa]. With J = det F:
    pressure part of the Kirchhoff stress kappa/2 (J^2 - 1) I (the neo-Hookean volumetric
    term), viscous part J 2 mu sym(grad v) with grad v the particle's APIC matrix C.
    The return map resets F to J^(1/3) I: a fluid keeps no shear memory, only volume.
    """
    J = wp.max(wp.determinant(F), J_MIN)
    I = wp.identity(n=3, dtype=float)
    tau = (J * mu) * (C + wp.transpose(C)) + I * (0.5 * kappa * (J * J - 1.0))
    Fe = I * wp.pow(J, 1.0 / 3.0)
    return Fe, ep, tau


@wp.func
def herschel_bulkley(
    F: wp.mat33, ep: float, mu: float, kappa: float, tau_Y: float, eta: float, n: float, dt: float
):
    """Non-Newtonian fluid: StVK-Hencky with Herschel-Bulkley viscoplasticity.

    mu is the shear modulus and kappa the bulk modulus [Pa] of the elastic part
    (lambda = kappa - 2 mu / 3, clamped at 0), tau_Y the yield stress [Pa], eta the
    plastic viscosity, n the power-law index. Yield surface: von Mises with tau_Y the
    UNIAXIAL (tensile) yield stress, as for metal and foam: ||s|| = sqrt(2/3) tau_Y, so
    the shear yield stress of rheology (simple shear, tau = s_xy) is tau_Y / sqrt(3).
    In steady simple shear at rate gamma_dot (||s|| = sqrt(2) tau, x / dt = gamma_dot /
    sqrt(2)) the flow rule below reads tau = tau_Y / sqrt(3) + K gamma_dot^n with the
    consistency K = eta 2^(-(n + 1) / 2) [Pa s^n] (K = eta / 2 for n = 1).
    The paper's Bingham formula (n = 1):
    s = s_trial - (||s_trial|| - sqrt(2/3) tau_Y)/(1 + eta/(2 mu dt)) s_trial/||s_trial||.
    In strain space the plastic increment x = dgamma solves
    ||s_trial|| - sqrt(2/3) tau_Y - 2 mu x - eta (x/dt)^n = 0; closed form for n = 1,
    otherwise 8 safeguarded Newton steps from the Bingham value.
    """
    U = wp.mat33()
    sig = wp.vec3()
    V = wp.mat33()
    wp.svd3(F, U, sig, V)
    lam = wp.max(kappa - 2.0 / 3.0 * mu, 0.0)
    eps = _hencky_strain(sig)
    dev = _deviator(eps)
    norm = _safe_norm(dev)
    s_norm = 2.0 * mu * norm
    k = wp.sqrt(2.0 / 3.0) * tau_Y
    Fe = F
    ep_out = ep
    if s_norm > k:
        x = (s_norm - k) / (2.0 * mu + eta / dt)
        x_max = (s_norm - k) / (2.0 * mu)
        # Always iterate (also for n = 1, where g(x) = 0 already): the last Newton step
        # carries the implicit-function derivative dx/dn = -(dg/dn)/(dg/dx) to the tape.
        for _it in range(8):
            rate = wp.max(x, 1.0e-6 * x_max) / dt
            g = s_norm - k - 2.0 * mu * x - eta * wp.pow(rate, n)
            dg = -2.0 * mu - eta * n * wp.pow(rate, n - 1.0) / dt
            x = wp.clamp(x - g / dg, 1.0e-6 * x_max, x_max)
        dgamma = x
        eps = eps - (dgamma / norm) * dev
        Fe = _from_strain(U, eps, V)
        ep_out = ep + dgamma
    return Fe, ep_out, _hencky_tau(U, eps, mu, lam)


# ---------------------------------------------------------------- the one dispatch table
# Every model behind one signature: (F_trial, C, ep, dt, E, nu, tau_Y, eta, theta_fric, mu,
# kappa, n) -> (F_e, ep, tau). MODELS[class_id] is the only place where class ids map to
# equations; kernels.py builds one stress kernel per entry (a runtime switch over seven
# models made Warp's generated adjoint 3x slower: it zero-initialises the adjoint
# variables of every branch).


@wp.func
def _elastic(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return fixed_corotated(F, ep, E, nu)


@wp.func
def _plasticine(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return von_mises_damage(F, ep, E, nu, tau_Y)


@wp.func
def _metal(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return von_mises_metal(F, ep, E, nu, tau_Y)


@wp.func
def _foam(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return viscoplastic_foam(F, ep, E, nu, tau_Y, eta, dt)


@wp.func
def _sand(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return drucker_prager_sand(F, ep, E, nu, theta_fric)


@wp.func
def _newtonian(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return weakly_compressible_fluid(F, C, ep, mu, kappa)


@wp.func
def _non_newtonian(
    F: wp.mat33,
    C: wp.mat33,
    ep: float,
    dt: float,
    E: float,
    nu: float,
    tau_Y: float,
    eta: float,
    theta_fric: float,
    mu: float,
    kappa: float,
    n: float,
):
    return herschel_bulkley(F, ep, mu, kappa, tau_Y, eta, n, dt)


MODELS = (_elastic, _plasticine, _metal, _foam, _sand, _newtonian, _non_newtonian)
"""Material class id (config.MATERIAL_CLASSES order) -> model function."""
