"""Tune the controller's gains under k_r + L k_θ ≤ V_max and compare, with the hard law.

The flags and outputs of ``wmr-jax tune`` (see ``wmr_jax.tuning``)::

    python experiments/tune_gains.py --out results/tune
    python experiments/tune_gains.py --out results/tune-nonideal --velocity nonideal
    python experiments/tune_gains.py --out results/tune --resume     # after a kill

``--gradient-cost`` instead measures the loss gradient of a 4,096-pose ×
150-step batch (time against the forward pass, XLA's peak memory, with and
without ``jax.checkpoint`` on the scan body) into ``OUT/gradient_cost.json``.
"""

import sys

from wmr_jax.cli import main

if __name__ == "__main__":
    sys.exit(main(["tune", *sys.argv[1:]]))
