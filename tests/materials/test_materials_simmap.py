"""The physical <-> simulation map: monotone, invertible, stable, visually faithful."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from motionphysics.materials.catalog import DENSITY, MATERIALS, MaterialParams, spec, validate
from motionphysics.materials.simmap import (
    SimContext,
    impact_to_yield,
    nn_consistency_factor,
    p_wave_speed,
    physical_to_sim,
    sim_to_physical,
    visible_changes,
    visible_stiffness,
    visible_strains,
)

CLASSES = list(MATERIALS)
# (dx [m], dt [s]): grid 32/64/128 on a 1 m domain; 64 fixed substeps and the "auto"
# budget frame_dt/512 at frame_dt = 0.04 s; plus a tiny dt where nothing is compressed.
GRIDS = [
    (1 / 32, 0.04 / 64),
    (1 / 64, 0.04 / 64),
    (1 / 64, 0.04 / 512),
    (1 / 128, 0.04 / 512),
    (1 / 128, 1e-8),
]


def _value(cls, name, u):
    ps = spec(cls, name)
    if ps.scale == "log":
        return math.exp(math.log(ps.low) + u * (math.log(ps.high) - math.log(ps.low)))
    return ps.low + u * (ps.high - ps.low)


@st.composite
def material_and_ctx(draw):
    cls = draw(st.sampled_from(CLASSES))
    u = st.floats(0.0, 1.0)
    values = {n: _value(cls, n, draw(u)) for n in MATERIALS[cls].names}
    rho = _value(cls, "density", draw(u))
    dx, dt = draw(st.sampled_from(GRIDS))
    length = draw(st.floats(0.05, 2.0))
    rule = draw(st.sampled_from(["auto", "strain", "impact"]))
    return MaterialParams(cls, rho, values), SimContext(dx, dt, rho, length, yield_rule=rule)


@settings(max_examples=300, deadline=None)
@given(material_and_ctx())
def test_round_trip_and_stability(pc):
    params, ctx = pc
    sim = physical_to_sim(params, ctx)
    # Stable: CFL on the P-wave speed (1e-9 relative slack for float round-off).
    assert p_wave_speed(params.cls, sim) <= ctx.c_max * (1 + 1e-9)
    # The viscosity of the explicit scheme: newtonian `mu`, non-Newtonian `eta` (its
    # Herschel-Bulkley consistency; its sim `mu` is the unyielded shear modulus).
    if params.cls == "newtonian":
        assert sim["mu"] <= ctx.mu_max * (1 + 1e-9)
    if params.cls == "non_newtonian":  # the solver's eta is 2^((n+1)/2) x the consistency K
        K = sim["eta"] / nn_consistency_factor(sim.get("n", 1.0))
        assert K <= ctx.mu_max * (1 + 1e-9)
    if "nu" in sim:
        assert sim["nu"] <= 0.49 + 1e-12
    assert sim["density"] == params.density
    back = sim_to_physical(sim, ctx, params.cls)
    assert back.cls == params.cls and back.density == params.density
    for name, x in params.values.items():
        # exp/log chains in float64: ~1e-12 relative; 1e-9 leaves room for the
        # conditioning of the affine log map (slopes up to ~1e3 at tiny caps).
        assert back.values[name] == pytest.approx(x, rel=1e-9, abs=1e-12), name


@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize("dx, dt", GRIDS)
def test_monotone_in_every_parameter(cls, dx, dt):
    rho = 1000.0
    ctx = SimContext(dx, dt, rho, 0.3)
    base = {n: _value(cls, n, 0.5) for n in MATERIALS[cls].names}
    for name in MATERIALS[cls].names:
        us = [i / 20 for i in range(21)]
        outs = []
        for u in us:
            v = dict(base, **{name: _value(cls, name, u)})
            # non-Newtonian sim keys follow the Herschel-Bulkley model: mu <-> eta.
            key = {"mu": "eta", "eta": "mu"}.get(name, name) if cls == "non_newtonian" else name
            outs.append(physical_to_sim(MaterialParams(cls, rho, v), ctx)[key])
        diffs = [b - a for a, b in zip(outs, outs[1:], strict=False)]
        assert all(d > 0 for d in diffs), (name, outs)


def test_identity_where_it_can_be_seen_and_the_budget_allows():
    # A tiny step: nothing is forced by the budget. What can be seen is simulated as
    # asked; steel's stiffness cannot be seen in a 0.3 m drop (its strains stay below
    # 0.5 %), so it is compressed, but never below the visible threshold.
    ctx = SimContext(1 / 128, 1e-9, 7850.0, 0.3)
    p, _ = validate("metal", {"E": 2e11, "nu": 0.3, "tau_Y": 2.5e8}, 7850)
    sim = physical_to_sim(p, ctx)
    assert visible_stiffness(ctx) <= sim["E"] < 2e11
    assert max(visible_strains("metal", sim["E"], ctx).values()) <= ctx.visible_strain * (1 + 1e-9)
    assert visible_changes(p, sim, ctx) == []
    rubber = MaterialParams("elastic", 1100.0, {"E": 1e6, "nu": 0.4})
    rctx = SimContext(1 / 128, 1e-9, 1100.0, 0.3)
    assert physical_to_sim(rubber, rctx)["E"] == 1e6  # a visible stiffness: as asked
    w, _ = validate("newtonian", {"mu": 1e-3, "kappa": 2.2e9}, 1000)
    assert physical_to_sim(w, ctx)["mu"] == 1e-3


@pytest.mark.parametrize("dx, dt", GRIDS)
def test_strain_rule_keeps_the_yield_strain(dx, dt):
    p, _ = validate("metal", {"E": 2.0e11, "nu": 0.3, "tau_Y": 2.5e8}, 7850)
    sim = physical_to_sim(p, SimContext(dx, dt, 7850.0, 0.3, yield_rule="strain"))
    assert sim["tau_Y"] / sim["E"] == pytest.approx(2.5e8 / 2.0e11, rel=1e-12)


@pytest.mark.parametrize("dx, dt", GRIDS)
def test_default_rule_metal_keeps_impact_ratio_clay_and_foam_keep_yield_strain(dx, dt):
    """yield_rule='auto' (the default): a steel object dropped from a 0.75 m table
    rebounds in the simulation as in reality; plasticine and foam keep tau_Y / E."""
    v = math.sqrt(2 * 9.8 * 0.75)
    steel, _ = validate("metal", {"E": 2.0e11, "nu": 0.3, "tau_Y": 2.5e8}, 7850)
    ctx = SimContext(dx, dt, 7850.0, 0.3)
    assert ctx.yield_rule == "auto"
    sim = physical_to_sim(steel, ctx)
    phys = impact_to_yield(dict(steel.values, density=7850.0), v)
    assert phys < 1.0  # real steel does not dent (0.70)
    assert impact_to_yield(sim, v) == pytest.approx(phys, rel=1e-12)
    # The strain rule would dent it wherever E is compressed (72x at grid 64, dt/512).
    strain = physical_to_sim(steel, SimContext(dx, dt, 7850.0, 0.3, yield_rule="strain"))
    if sim["E"] < 0.5 * 2.0e11:
        assert impact_to_yield(strain, v) > 1.0
    for cls, rho, vals in (
        ("plasticine", 1500.0, {"E": 2.5e6, "nu": 0.4, "tau_Y": 1e4}),
        ("foam", 50.0, {"E": 1e5, "nu": 0.2, "tau_Y": 1e4, "eta": 1.0}),
    ):
        s = physical_to_sim(MaterialParams(cls, rho, vals), SimContext(dx, dt, rho, 0.3))
        assert s["tau_Y"] / s["E"] == pytest.approx(vals["tau_Y"] / vals["E"], rel=1e-12), cls


def test_impact_rule_keeps_impact_to_yield_ratio():
    p, _ = validate("metal", {"E": 2.0e11, "nu": 0.3, "tau_Y": 2.5e8}, 7850)
    ctx = SimContext(1 / 64, 0.04 / 512, 7850.0, 0.3, yield_rule="impact")
    sim = physical_to_sim(p, ctx)
    v = math.sqrt(2 * 9.8 * 0.75)  # dropped from a 0.75 m table
    phys = impact_to_yield(dict(p.values, density=7850.0), v)
    assert phys < 1.0  # real steel does not dent
    assert impact_to_yield(sim, v) == pytest.approx(phys, rel=1e-12)


@pytest.mark.parametrize("dx, dt", [(1 / 64, 0.04 / 512), (1 / 128, 0.04 / 512)])
def test_water_stays_nearly_incompressible(dx, dt):
    L = 0.3
    ctx = SimContext(dx, dt, 1000.0, L)
    p, _ = validate("newtonian", {"mu": 1e-3, "kappa": 2.2e9}, 1000)
    sim = physical_to_sim(p, ctx)
    c = p_wave_speed("newtonian", sim)
    assert c >= 10 * math.sqrt(2 * 9.8 * L)
    assert c <= ctx.c_max
    assert sim["mu"] == 1e-3  # water's viscosity passes through


def test_water_sound_speed_capped_by_cfl_on_coarse_steps():
    ctx = SimContext(1 / 32, 0.04 / 64, 1000.0, 0.3)  # c_max = 0.4 * 0.03125 / 6.25e-4 = 20 m/s
    p, _ = validate("newtonian", {"mu": 1e-3, "kappa": 5e9}, 1000)
    assert p_wave_speed("newtonian", physical_to_sim(p, ctx)) == pytest.approx(ctx.c_max)


def test_rubber_softer_than_steel_and_supports_its_weight():
    ctx = SimContext(1 / 64, 0.04 / 512, 1100.0, 0.3)
    rubber = physical_to_sim(MaterialParams("elastic", 1100.0, {"E": 1e7, "nu": 0.49}), ctx)
    steel = physical_to_sim(MaterialParams("elastic", 1100.0, {"E": 2e11, "nu": 0.3}), ctx)
    assert rubber["E"] < steel["E"]
    # own-weight strain rho g L / E of the softest elastic material stays <= 5 %
    assert 1100.0 * 9.8 * 0.3 / rubber["E"] <= 0.05 + 1e-12


def test_torch_matches_float_and_is_differentiable():
    ctx = SimContext(1 / 64, 0.04 / 64, 7850.0, 0.3)
    vals = {"E": 2e11, "nu": 0.47, "tau_Y": 2.5e8}
    ref = physical_to_sim(MaterialParams("metal", 7850.0, vals), ctx)
    tv = {k: torch.tensor(v, dtype=torch.float64) for k, v in vals.items()}
    out = physical_to_sim(MaterialParams("metal", 7850.0, tv), ctx)
    for k in ("E", "nu", "tau_Y"):
        assert float(out[k]) == pytest.approx(ref[k], rel=1e-12)

    def f(logE, nu, logmu):
        s = physical_to_sim(
            {"E": torch.exp(logE), "nu": nu, "tau_Y": torch.tensor(1e8, dtype=torch.float64)},
            ctx,
            cls="metal",
        )
        m = physical_to_sim(
            {
                "mu": torch.exp(logmu),
                "kappa": torch.tensor(2e9, dtype=torch.float64),
                "tau_Y": torch.tensor(10.0, dtype=torch.float64),
                "eta": torch.tensor(0.5, dtype=torch.float64),
                "n": torch.tensor(1.0, dtype=torch.float64),
            },
            ctx,
            cls="non_newtonian",
        )
        return torch.stack([torch.log(s["E"]), s["nu"], torch.log(s["tau_Y"]), torch.log(m["eta"])])

    args = (
        torch.tensor(math.log(1e11), dtype=torch.float64, requires_grad=True),
        torch.tensor(0.3, dtype=torch.float64, requires_grad=True),
        torch.tensor(math.log(300.0), dtype=torch.float64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(f, args)


def test_per_particle_tensors():
    ctx = SimContext(1 / 64, 0.04 / 64, 1000.0, 0.3)
    E = torch.tensor([1e7, 1e9, 4e11], dtype=torch.float64)
    nu = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64)
    sim = physical_to_sim({"E": E, "nu": nu, "density": 1000.0}, ctx, cls="elastic")
    assert sim["E"].shape == (3,)
    back = sim_to_physical(sim, ctx, "elastic")
    torch.testing.assert_close(back.values["E"], E, rtol=1e-9, atol=0)
    torch.testing.assert_close(back.values["nu"], nu, rtol=1e-9, atol=1e-12)


def test_sand_gets_a_stable_elastic_predictor():
    ctx = SimContext(1 / 64, 0.04 / 64, 1600.0, 0.3)
    sim = physical_to_sim(MaterialParams("sand", 1600.0, {"theta_fric": 35.0}), ctx)
    assert sim["theta_fric"] == 35.0 and sim["nu"] == 0.3
    assert p_wave_speed("sand", sim) <= ctx.c_max * (1 + 1e-12)


def test_bad_context_rejected():
    with pytest.raises(ValueError):
        SimContext(0.0, 1e-3, 1000.0, 1.0)
    with pytest.raises(ValueError):
        SimContext(0.01, 1e-3, 1000.0, 1.0, yield_rule="nope")
    assert SimContext(0.01, 1e-3, 1000.0, 1.0, yield_rule="impact").yield_rule == "impact"
    assert DENSITY.low > 0


def test_dicts_with_a_class_key():
    ctx = SimContext(1 / 64, 0.04 / 64, 7850.0, 0.3)
    p, _ = validate("metal", {"E": 2e11, "nu": 0.3, "tau_Y": 2.5e8}, 7850)
    sim = physical_to_sim(p.to_dict(), ctx)
    assert sim == physical_to_sim(p, ctx)
    back = sim_to_physical({**sim, "class": "metal"}, ctx)
    assert back.cls == "metal" and back.values["E"] == pytest.approx(2e11, rel=1e-12)
    with pytest.raises(ValueError):
        sim_to_physical(sim, ctx)
    # n has a default: a non-Newtonian material without it maps (the simulator uses 1)
    nn = physical_to_sim(
        {"mu": 5.0, "kappa": 2e9, "tau_Y": 100.0, "eta": 0.5}, ctx, cls="non_newtonian"
    )
    assert "n" not in nn and nn["tau_Y"] == pytest.approx(100.0 * math.sqrt(3.0), rel=1e-12)


def test_zero_gravity_keeps_every_map_finite_and_stable():
    ctx = SimContext(1 / 64, 0.04 / 64, 1000.0, 0.3, gravity=0.0)
    for cls in CLASSES:
        values = {n: _value(cls, n, 0.3) for n in MATERIALS[cls].names}
        sim = physical_to_sim(MaterialParams(cls, 1000.0, values), ctx)
        assert all(math.isfinite(v) and v > 0 for k, v in sim.items() if k != "nu"), (cls, sim)
        assert p_wave_speed(cls, sim) <= ctx.c_max * (1 + 1e-12)
        back = sim_to_physical(sim, ctx, cls)
        for k, v in values.items():
            assert back.values[k] == pytest.approx(v, rel=1e-9)


def test_non_newtonian_keys_follow_the_herschel_bulkley_model():
    # Catalogue mu (viscosity, Pa s) -> sim eta (flow-rule consistency); catalogue eta
    # (unitless) -> sim mu = eta * 0.375 * kappa_sim (unyielded shear modulus).
    ctx = SimContext(1 / 64, 0.04 / 64, 1300.0, 0.3)
    phys = {"mu": 2.0, "kappa": 2e9, "tau_Y": 150.0, "eta": 0.4, "n": 0.6}
    sim = physical_to_sim(phys, ctx, cls="non_newtonian")
    # below the viscosity knee K passes through; the solver's eta is K 2^((n+1)/2)
    assert sim["eta"] == pytest.approx(2.0 * 2.0 ** (1.6 / 2.0), rel=1e-12)
    assert sim["mu"] == pytest.approx(0.4 * 0.375 * sim["kappa"], rel=1e-12)
    # catalogue tau_Y = shear yield stress (rheometer); solver tau_Y = uniaxial von
    # Mises yield stress, whose shear yield is tau_Y / sqrt(3).
    assert sim["tau_Y"] == pytest.approx(150.0 * math.sqrt(3.0), rel=1e-12) and sim["n"] == 0.6
    # A stiffer unyielded paste (larger eta) raises the shear modulus, nothing else.
    sim2 = physical_to_sim({**phys, "eta": 0.8}, ctx, cls="non_newtonian")
    assert sim2["mu"] > sim["mu"] and sim2["eta"] == sim["eta"]
    assert p_wave_speed("non_newtonian", {**sim2, "density": 1300.0}) <= ctx.c_max
