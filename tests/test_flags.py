"""Flags without effect in a combination: errors or one warning line naming them."""

from __future__ import annotations

import pytest

from motionphysics.config import config_from_dict
from motionphysics.errors import UserInputError
from motionphysics.flags import check_run_flags, material_fully_given


def test_loss_without_prior_is_an_error():
    cfg = config_from_dict({})
    with pytest.raises(UserInputError, match=r"^--loss sds: has no effect without a video prior"):
        check_run_flags(cfg, {"loss": "sds"})
    with pytest.raises(UserInputError, match=r"^--iters 2:"):
        check_run_flags(cfg, {"iters": 2})
    assert check_run_flags(cfg, {"loss": "sds", "prior": "motion"}) == []


def test_init_llm_with_every_field_given_is_named():
    full = {"class": "elastic", "E": 2e7, "nu": 0.4, "density": 1100}
    cfg = config_from_dict({"material": full})
    assert material_fully_given(cfg.material)
    (w,) = check_run_flags(cfg, {"init": "llm"})
    assert w.startswith("warning: --init llm: has no effect") and "\n" not in w
    part = config_from_dict({"material": {"class": "elastic", "E": 2e7}})
    assert not material_fully_given(part.material) and check_run_flags(part, {"init": "llm"}) == []
    # n has a default: a non-Newtonian block without n is still complete.
    nn = {
        "class": "non_newtonian",
        "mu": 5.0,
        "kappa": 2e9,
        "tau_Y": 100.0,
        "eta": 0.5,
        "density": 1300,
    }
    assert material_fully_given(config_from_dict({"material": nn}).material)


def test_init_with_params_file_is_an_error():
    with pytest.raises(UserInputError, match="--init kb: has no effect with --params"):
        check_run_flags(config_from_dict({}), {"init": "kb", "params": "m.json"})
