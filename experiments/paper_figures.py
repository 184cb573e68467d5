"""Reproduce the paper's Figs. 6–10 and their table.

Usage: ``python experiments/paper_figures.py [DIR]`` (default ``results/``).
"""

import sys

from wmr_jax import paper

if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "results"
    result = paper.paper_figures(out)
    for case in ("kr=120", "kr=60"):
        print(case, result["summary"][case])
