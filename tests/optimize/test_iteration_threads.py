"""An optimisation iteration whose loss needs no render runs torch on one thread (many
small ops: with 2 threads on a busy machine the motion prior's predictions were up to
150x slower); a loss on rendered frames keeps the threads set; the count is restored."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from motionphysics.optimize.loop import iteration_threads


def test_a_states_loss_runs_on_one_thread_and_restores_the_count():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with iteration_threads(SimpleNamespace(needs_render=False)):
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with iteration_threads(SimpleNamespace(needs_render=True)):
            assert torch.get_num_threads() == 2
        try:
            with iteration_threads(SimpleNamespace(needs_render=False)):
                raise ValueError("an iteration that fails")
        except ValueError:
            pass
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
