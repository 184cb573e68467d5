"""The ``wmr-jax`` command line as a function: ``main(["simulate", "--ref", ...])``."""

from wmr_jax._src.cli.main import main as main

if __name__ == "__main__":  # python -m wmr_jax.cli, as python -m wmr_jax
    raise SystemExit(main())
