"""``python -m wmr_jax``: the ``wmr-jax`` command line."""

from wmr_jax._src.cli.main import entry

entry()
