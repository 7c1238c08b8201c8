"""Prior part of one LMD iteration (16 frames at 256², encode with grad, one guided
prediction, backward to the frames) on the recorded architectures with random weights.

    python benchmarks/bench_prior.py --model cogvideox-5b --size tiny [--device cpu] [--json]

The same as ``motionphysics bench prior``; see motionphysics.optimize.prior_bench.
"""

from __future__ import annotations

import argparse

from motionphysics.optimize.prior_bench import MODELS_BENCHED, run_prior_bench


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=MODELS_BENCHED, default="cogvideox-5b")
    ap.add_argument("--random-weights", action="store_true", default=True)
    ap.add_argument("--size", choices=("tiny", "full"), default="tiny")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    run_prior_bench(a.model, a.random_weights, a.device, a.json, size=a.size, repeats=a.repeats)


if __name__ == "__main__":
    main()
