"""Learning-rate schedule of the optimisation loop: linear warm-up, then cosine decay.

The schedule is a pure function of the iteration index (no hidden state), so a resumed
run takes exactly the steps an uninterrupted one takes.
"""

from __future__ import annotations

import math

__all__ = ["FINAL_RATIO", "lr_factor", "learning_rates"]

FINAL_RATIO = 0.1
"""The rate at the last iteration, as a fraction of the base rate. Decaying to zero
would waste the last iterations; a tenth keeps them useful for fine convergence."""


def lr_factor(iteration: int, total: int, warmup: int, final_ratio: float = FINAL_RATIO) -> float:
    """Multiplier of the base learning rate at 0-based ``iteration`` of ``total``.

    Warm-up: ``(iteration + 1) / (warmup + 1)`` for the first ``warmup`` iterations.
    Then a half cosine from 1 to ``final_ratio`` over the remaining iterations.
    """
    if iteration < 0:
        raise ValueError(f"iteration must be >= 0, got {iteration}")
    if iteration < warmup:
        return (iteration + 1) / (warmup + 1)
    span = max(1, total - warmup - 1)
    progress = min(1.0, (iteration - warmup) / span)
    return final_ratio + (1.0 - final_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def learning_rates(
    names: list[str],
    base: float,
    per_param: dict[str, float],
    iteration: int,
    total: int,
    warmup: int,
) -> dict[str, float]:
    """Learning rate of each named parameter at ``iteration`` (per-parameter base rates
    from ``optimize.lr_per_param`` override ``optimize.lr``)."""
    f = lr_factor(iteration, total, warmup)
    return {n: per_param.get(n, base) * f for n in names}
