"""Measure the simulator's throughput against its NumPy baselines (``wmr-jax bench``).

Usage: ``python experiments/benchmark.py [--sizes N ...] [--json FILE] ...``
(the flags of ``wmr-jax bench``; default sizes 1000 10000 100000, 100 steps,
float32, writes ``results/benchmark.json``).
"""

import argparse
import sys

from wmr_jax import bench

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bench.configure_parser(parser)
    parser.set_defaults(json="results/benchmark.json")
    sys.exit(bench.run_cli(parser.parse_args()))
