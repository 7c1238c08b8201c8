"""SIGKILL at a random point of ``run`` (plain, refinement with a cheap loss, the tiny
CogVideoX prior with ``lmd``) and ``fit``, then ``--resume``: status 0 and the final
parameters, theta, loss states (the LMD extractor, its AdamW moments and EMA) and
trajectory of an uninterrupted run, bit for bit. See ``faults.py`` (also the script
that produces the BENCHMARKS.md figures)."""

from __future__ import annotations

import random

import pytest
from faults import (
    CASES,
    ITERATIONS,
    differences,
    final_state,
    kill_and_resume,
    prepare,
    uninterrupted,
)


@pytest.fixture(scope="module")
def commands(tmp_path_factory):
    root = tmp_path_factory.mktemp("faults")
    return root, prepare(root)


@pytest.mark.slow  # three to five CLI processes per case at tiny size: ~1-3 min each
@pytest.mark.parametrize("case", CASES)
def test_sigkill_then_resume_ends_as_uninterrupted(commands, case):
    root, cmds = commands
    cmd = cmds[case]
    duration = uninterrupted(cmd, root / f"{case}-a")
    ref = final_state(root / f"{case}-a")
    rng = random.Random(f"kill-{case}")
    # one kill at a random time; for an optimising case one more inside the
    # optimisation (up to 0.15 s after a random iteration's log line)
    plans = [(rng.uniform(0.1, 0.9) * duration, None)]
    if case in ITERATIONS:
        plans.append((rng.uniform(0.0, 0.15), rng.randint(1, ITERATIONS[case] - 1)))
    for k, (delay, line) in enumerate(plans):
        out = root / f"{case}-kill{k}"
        trial = kill_and_resume(cmd, out, delay, after_log_lines=line)
        assert trial["resume_status"] == 0, trial
        if trial["killed"]:
            # killed after the final params.json, the run is complete: also an answer
            msg = trial["resume_message"]
            assert msg.startswith("motionphysics: "), trial
            assert any(w in msg for w in ("resuming", "nothing to resume", "already complete"))
        assert differences(ref, final_state(out)) == [], trial
