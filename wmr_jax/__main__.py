"""``python -m wmr_jax`` runs the ``wmr-jax`` command line."""

import sys

from wmr_jax._src.cli.main import main

sys.exit(main())
