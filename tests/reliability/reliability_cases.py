"""Counters of the property tests (see conftest.py)."""

from __future__ import annotations

import os
from collections import Counter

CASES: Counter = Counter()
OUTCOMES: Counter = Counter()


def examples(default: int) -> int:
    """Examples per property: ``$MOTIONPHYSICS_PROPERTY_EXAMPLES`` or ``default``."""
    return int(os.environ.get("MOTIONPHYSICS_PROPERTY_EXAMPLES", default))
