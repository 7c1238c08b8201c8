"""Counting what the property tests tried (BENCHMARKS.md, "Reliability").

Each property adds to :data:`CASES` once per example it runs; at the end of the module
the counts are printed and, with ``MOTIONPHYSICS_RELIABILITY_OUT=FILE``, merged into a
JSON file. ``MOTIONPHYSICS_PROPERTY_EXAMPLES=N`` raises every property's example count
(default: a fast run for the default suite).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from reliability_cases import CASES, OUTCOMES


@pytest.fixture(scope="session", autouse=True)
def _report_cases():
    yield
    if not CASES:
        return
    out = os.environ.get("MOTIONPHYSICS_RELIABILITY_OUT")
    data = {"cases": dict(CASES), "outcomes": dict(OUTCOMES)}
    print("\nproperty cases:", json.dumps(data, sort_keys=True))
    if out:
        p = Path(out)
        old = json.loads(p.read_text()) if p.is_file() else {"cases": {}, "outcomes": {}}
        for k in ("cases", "outcomes"):
            for name, n in data[k].items():
                old[k][name] = old[k].get(name, 0) + n
        p.write_text(json.dumps(old, indent=1, sort_keys=True) + "\n")
