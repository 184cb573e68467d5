"""Reproduce the paper's Figs. 6–10 and their table (``wmr-jax paper``).

Usage: ``python experiments/paper_figures.py [DIR]`` (default ``results/``).
"""

import sys

from wmr_jax.cli import main

if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "results"
    sys.exit(main(["paper", "--out", out]))
