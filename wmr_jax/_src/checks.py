"""Boundary checks: every user input is checked here, in plain Python, before tracing.

Each check names the argument, the value it got and what is allowed, and
raises ``ValueError``; the rest of the package calls these and has no checks
of its own. Values that are JAX tracers (a caller running the library inside
their own ``jit`` or ``grad``) cannot be inspected and pass through unchecked.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "as_float_tree",
    "as_poses",
    "check_dt",
    "check_int",
    "check_number",
    "field_values",
    "float_dtype",
    "is_traced",
    "require",
]


def float_dtype() -> Any:
    """Return JAX's default float dtype (float64 when ``jax_enable_x64`` is on)."""
    return jnp.result_type(float)


def is_traced(tree: Any) -> bool:
    """Return whether any leaf of ``tree`` is a JAX tracer."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """Return ``value`` as an ``int`` in ``[minimum, maximum]``.

    Raises:
        ValueError: for a bool, a non-integer or a value out of range.
    """
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer))
    if not ok or value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise ValueError(
            f"{name} = {value!r} is not allowed; allowed: an integer >= {minimum}{upper}"
        )
    return int(value)


def check_number(
    name: str,
    value: Any,
    *,
    low: float = 0.0,
    high: float = math.inf,
    closed: bool = False,
    unit: str = "",
) -> float:
    """Return ``value`` as a float in ``(low, high)``, or ``[low, high)`` if ``closed``.

    Raises:
        ValueError: for a non-number, NaN or a value out of range.
    """
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    above = number >= low if closed else number > low
    if not (above and number < high):
        sign = ">=" if closed else ">"
        upper = f" and < {high:.6g}" if math.isfinite(high) else ""
        suffix = f" {unit}" if unit else ""
        raise ValueError(
            f"{name} = {value!r} is not allowed; allowed: a number {sign} {low:g}{upper}{suffix}"
        )
    return number


def check_dt(dt: Any) -> Any:
    """Return the control period ``dt`` as a float after checking it is finite and > 0."""
    if isinstance(dt, jax.core.Tracer):
        return dt
    return check_number("dt", dt, unit="s")


def _shown(arr: np.ndarray, bad: np.ndarray) -> str:
    """Describe the offending value(s) of ``arr`` (a scalar, or one example)."""
    if arr.ndim == 0:
        return repr(float(arr))
    return f"array of shape {arr.shape} (e.g. {float(arr[bad].reshape(-1)[0])!r})"


def require(name: str, value: np.ndarray | None, ok: Any, allowed: str) -> None:
    """Raise unless ``ok`` holds everywhere; ``value`` ``None`` (a tracer) passes."""
    if value is None:
        return
    ok = np.asarray(ok)
    if not np.all(ok):
        raise ValueError(f"{name} = {_shown(value, ~ok)} is not allowed; allowed: {allowed}")


def field_values(
    obj: Any, cls: type, prefix: str, *, skip: tuple[str, ...] = ()
) -> dict[str, np.ndarray | None]:
    """Return the numeric fields of a parameter dataclass as checked NumPy arrays.

    Every field not in ``skip`` must be a finite number, a scalar or with one
    leading batch axis; tracers map to ``None`` (not checkable).

    Args:
        obj: the instance to check.
        cls: the class it must be (``Gains``, ``Robot``, ...).
        prefix: the argument's name in messages (``"gains"``, ``"robot"``).
        skip: fields that are not numbers (static flags).

    Raises:
        ValueError: naming the field, its value and what is allowed.
    """
    if not isinstance(obj, cls):
        raise ValueError(f"{prefix} is a {type(obj).__name__}; allowed: a wmr_jax.{cls.__name__}")
    out: dict[str, np.ndarray | None] = {}
    for field in dataclasses.fields(cls):
        if field.name in skip:
            continue
        name, value = f"{prefix}.{field.name}", getattr(obj, field.name)
        if isinstance(value, jax.core.Tracer):
            out[field.name] = None
            continue
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(
                f"{name} = {value!r} is not allowed; allowed: a finite number"
            ) from None
        if arr.ndim > 1:
            raise ValueError(
                f"{name} has shape {arr.shape}; allowed: a scalar or one leading batch axis"
            )
        require(name, arr, np.isfinite(arr), "a finite number")
        out[field.name] = arr
    return out


def as_poses(name: str, value: Any, *, batch: bool | None) -> jax.Array:
    """Return ``value`` as a float pose array after checking shape and finiteness.

    Args:
        name: the argument's name, for error messages.
        value: a pose ``(3,)`` or, where ``batch`` allows, a batch ``(N, 3)``.
        batch: ``False`` for a single pose, ``True`` for ``(N, 3)``, ``None`` for either.

    Raises:
        ValueError: naming the argument, its shape or bad value, and what is allowed.
    """
    if isinstance(value, jax.core.Tracer):
        return value
    if isinstance(value, jax.Array):
        arr = value.astype(float_dtype()) if value.dtype != float_dtype() else value
        host = None
    else:
        try:
            host = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be numbers [x cm, y cm, theta rad]: {err}") from err
        arr = None
    shape = tuple((arr if arr is not None else host).shape)
    allowed = {False: "(3,)", True: "(N, 3) with N >= 1", None: "(3,) or (N, 3)"}[batch]
    ok_ndim = {False: (1,), True: (2,), None: (1, 2)}[batch]
    if len(shape) not in ok_ndim or shape[-1] != 3 or (len(shape) == 2 and shape[0] == 0):
        raise ValueError(f"{name} has shape {shape}; allowed: {allowed} [x cm, y cm, theta rad]")
    if arr is not None:
        # Concrete, but maybe closed over by a caller's jit: check it eagerly.
        with jax.ensure_compile_time_eval():
            finite = bool(jnp.all(jnp.isfinite(arr)))
    else:
        finite = bool(np.isfinite(host).all())
    if not finite:
        flat = np.asarray(arr if arr is not None else host).reshape(-1, 3)
        row = int(np.flatnonzero(~np.isfinite(flat).all(axis=1))[0])
        where = f"{name}[{row}]" if len(shape) == 2 else name
        raise ValueError(f"{where} = {flat[row].tolist()} is not finite; allowed: finite numbers")
    return arr if arr is not None else jnp.asarray(host, dtype=float_dtype())


def as_float_tree(tree: Any) -> Any:
    """Convert every concrete leaf to an array of the default float dtype.

    Python floats, NumPy scalars and arrays then all reach ``jit`` with one
    signature, so changing a gain's type does not recompile.
    """
    dtype = float_dtype()

    def convert(leaf):
        if isinstance(leaf, jax.core.Tracer):
            return leaf
        if isinstance(leaf, jax.Array):
            return leaf if leaf.dtype == dtype else leaf.astype(dtype)
        # Host values stay NumPy: jit transfers them with the call, which is
        # much cheaper than one device transfer per leaf here.
        return np.asarray(leaf, dtype)

    return jax.tree.map(convert, tree)
