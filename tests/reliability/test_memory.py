"""A 200-iteration optimisation does not grow in resident memory.

``fit`` of the tiny sphere (100 particles, 8^3 grid, 3 frames, 8 substeps) against a
trajectory made by ``simulate``, ``trajectory_match`` loss, gradients through every
substep, log.jsonl and checkpoint.pt written every iteration: the real loop, simulator
bridge and writer. Resident memory (``/proc/self/statm``) is sampled after every
iteration. The first :data:`WARMUP` iterations are excluded (Warp kernel loading, the
allocator reaching its working set); from there to the end the growth must stay below
:data:`BOUND_MIB`. What legitimately grows is the in-memory history (one record per
iteration, ~2 KiB: ~0.4 MiB over 200), so the bound leaves an order of magnitude of
allocator noise and still catches a leak of one rollout tape or renderer buffer per
iteration (this problem's tape alone is ~1 MiB: 200 of them would be ~200 MiB).
"""

from __future__ import annotations

import json
import os

import pytest
import yaml
from test_resume import TINY

from motionphysics.cli import main
from motionphysics.events import NullObserver

ITERATIONS = 200
WARMUP = 20
BOUND_MIB = 16.0


def rss_mib() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


class RssSampler(NullObserver):
    def __init__(self):
        self.samples: list[tuple[int, float]] = []

    def iteration_done(self, iteration, record):
        self.samples.append((int(iteration), rss_mib()))


@pytest.mark.slow  # ~1-3 min on a shared CPU
def test_200_iterations_do_not_grow_resident_memory(tmp_path):
    from motionphysics.optimize.fit import run_fit
    from motionphysics.runconfig import load_run_config

    true = {**TINY, "material": {"class": "elastic", "density": 1000.0, "E": 2.0e7, "nu": 0.3}}
    (tmp_path / "true.yaml").write_text(yaml.safe_dump(true))
    assert (
        main(["--quiet", "simulate", str(tmp_path / "true.yaml"), "--out", str(tmp_path / "ref")])
        == 0
    )
    start = {
        **TINY,
        "material": {"class": "elastic", "density": 1000.0, "E": 2.0e9, "nu": 0.3},
        # tolerance 0: no early stop, all 200 iterations run
        "optimize": {"params": ["E"], "lr": 0.05, "warmup": 0, "boost": 1, "tolerance": 0.0},
    }
    (tmp_path / "start.yaml").write_text(yaml.safe_dump(start))
    cfg = load_run_config(str(tmp_path / "start.yaml"), {})
    sampler = RssSampler()
    result = run_fit(
        cfg,
        tmp_path / "ref" / "trajectory.npz",
        tmp_path / "fit",
        iterations=ITERATIONS,
        observer=sampler,
    )
    assert result.params["fit"]["iterations_run"] == ITERATIONS
    rss = dict(sampler.samples)
    assert len(rss) == ITERATIONS
    growth = rss[ITERATIONS - 1] - rss[WARMUP]
    peak = max(v for i, v in rss.items() if i >= WARMUP) - rss[WARMUP]
    summary = {
        "rss_at_warmup_mib": round(rss[WARMUP], 1),
        "rss_final_mib": round(rss[ITERATIONS - 1], 1),
        "growth_mib": round(growth, 2),
        "peak_over_warmup_mib": round(peak, 2),
        "bound_mib": BOUND_MIB,
    }
    print("\nmemory:", json.dumps(summary))
    out = os.environ.get("MOTIONPHYSICS_MEMORY_OUT")
    if out:
        with open(out, "w") as f:
            json.dump({"samples": sampler.samples, **summary}, f)
    assert growth < BOUND_MIB and peak < BOUND_MIB, summary
