"""The plug-in registry and the observer fan-out."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict

from motionphysics.errors import UserInputError
from motionphysics.events import Observer, Observers
from motionphysics.registry import Registry


class _Plugin:
    class Options(BaseModel):
        model_config = ConfigDict(extra="forbid")
        weight: float = 1.0


def test_registry_lazy_entry_resolves_and_caches():
    reg = Registry("thing", "cfg.thing", {"path": "os.path:join"})
    import os.path

    assert reg.get("path") is os.path.join
    assert reg.names() == ["path"]


def test_registry_unknown_name_lists_choices_and_suggests():
    reg = Registry("loss", "optimize.loss", {"lmd": _Plugin, "sds": _Plugin})
    with pytest.raises(UserInputError) as err:
        reg.get("lmdd")
    msg = str(err.value)
    assert "optimize.loss" in msg and "'lmdd'" in msg and "did you mean 'lmd'" in msg
    assert "lmd, sds" in msg


def test_registry_removed_name_is_refused_with_its_reason_and_never_listed():
    import argparse

    reg = Registry("video prior", "optimize.prior", {"a": _Plugin}, removed={"old": "gone (why)"})
    assert reg.names() == ["a"] and "old" not in reg
    with pytest.raises(UserInputError) as err:
        reg.get("old")
    assert str(err.value) == "optimize.prior: 'old': gone (why); expected one of a"
    # as argparse choices: the removed name reaches the command, the usage lists only "a"
    choices = reg.choices("none")
    assert list(choices) == ["none", "a"] and "old" in choices and "b" not in choices
    p = argparse.ArgumentParser(prog="x")
    p.add_argument("--prior", choices=choices)
    assert p.parse_args(["--prior", "old"]).prior == "old"
    assert "{none,a}" in p.format_usage()


def test_registry_options_validate_strictly():
    reg = Registry("loss", "optimize.losses[0]", {"lmd": _Plugin})
    assert reg.options("lmd", {"weight": 2}).weight == 2.0
    with pytest.raises(UserInputError, match="weigth"):
        reg.options("lmd", {"weigth": 2})


def test_observers_fan_out_in_order():
    seen = []

    class A(Observer):
        def frame_simulated(self, frame, frames):
            seen.append(("a", frame, frames))

    class B(Observer):
        def frame_simulated(self, frame, frames):
            seen.append(("b", frame, frames))

    obs = Observers([A(), B()])
    obs.frame_simulated(3, 10)
    obs.stage_started("simulate")  # a no-op on both
    assert seen == [("a", 3, 10), ("b", 3, 10)]
