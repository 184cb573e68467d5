"""The ``wmr-jax`` command line as a function: ``main(["simulate", "--ref", ...])``."""

from wmr_jax._src.cli.main import main as main
