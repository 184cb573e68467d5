"""Tune the controller's gains under k_r + L k_θ ≤ V_max and compare, with the hard law.

The flags and outputs of ``wmr-jax tune`` (see ``wmr_jax.tuning``)::

    python experiments/tune_gains.py --out results/tune
    python experiments/tune_gains.py --out results/tune-nonideal --velocity nonideal
    python experiments/tune_gains.py --out results/tune --resume     # after a kill

``experiments/gradient_cost.py`` measures what the tuner's gradient costs.
"""

import sys

from wmr_jax.cli import main

if __name__ == "__main__":
    sys.exit(main(["tune", *sys.argv[1:]]))
