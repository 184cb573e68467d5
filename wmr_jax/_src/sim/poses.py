"""Reference poses: the evaluation set of ``docs/model.md §6``, the paper's seven, the horizon.

``sample_poses`` is the one sampler of evaluation poses, so "the same seed"
means the same poses everywhere.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    MAX_STEPS,
    check_dt,
    check_int,
    check_number,
    float_dtype,
    position_limit,
)

# docs/model.md §6: the default evaluation set and horizon.
EVAL_R_MIN = 5.0  # cm
EVAL_R_MAX = 80.0  # cm
HORIZON_S = 6.0  # s
# One draw holds every pose in memory (12 bytes each in float32); larger sets
# are drawn in pieces, e.g. from jax.random.fold_in(key, i).
MAX_SAMPLES = 2**27

# docs/model.md §5: the references of the paper's Fig. 7, [x cm, y cm, θ degrees].
PAPER_REFS_DEG = (
    (40.0, 0.0, -45.0),
    (30.0, 30.0, 0.0),
    (0.0, 40.0, 90.0),
    (-30.0, 30.0, 135.0),
    (-30.0, -30.0, 0.0),
    (0.0, -40.0, 0.0),
    (30.0, -30.0, 90.0),
)


def paper_refs() -> np.ndarray:
    """Return the seven references of Fig. 7, ``(7, 3)`` in cm, cm, rad."""
    refs = np.array(PAPER_REFS_DEG)
    refs[:, 2] = np.radians(refs[:, 2])
    return refs


def sample_poses(
    key: Any,
    n: int,
    *,
    r_min: float = EVAL_R_MIN,
    r_max: float = EVAL_R_MAX,
    dtype: Any = None,
) -> jax.Array:
    """Draw ``n`` reference poses of the evaluation set, for a robot at ``(0, 0, 0)``.

    Distance uniform in ``[r_min, r_max]`` cm; bearing and heading uniform in
    ``[−π, π)`` (``docs/model.md §6``); drawn in float32 whatever the precision.

    Args:
        key: a JAX PRNG key, or an integer seed.
        n: number of poses.
        r_min: least distance, cm, ``>= 0``.
        r_max: largest distance, cm, ``>= r_min``.
        dtype: of the result; default JAX's default float dtype.

    Returns:
        ``(n, 3)`` poses ``[x cm, y cm, θ rad]``.

    Raises:
        ValueError: for a bad seed, count, distance range or dtype.
    """
    seed = None if isinstance(key, jax.Array) else check_int("seed", key, 0, 2**32 - 1)
    typed = seed is None and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    if seed is None and not typed and key.shape != (2,):
        # A seed as a JAX array, e.g. traced inside jit: JAX would fail on it as a key.
        raise ValueError(
            f"key = an array of shape {key.shape} and dtype {key.dtype} is not allowed; "
            "allowed: a JAX PRNG key (jax.random.key(seed), also inside jit), or an int seed"
        )
    n = check_int("n", n, 0, MAX_SAMPLES)
    r_min = check_number("r_min", r_min, closed=True, unit="cm")
    r_max = check_number("r_max", r_max, low=r_min, closed=True, unit="cm")
    limit = position_limit(np.float32)  # drawn in float32, whatever the result's dtype
    if r_max > limit:
        raise ValueError(f"r_max = {r_max!r} is not allowed; allowed: a distance <= {limit:.0e} cm")
    dtype = float_dtype() if dtype is None else dtype
    try:
        ok = np.dtype(dtype) in (np.dtype(np.float32), np.dtype(np.float64))
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"dtype = {dtype!r} is not allowed; allowed: float32 or float64")
    if np.dtype(dtype) == np.float64 and float_dtype() != np.float64:
        # JAX would hand back float32 without a word.
        raise ValueError(
            "dtype = float64 is not allowed while JAX computes in float32; allowed: float32, "
            "or float64 after jax.config.update('jax_enable_x64', True)"
        )
    key = key if seed is None else jax.random.key(seed)  # once every argument is checked
    poses = _draw(key, n, jnp.float32(r_min), jnp.float32(r_max))
    return poses.astype(dtype)


@functools.partial(jax.jit, static_argnums=1)
def _draw(key: jax.Array, n: int, r_min: jax.Array, r_max: jax.Array) -> jax.Array:
    k_dist, k_bearing, k_heading = jax.random.split(key, 3)
    dist = jax.random.uniform(k_dist, (n,), jnp.float32, r_min, r_max)
    bearing = jax.random.uniform(k_bearing, (n,), jnp.float32, -jnp.pi, jnp.pi)
    heading = jax.random.uniform(k_heading, (n,), jnp.float32, -jnp.pi, jnp.pi)
    return jnp.stack([dist * jnp.cos(bearing), dist * jnp.sin(bearing), heading], axis=-1)


def horizon_steps(dt: float, horizon: float = HORIZON_S) -> int:
    """Return the number of control periods that cover ``horizon`` s (default 6 s)."""
    dt = check_dt(dt)
    horizon = check_number("horizon", horizon, unit="s")
    # The slack keeps 6.0 / 0.033 = 181.8… at 182 despite rounding.
    steps = math.ceil(horizon / dt - 1e-9)
    if horizon < dt * (1 - 1e-9):  # it would be run as a whole period
        raise ValueError(
            f"horizon = {horizon!r} s is shorter than one control period (dt = {dt!r} s); "
            "allowed: horizon >= dt"
        )
    if steps > MAX_STEPS:
        raise ValueError(
            f"horizon = {horizon!r} s at dt = {dt!r} s is {steps} control periods; allowed: "
            f"at most {MAX_STEPS} (2^31 - 1) periods"
        )
    return steps
