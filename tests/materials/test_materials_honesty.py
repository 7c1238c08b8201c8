"""Physically impossible values, values kept as written, tagged substitutions, the
'behaves as another class' refusal of the sim map and simulation quantities' names."""

from __future__ import annotations

import math

import pytest

from motionphysics.errors import UserInputError
from motionphysics.materials.catalog import (
    PHYSICAL_LIMITS,
    check_physical,
    physical_problem,
    validate,
)
from motionphysics.materials.resolve import resolve_material
from motionphysics.materials.simmap import (
    SimContext,
    class_violations,
    mapped_substitutions,
    physical_to_sim,
    plan_substeps,
    sim_quantities,
    substeps_keeping_class,
    visible_changes,
)


def _cfl(values, dx, frame_dt):
    # Stand-in for the solver's CFL count (solids: P-wave speed), keeps the test off Warp.
    from motionphysics.materials.simmap import p_wave_speed

    c = float(p_wave_speed(values["class"], values))
    return max(1, math.ceil(frame_dt * c / (0.4 * dx)))


@pytest.mark.parametrize(
    "name, value",
    [
        ("E", -5.0),
        ("E", 0.0),
        ("E", float("nan")),
        ("nu", 0.75),
        ("nu", -1.0),
        ("density", 0.0),
        ("density", -3),
        ("mu", 0.0),
        ("mu", -1e-3),
        ("kappa", float("inf")),
        ("theta_fric", 95.0),
        ("tau_Y", -1),
        ("n", 0),
    ],
)
def test_impossible_values_are_errors_in_every_mode(name, value):
    assert physical_problem(name, value) is not None
    with pytest.raises(UserInputError) as err:
        check_physical(name, value, f"material.{name}")
    msg = str(err.value)
    assert msg.startswith(f"material.{name}: got ") and "\n" not in msg
    cls = {"mu": "newtonian", "kappa": "newtonian", "theta_fric": "sand", "n": "non_newtonian"}
    c = cls.get(name, "metal")
    vals = {"newtonian": {"mu": 1e-3, "kappa": 2e9}, "sand": {"theta_fric": 30.0}}.get(
        c, {"E": 2e11, "nu": 0.3, "tau_Y": 2e8}
    )
    if c == "non_newtonian":
        vals = {"mu": 1.0, "kappa": 2e9, "tau_Y": 100.0, "eta": 0.5}
    vals = {**vals, name: value} if name != "density" else vals
    rho = value if name == "density" else 1000.0
    for mode in ("clamp", "error", "keep"):
        with pytest.raises(UserInputError):
            validate(c, vals, density=rho, on_out_of_range=mode)


def test_limits_admit_the_whole_handbook():
    from motionphysics.materials.catalog import DENSITY, MATERIALS

    for mc in MATERIALS.values():
        for ps in (*mc.params, DENSITY):
            assert ps.name in PHYSICAL_LIMITS
            for v in (ps.low, ps.high):
                assert physical_problem(ps.name, v) is None, (mc.name, ps.name, v)


def test_written_values_used_as_written_with_one_warning():
    # 1e6 Pa (soft rubber) lies in the extended elastic range, below the paper's
    res = resolve_material("elastic", {"E": 1.0e6, "nu": 0.3, "density": 1000.0})
    assert res["material"].values["E"] == 1.0e6 and res["warnings"] == []
    res = resolve_material("elastic", {"E": 1.0e6, "nu": 0.3, "density": 1000.0}, ranges="paper")
    assert res["material"].values["E"] == 1.0e6
    assert res["clamps"] == []
    assert len(res["warnings"]) == 1 and "material.E" in res["warnings"][0]
    assert "used as written" in res["warnings"][0] and res["sources"]["E"] == "config"
    assert "(1e7 - 4e11 Pa)" in res["warnings"][0]
    res = resolve_material("elastic", {"E": 200.0, "nu": 0.3, "density": 1000.0})
    assert res["material"].values["E"] == 200.0 and "(1e3 - 4e11 Pa)" in res["warnings"][0]
    foam = resolve_material(
        "foam", {"E": 1.0e3, "tau_Y": 100.0, "nu": 0.2, "eta": 0.5, "density": 30.0}
    )
    assert foam["material"].values["tau_Y"] == 100.0


def test_estimates_stay_clamped_and_tagged():
    est = {
        "class": "elastic",
        "density": 1100.0,
        "params": {"E": 5.0e5, "nu": 0.45},
        "backend": "llm",
        "clamps": [],
    }
    res = resolve_material(None, {}, estimate=est, ranges="paper")
    assert res["material"].values["E"] == 1.0e7
    (c,) = res["clamps"]
    assert c["kind"] == "clamped" and c["source"] == "llm" and c["original"] == 5.0e5
    # the extended table (the default) holds 5e5 Pa; below its floor an estimate is clamped
    assert resolve_material(None, {}, estimate=est)["clamps"] == []
    est_gel = {**est, "params": {"E": 50.0, "nu": 0.45}}
    (c,) = resolve_material(None, {}, estimate=est_gel)["clamps"]
    assert (c["original"], c["clamped"], c["kind"]) == (50.0, 1e3, "clamped")
    # A backend's own floor substitution keeps its tag.
    est2 = {
        **est,
        "params": {"E": 1.0e7, "nu": 0.45},
        "backend": "kb",
        "clamps": [{"field": "E", "original": 1e4, "clamped": 1e7, "kind": "range floor"}],
    }
    res2 = resolve_material(None, {}, estimate=est2)
    assert res2["clamps"][0]["kind"] == "range floor"
    # A config value replaces the estimate: the estimate's clamp is no longer shown.
    res3 = resolve_material(None, {"E": 2e7}, estimate=est2)
    assert res3["clamps"] == [] and res3["sources"]["E"] == "config"


