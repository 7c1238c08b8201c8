"""The catalogue: the appendix table, class-name normalisation, validation and clamps."""

from __future__ import annotations

import math

import pytest

from motionphysics.config import MATERIAL_CLASSES
from motionphysics.errors import UserInputError
from motionphysics.materials.catalog import (
    DEFAULT_RANGES,
    DENSITY,
    MATERIALS,
    PAPER_MATERIALS,
    RANGE_TABLES,
    SOURCES,
    Clamp,
    active_ranges,
    check_ranges,
    class_id,
    materials,
    normalise_class,
    param_names,
    ranges,
    spec,
    use_ranges,
    validate,
)

# The paper's appendix table, transcribed independently of catalog.py.
PAPER_TABLE = {
    "elastic": {"E": (1e7, 4e11), "nu": (0.1, 0.5)},
    "plasticine": {"E": (1e6, 5e6), "nu": (0.3, 0.4), "tau_Y": (5e3, 2e4)},
    "metal": {"E": (4.5e10, 4.0e11), "nu": (0.25, 0.35), "tau_Y": (1e7, 2e9)},
    "foam": {"E": (1e3, 1e7), "nu": (0.0, 0.3), "tau_Y": (1e4, 1e6), "eta": (0.1, 1.0)},
    "sand": {"theta_fric": (27.0, 45.0)},
    "newtonian": {"mu": (1e-3, 10.0), "kappa": (1e9, 5e9)},
    "non_newtonian": {
        "mu": (1e-3, 1e3),
        "kappa": (1e9, 5e9),
        "tau_Y": (1.0, 2e3),
        "eta": (0.1, 1.0),
        "n": (0.3, 1.0),
    },
}


# The extended table (the default): the paper's ranges widened where they leave out what
# people name at the sizes they simulate (see catalog._EXTENSIONS for each reason).
EXTENDED_TABLE = {
    "elastic": {"E": (1e3, 4e11), "nu": (0.1, 0.5)},
    "plasticine": {"E": (1e5, 1e8), "nu": (0.3, 0.4), "tau_Y": (1e3, 1e6)},
    "metal": {"E": (1e10, 4.0e11), "nu": (0.25, 0.45), "tau_Y": (1e6, 2e9)},
    "foam": {"E": (1e3, 1e8), "nu": (0.0, 0.3), "tau_Y": (1e3, 1e6), "eta": (0.1, 1.0)},
    "sand": {"theta_fric": (20.0, 50.0)},
    "newtonian": {"mu": (1e-4, 1e4), "kappa": (1e9, 5e9)},
    "non_newtonian": {
        "mu": (1e-3, 1e4),
        "kappa": (1e9, 5e9),
        "tau_Y": (1.0, 1e4),
        "eta": (0.1, 1.0),
        "n": (0.2, 1.0),
    },
}


@pytest.mark.parametrize(
    "table, expected, classes",
    [("paper", PAPER_TABLE, PAPER_MATERIALS), ("extended", EXTENDED_TABLE, MATERIALS)],
)
def test_catalogue_matches_the_paper_table(table, expected, classes):
    assert tuple(classes) == MATERIAL_CLASSES
    assert materials(table) is classes
    for cls, params in expected.items():
        assert param_names(cls) == tuple(params), cls
        for name, (lo, hi) in params.items():
            ps = classes[cls].param(name)
            assert (ps.low, ps.high) == (lo, hi), (cls, name)
            assert ranges(cls, table).param(name) == ps
            assert spec(cls, name, table) == ps
            assert ps.source in SOURCES
            assert ps.scale in ("log", "linear")
    assert (DENSITY.low, DENSITY.high) == (10.0, 2.3e4)
    assert classes["non_newtonian"].param("n").default == 1.0
    assert [class_id(c) for c in MATERIAL_CLASSES] == list(range(7))


