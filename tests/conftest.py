"""Test configuration: float64 for reference comparisons.

JAX's default float32 path is exercised by tests that wrap themselves in
``jax.enable_x64(False)`` (e.g. ``test_rollout.py::test_float32_default_path_*``).
"""

import jax
import numpy as np
import pytest

import wmr_jax as w

jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper_refs() -> np.ndarray:
    """The seven references of Fig. 7, ``(7, 3)`` in cm, cm, rad."""
    return w.paper_refs()


def random_refs(seed: int, n: int, r_min: float = 5.0, r_max: float = 80.0) -> np.ndarray:
    """``n`` references of the evaluation set (``docs/model.md §6``), as float64 NumPy."""
    return np.asarray(w.sample_poses(seed, n, r_min=r_min, r_max=r_max, dtype=np.float64))
