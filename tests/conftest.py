"""Test configuration: float64 for reference comparisons.

JAX's default float32 path is exercised by tests that wrap themselves in
``jax.enable_x64(False)`` (see ``test_rollout.py::test_float32_*``).
"""

import math

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

PAPER_REFS_DEG = [
    (40.0, 0.0, -45.0),
    (30.0, 30.0, 0.0),
    (0.0, 40.0, 90.0),
    (-30.0, 30.0, 135.0),
    (-30.0, -30.0, 0.0),
    (0.0, -40.0, 0.0),
    (30.0, -30.0, 90.0),
]


@pytest.fixture
def paper_refs() -> np.ndarray:
    """The seven references of Fig. 7, ``(7, 3)`` in cm, cm, rad."""
    refs = np.array(PAPER_REFS_DEG)
    refs[:, 2] = np.radians(refs[:, 2])
    return refs


def random_refs(rng: np.random.Generator, n: int, r_min=5.0, r_max=80.0) -> np.ndarray:
    """References at distance ``r_min``–``r_max`` cm, any bearing, any heading (SPEC §6)."""
    dist = rng.uniform(r_min, r_max, n)
    bearing = rng.uniform(-math.pi, math.pi, n)
    heading = rng.uniform(-math.pi, math.pi, n)
    return np.stack([dist * np.cos(bearing), dist * np.sin(bearing), heading], axis=-1)
