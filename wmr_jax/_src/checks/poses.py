"""Checks of poses: shape, finiteness, the dtype's range, huge headings reduced."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks.values import _FLOAT64_HINT, float_dtype, is_traced, real_array


def as_poses(
    name: str, value: Any, *, batch: bool | None, check_only: bool = False
) -> jax.Array | None:
    """Return ``value`` as a float pose array after checking shape and finiteness.

    Args:
        name: the argument's name, for error messages.
        value: a pose ``(3,)`` or, where ``batch`` allows, a batch ``(N, 3)``.
        batch: ``False`` for a single pose, ``True`` for ``(N, 3)``, ``None`` for either.
        check_only: only check, return ``None`` (no converted copy is made).
    """
    if isinstance(value, jax.core.Tracer):
        return value
    real = "real numbers [x cm, y cm, theta rad]"
    if isinstance(value, jax.Array):
        if value.dtype.kind in "bc":
            raise ValueError(f"{name} has dtype {value.dtype}; allowed: {real}")
        arr = value.astype(float_dtype()) if value.dtype != float_dtype() else value
        host = None
    else:
        host, arr = real_array(name, value, real, objects=True), None
    shape = tuple((arr if arr is not None else host).shape)
    allowed = {False: "(3,)", True: "(N, 3) with N >= 1", None: "(3,) or (N, 3)"}[batch]
    ok_ndim = {False: (1,), True: (2,), None: (1, 2)}[batch]
    if len(shape) not in ok_ndim or shape[-1] != 3 or (len(shape) == 2 and shape[0] == 0):
        raise ValueError(f"{name} has shape {shape}; allowed: {allowed} [x cm, y cm, theta rad]")
    limit = position_limit()
    dtype = np.dtype(float_dtype()).name
    problems = (
        (lambda rows: ~np.isfinite(rows), "is not finite; allowed: finite numbers"),
        (
            lambda rows: np.abs(rows[..., 2:]) > MAX_HEADING,
            f"has a heading beyond {MAX_HEADING:.0e} rad, where float64 no longer holds "
            "the angle modulo 2π; allowed: |theta| <= 1e+12 rad",
        ),
        (
            lambda rows: np.abs(rows[..., :2]) > limit,
            f"is too far for {dtype}; allowed: |x|, |y| <= {limit:.0e} cm (squared distances "
            f"must stay finite){_FLOAT64_HINT if dtype != 'float64' else ''}",
        ),
    )
    if arr is not None:
        # Maybe closed over by a caller's jit: checked eagerly, as one program.
        with jax.ensure_compile_time_eval():
            flags, reduced = _device_pose_checks(arr, limit)
            flags = [bool(f) for f in flags]
    else:
        flags = [bool(np.any(bad(host))) for bad, _ in problems]
    for flag, (bad, message) in zip(flags, problems, strict=True):
        if flag:
            _raise_row(name, shape, arr, host, bad, message)
    if arr is not None:
        return None if check_only else reduced
    if check_only:
        return None
    host = host.copy()
    host[..., 2] = reduce_heading(host[..., 2])
    return jnp.asarray(host, dtype=float_dtype())


@jax.jit
def _device_pose_checks(arr: jax.Array, limit: Any) -> tuple[tuple[jax.Array, ...], jax.Array]:
    """Whether each check of ``as_poses`` fails on a device array; the array, headings reduced."""
    flags = (
        ~jnp.all(jnp.isfinite(arr)),
        jnp.any(jnp.abs(arr[..., 2]) > MAX_HEADING),
        jnp.any(jnp.abs(arr[..., :2]) > limit),
    )
    return flags, arr.at[..., 2].set(reduce_heading(arr[..., 2]))


def _raise_row(name, shape, arr, host, bad, message: str):
    """Raise ``message`` naming the first pose (row) for which ``bad`` holds."""
    flat = np.asarray(arr if arr is not None else host, dtype=float).reshape(-1, 3)
    row = int(np.flatnonzero(np.asarray(bad(flat)).any(axis=1))[0])
    where = f"{name}[{row}]" if len(shape) == 2 else name
    raise ValueError(f"{where} = {flat[row].tolist()} {message}")


# Headings beyond this many radians are reduced modulo 2π on the way in: the
# rollouts' fast sine and cosine hold up to about 1e5 rad in float32.
HEADING_REDUCE_ABOVE = 1e4
# Beyond this a float64 heading is a multiple of 2π only to ±1e-4 rad and worse.
MAX_HEADING = 1e12


def reduce_heading(theta: Any) -> Any:
    """Return headings with ``|θ| > HEADING_REDUCE_ABOVE`` reduced to ``[−π, π)``."""
    if isinstance(theta, np.ndarray):
        wrapped = np.remainder(theta + np.pi, 2 * np.pi) - np.pi
        return np.where(np.abs(theta) > HEADING_REDUCE_ABOVE, wrapped, theta)
    wrapped = jnp.remainder(theta + jnp.pi, 2 * jnp.pi) - jnp.pi
    return jnp.where(jnp.abs(theta) > HEADING_REDUCE_ABOVE, wrapped, theta)


def position_limit(dtype: Any = None) -> float:
    """Return the largest ``|x|``, ``|y|`` (cm) a pose may have in ``dtype`` (default: compute).

    Squared distances must stay finite: ``(2 limit)² · 2`` below the dtype's
    largest number, rounded down to a power of ten.
    """
    largest = float(np.finfo(np.dtype(float_dtype() if dtype is None else dtype)).max)
    return float(10.0 ** math.floor(math.log10(math.sqrt(largest / 8))))


def as_pose_array(name: str, value: Any) -> Any:
    """Return ``value`` as checked float poses of any batch shape ``(..., 3)`` (tracers pass).

    The checks of ``as_poses``, for functions that broadcast poses.
    """
    if is_traced(value):
        return value
    arr = real_array(name, value, "real numbers (..., 3) [x cm, y cm, theta rad]", objects=True)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} has shape {arr.shape}; allowed: (..., 3) [x cm, y cm, theta rad]")
    if arr.ndim == 1:
        return as_poses(name, arr, batch=False)
    flat = arr.reshape(-1, 3)
    poses = as_poses(name, flat, batch=True) if flat.size else jnp.asarray(flat, float_dtype())
    return poses.reshape(arr.shape)