def test_range_tables_default_accessor_and_context():
    assert DEFAULT_RANGES == "extended" and RANGE_TABLES == ("extended", "paper")
    assert active_ranges() == "extended" and spec("elastic", "E").low == 1e3
    assert ranges("Elastic", "paper").param("E").low == 1e7
    with use_ranges("paper"):
        assert active_ranges() == "paper" and spec("elastic", "E").low == 1e7
        with use_ranges("extended"):
            assert ranges("jelly").param("E").low == 1e3  # aliases accepted
        with use_ranges(None):  # None leaves the active table as it is
            assert active_ranges() == "paper"
        p, clamps = validate("elastic", {"E": 5e3, "nu": 0.45}, density=1050)
        assert p.values["E"] == 1e7 and clamps == [Clamp("E", 5e3, 1e7)]
    assert active_ranges() == "extended"
    p, clamps = validate("elastic", {"E": 5e3, "nu": 0.45}, density=1050)
    assert p.values["E"] == 5e3 and clamps == []
    with pytest.raises(UserInputError, match=r"init\.ranges: expected one of extended, paper"):
        check_ranges("handbook")
    with pytest.raises(UserInputError):
        ranges("elastic", "handbook")


@pytest.mark.parametrize(
    "text, cls",
    [
        ("Metal", "metal"),
        ("Newtonian fluid", "newtonian"),
        ("non-newtonian", "non_newtonian"),
        ("Non-Newtonian fluid", "non_newtonian"),
        ("NON_NEWTONIAN", "non_newtonian"),
        ("Elastic", "elastic"),
        ("  sand ", "sand"),
        ("Foam", "foam"),
        ("Plasticine", "plasticine"),
        ("Metal (steel)", "metal"),
        ("elastic material", "elastic"),
    ],
)
def test_normalise_class_accepts_answer_spellings(text, cls):
    assert normalise_class(text) == cls


@pytest.mark.parametrize("bad", ["glass", "", None, 3, "newtonianish"])
def test_unknown_class_is_a_user_error(bad):
    with pytest.raises(UserInputError, match="class"):
        normalise_class(bad)


def test_validate_good_values_unchanged():
    p, clamps = validate("metal", {"E": 2e11, "nu": 0.3, "tau_Y": 2.5e8}, density=7850)
    assert clamps == []
    assert p.cls == "metal" and p.density == 7850.0
    assert p.values == {"E": 2e11, "nu": 0.3, "tau_Y": 2.5e8}
    assert p.to_dict() == {
        "class": "metal",
        "density": 7850.0,
        "E": 2e11,
        "nu": 0.3,
        "tau_Y": 2.5e8,
    }


def test_validate_density_inside_values_and_default_n():
    p, clamps = validate(
        "non-newtonian", {"density": 1300, "mu": 5.0, "kappa": 2e9, "tau_Y": 100.0, "eta": 0.5}
    )
    assert p.cls == "non_newtonian" and p.density == 1300.0
    assert p.values["n"] == 1.0 and clamps == []


def test_validate_clamps_and_records():
    p, clamps = validate("elastic", {"E": 1e13, "nu": 0.05}, density=5.0)
    assert p.values == {"E": 4e11, "nu": 0.1} and p.density == 10.0
    assert set(clamps) == {
        Clamp("E", 1e13, 4e11),
        Clamp("nu", 0.05, 0.1),
        Clamp("density", 5.0, 10.0),
    }


def test_validate_error_mode_names_the_field():
    with pytest.raises(UserInputError, match=r"cfg\.E: 1e\+13 is outside"):
        validate("elastic", {"E": 1e13, "nu": 0.3}, 1000, on_out_of_range="error", origin="cfg")


@pytest.mark.parametrize(
    "values, match",
    [
        ({"E": 1e9}, r"material\.nu: missing"),
        ({"E": 1e9, "nu": 0.3, "mu": 1.0}, "do not belong"),
        ({"E": float("nan"), "nu": 0.3}, "finite"),
        ({"E": math.inf, "nu": 0.3}, "finite"),
        ({"E": "1e9", "nu": 0.3}, "expected a number"),
        ({"E": True, "nu": 0.3}, "expected a number"),
    ],
)
def test_validate_rejects_bad_values(values, match):
    with pytest.raises(UserInputError, match=match):
        validate("elastic", values, 1000.0)


def test_validate_missing_density():
    with pytest.raises(UserInputError, match="density: missing"):
        validate("sand", {"theta_fric": 30.0})


def test_error_messages_are_one_line():
    for values in ({"E": 1e9}, {"E": 1e13, "nu": 0.3}):
        try:
            validate("elastic", values, 1000, on_out_of_range="error")
        except UserInputError as err:
            assert "\n" not in str(err)
        else:  # pragma: no cover - the call must fail
            pytest.fail("no error")
