"""Tune the controller's gains under k_r + L k_θ ≤ V_max and compare, with the hard law.

Same flags and outputs as ``wmr-jax tune`` (see ``wmr_jax.tuning``)::

    python experiments/tune_gains.py --out results/tune
    python experiments/tune_gains.py --out results/tune-nonideal --velocity nonideal
    python experiments/tune_gains.py --out results/tune --resume     # after a kill

``--gradient-cost`` instead measures the loss gradient of a 4,096-pose ×
150-step batch (time against the forward pass, XLA's peak memory, with and
without ``jax.checkpoint`` on the scan body) into ``OUT/gradient_cost.json``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from wmr_jax import io, tuning


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiment; return the exit status (2 for a bad flag)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    tuning.configure_parser(parser)
    parser.add_argument(
        "--gradient-cost",
        action="store_true",
        help="measure the gradient's time and memory (4096 poses x 150 steps) instead of tuning",
    )
    args = parser.parse_args(argv)
    try:
        if not args.gradient_cost:
            return tuning.run_cli(args)
        costs = [tuning.gradient_cost(remat=remat) for remat in (True, False)]
    except ValueError as err:
        print(f"tune_gains: error: {err}", file=sys.stderr)
        return 2
    io.atomic_write_json(Path(args.out) / "gradient_cost.json", [c._asdict() for c in costs])
    for c in costs:
        print(
            f"{c.poses} poses x {c.steps} steps, remat={c.remat}: forward {c.forward_s:.3f} s, "
            f"gradient {c.gradient_s:.3f} s ({c.gradient_s / c.forward_s:.1f}x); peak memory "
            f"forward {c.forward_peak_bytes / 2**20:.1f} MiB, "
            f"gradient {c.gradient_peak_bytes / 2**20:.1f} MiB"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
