"""Measure the simulator's throughput against its NumPy baselines (``wmr-jax bench``).

Usage: ``python experiments/benchmark.py [--sizes N ...] [--json FILE] ...``
(the flags of ``wmr-jax bench``; default sizes 1000 10000 100000, 100 steps,
float32, writes ``results/benchmark.json``).
"""

import sys

from wmr_jax.cli import main

if __name__ == "__main__":
    argv = sys.argv[1:]
    if "--json" not in argv:
        argv += ["--json", "results/benchmark.json"]
    sys.exit(main(["bench", *argv]))
