"""theta <-> physical values: round trips (hypothesis), bounds, gradients."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from motionphysics.materials.catalog import MATERIALS, spec, use_ranges
from motionphysics.materials.theta import Parameterisation

CLASSES = list(MATERIALS)


def _in_range(cls, name):
    ps = spec(cls, name)
    if ps.scale == "log":
        return (
            st.floats(math.log(ps.low), math.log(ps.high))
            .map(math.exp)
            .map(lambda x: min(max(x, ps.low), ps.high))
        )
    return st.floats(ps.low, ps.high)


@st.composite
def class_and_values(draw):
    cls = draw(st.sampled_from(CLASSES))
    names = (*MATERIALS[cls].names, "density")
    return cls, {n: draw(_in_range(cls, n)) for n in names}


@settings(max_examples=200, deadline=None)
@given(class_and_values())
def test_physical_theta_physical_round_trip(cv):
    cls, values = cv
    par = Parameterisation(cls, (*MATERIALS[cls].names, "density"))
    back = par.from_theta(par.to_theta(values))
    for name, x in values.items():
        ps = spec(cls, name)
        # Values within EPS (1e-6 of the range fraction) of a bound are moved onto
        # EPS; elsewhere float64 logit/sigmoid round trips to ~1e-12 relative.
        if ps.scale == "log":
            tol = 2e-6 * (math.log(ps.high) - math.log(ps.low))
            assert abs(math.log(float(back[name])) - math.log(x)) <= tol
        else:
            assert abs(float(back[name]) - x) <= 2e-6 * (ps.high - ps.low)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(CLASSES), st.lists(st.floats(-30, 30), min_size=5, max_size=5))
def test_theta_physical_theta_round_trip_and_bounds(cls, raw):
    par = Parameterisation(cls)
    theta = torch.tensor(raw[: len(par)], dtype=torch.float64)
    values = par.from_theta(theta)
    for ps in par.specs:
        v = float(values[ps.name])
        assert ps.low <= v <= ps.high
    # Inside |theta| < 13 the logit is well conditioned in float64 (sigmoid > 2e-6).
    inner = theta.clamp(-13, 13)
    back = par.to_theta(par.from_theta(inner))
    torch.testing.assert_close(back, inner, rtol=0, atol=1e-6)


def test_from_theta_is_differentiable_and_matches_finite_differences():
    par = Parameterisation("metal")
    theta = torch.tensor([0.3, -0.2, 1.1], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda t: torch.stack(list(par.from_theta(t).values())), (theta,)
    )


def test_names_subset_density_and_errors():
    par = Parameterisation("Metal", ["E", "density"])
    assert par.names == ("E", "density") and len(par) == 2
    lo, hi = par.bounds()
    # the extended table (the default) reaches down to lead's E
    assert lo.tolist() == [1e10, 10.0] and hi.tolist() == [4e11, 2.3e4]
    with use_ranges("paper"):  # a run with init.ranges: paper refines within the paper's
        lo, hi = Parameterisation("Metal", ["E", "density"]).bounds()
    assert lo.tolist() == [4.5e10, 10.0] and hi.tolist() == [4e11, 2.3e4]
    with pytest.raises(ValueError):
        Parameterisation("metal", ["mu"])
    with pytest.raises(ValueError, match="outside"):
        par.to_theta({"E": 1e12, "density": 7800})
    with pytest.raises(ValueError, match="missing"):
        par.to_theta({"E": 1e11})


def test_per_particle_values():
    par = Parameterisation("elastic")
    E = torch.tensor([1e7, 1e9, 4e11], dtype=torch.float64)
    nu = torch.tensor([0.1, 0.3, 0.5], dtype=torch.float64)
    theta = par.to_theta({"E": E, "nu": nu})
    assert theta.shape == (2, 3)
    back = par.from_theta(theta)
    torch.testing.assert_close(back["E"], E, rtol=1e-4, atol=0)
