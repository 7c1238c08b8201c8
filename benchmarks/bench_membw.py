"""Memory bandwidth of this machine, STREAM style, for the MPM bound in BENCHMARKS.md.

Two kernels over float32 arrays, split into ``--threads`` contiguous bands, one Python
thread per band (numpy's copy and add release the GIL on large arrays, so the bands run
in parallel), each band looping ``--loops`` times between two barriers:

- copy: ``dst[:] = src``            8 bytes moved per element (read + write);
- add:  ``c[:] = a + b``           12 bytes per element (two reads, one write).

Bytes are counted the STREAM way (a store counts once; the CPU's read-for-ownership of
the destination line is not counted), so the figure is comparable with published STREAM
numbers and is an upper bound for what a kernel that streams arrays can reach. Two
working-set sizes: ``--small-mb`` (default 6 MB, the size of the 20k-particle state:
cache-resident on a CPU with a large L3) and ``--large-mb`` (default 1536 MB: DRAM).
Prints one JSON object with the median of ``--repeats`` timed runs per kernel and size
(GB/s = 1e9 bytes per second).

    python benchmarks/bench_membw.py --threads 2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import threading
import time

import numpy as np


def _run(kind: str, arrays: list[np.ndarray], threads: int, loops: int) -> float:
    n = arrays[0].size
    bands = [(t * n // threads, (t + 1) * n // threads) for t in range(threads)]
    barrier = threading.Barrier(threads + 1)

    def work(lo: int, hi: int) -> None:
        views = [a[lo:hi] for a in arrays]
        barrier.wait()
        for _ in range(loops):
            if kind == "copy":
                np.copyto(views[1], views[0])
            else:
                np.add(views[0], views[1], out=views[2])
        barrier.wait()

    pool = [threading.Thread(target=work, args=band) for band in bands]
    for t in pool:
        t.start()
    barrier.wait()
    t0 = time.perf_counter()
    barrier.wait()
    dt = time.perf_counter() - t0
    for t in pool:
        t.join()
    per_elem = 8 if kind == "copy" else 12
    return per_elem * n * loops / dt / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--small-mb", type=float, default=6.0)
    ap.add_argument("--large-mb", type=float, default=1536.0)
    args = ap.parse_args()
    out: dict = {"threads": args.threads, "repeats": args.repeats, "load_average": []}
    for label, mb in (("small", args.small_mb), ("large", args.large_mb)):
        # working set = all arrays of the add kernel (3 arrays)
        n = int(mb * 1e6 / 4 / 3)
        arrays = [np.ones(n, np.float32), np.full(n, 2.0, np.float32), np.zeros(n, np.float32)]
        loops = max(1, int(2e9 / (12 * n)))  # ~2 GB moved per timed run
        res = {"working_set_mb": 12 * n / 1e6, "loops": loops}
        for kind in ("copy", "add"):
            _run(kind, arrays, args.threads, 1)  # warm-up (page faults)
            out["load_average"].append(os.getloadavg()[0])
            rates = [_run(kind, arrays, args.threads, loops) for _ in range(args.repeats)]
            res[f"{kind}_gb_s"] = statistics.median(rates)
            res[f"{kind}_gb_s_max"] = max(rates)
        out[label] = res
        del arrays
    print(json.dumps(out))


if __name__ == "__main__":
    main()