def test_params_file_values_are_written_values():
    base = {"class": "metal", "density": 7800.0, "params": {"E": 1e12, "nu": 0.3, "tau_Y": 1e9}}
    res = resolve_material(None, {}, base={**base, "origin": "m.json"})
    assert res["material"].values["E"] == 1e12 and res["sources"]["E"] == "params file"
    assert len(res["warnings"]) == 1 and "m.json" in res["warnings"][0]
    with pytest.raises(UserInputError, match="m.json.nu"):
        resolve_material(
            None, {}, base={**base, "params": {**base["params"], "nu": 0.7}, "origin": "m.json"}
        )


STEEL = validate("metal", {"E": 4.0e11, "nu": 0.3, "tau_Y": 2.0e9}, density=7800)[0]
RUBBER = validate("elastic", {"E": 1.5e7, "nu": 0.4}, density=1100)[0]
CLAY = validate("plasticine", {"E": 2e6, "nu": 0.35, "tau_Y": 1e4}, density=1500)[0]
GEOM = dict(dx=1.0 / 64, frame_dt=0.04, length=0.3, gravity=9.8)


def test_steel_with_five_substeps_is_refused_with_what_is_needed():
    with pytest.raises(UserInputError) as err:
        plan_substeps(STEEL, 5, cfl_substeps=_cfl, **GEOM)
    msg = str(err.value)
    assert msg.startswith("sim.substeps: with substeps 5 this metal is simulated with E = ")
    assert "flows like dough" in msg and "use `substeps: auto` (" in msg
    least = int(msg.rsplit("at least ", 1)[1])
    # The count it names is the smallest that works.
    assert plan_substeps(STEEL, least, cfl_substeps=_cfl, **GEOM).substeps == least
    with pytest.raises(UserInputError):
        plan_substeps(STEEL, least - 1, cfl_substeps=_cfl, **GEOM)


@pytest.mark.parametrize("mat", [STEEL, RUBBER, CLAY])
def test_auto_never_leaves_the_class(mat):
    for grid in (16, 32, 64, 128):
        geom = {**GEOM, "dx": 1.0 / grid}
        plan = plan_substeps(mat, "auto", cfl_substeps=_cfl, **geom)
        assert not class_violations(mat, plan.sim, plan.ctx)
        assert plan.substeps <= 2048  # the default budget (sim.max_substeps)
        # Within the budget nothing visible changes; where the budget binds (rubber at
        # grid 128: 38 cells across a 0.3 m object) the run says so, with numbers.
        changes = visible_changes(mat, plan.sim, plan.ctx)
        assert plan.notes == [f"warning: sim.substeps: {c.text}" for c in changes]
        if grid <= 64:
            assert plan.notes == [], (grid, plan.notes)


def test_auto_says_when_the_cap_binds():
    geom = {**GEOM, "dx": 1.0 / 512, "length": 3.0}
    plan = plan_substeps(STEEL, "auto", cfl_substeps=_cfl, cap=600, **geom)
    assert plan.violations and len(plan.notes) == 1 and "capped at 600" in plan.notes[0]


def test_soft_values_written_by_a_person_are_not_refused():
    # A jelly written as E = 1e4 Pa sags in reality; the map is not to blame.
    jelly = validate("elastic", {"E": 1.0e4, "nu": 0.45}, density=1050, on_out_of_range="keep")[0]
    n = substeps_keeping_class(jelly, start=1, **GEOM)
    assert n is not None and n <= 64


def test_fluids_and_sand_have_no_refusal():
    water = validate("newtonian", {"mu": 1e-3, "kappa": 2.2e9}, density=1000)[0]
    sand = validate("sand", {"theta_fric": 35.0}, density=1600)[0]
    for m in (water, sand):
        ctx = SimContext(dx=1 / 64, dt=0.04 / 2, density=m.density, length=0.3)
        assert class_violations(m, physical_to_sim(m, ctx), ctx) == []


def test_non_newtonian_sim_quantities_have_their_own_names():
    paste = validate(
        "non_newtonian", {"mu": 500.0, "kappa": 2e9, "tau_Y": 200.0, "eta": 0.5}, density=1300
    )[0]
    ctx = SimContext(dx=1 / 32, dt=0.04 / 512, density=1300, length=0.1)
    sim = physical_to_sim(paste, ctx)
    rows = {r["key"]: r for r in sim_quantities("non_newtonian", sim)}
    assert rows["mu"]["name"] == "unyielded_shear_modulus" and rows["mu"]["unit"] == "Pa"
    assert rows["mu"]["pairs_with"] is None and rows["eta"]["pairs_with"] is None
    assert rows["tau_Y"]["pairs_with"] is None  # uniaxial vs shear yield stress
    names = [r["name"] for r in rows.values()]
    assert len(set(names)) == len(names)
    subs = mapped_substitutions(paste, sim)
    assert {c.field for c in subs} <= {"kappa", "n"}
    assert all(c.kind == "mapped to simulation" for c in subs)


def test_mapped_substitutions_for_compressed_steel():
    ctx = SimContext(dx=1 / 64, dt=0.04 / 512, density=7800, length=0.3)
    subs = mapped_substitutions(STEEL, physical_to_sim(STEEL, ctx))
    by = {c.field: c for c in subs}
    assert by["E"].original == 4e11 and by["E"].clamped < 1e10
    assert by["E"].to_dict()["kind"] == "mapped to simulation"
