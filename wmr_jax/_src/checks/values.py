"""Checks of single arguments: integers, numbers, flags, keys, paths, ``dt``.

Each names the argument, the value it got and what is allowed, and raises
``ValueError``; a JAX tracer cannot be inspected and passes.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import jax
import numpy as np

MAX_STEPS = 2**31 - 1  # a scan's length is an int32
MAX_TEMPERATURE = 10.0
# Far below, the relaxed switches' arguments would leave the float32 range.
MIN_TEMPERATURE = 1e-12
_FLOAT64_HINT = ", or float64 (jax.config.update('jax_enable_x64', True))"


def float_dtype() -> Any:
    """Return JAX's default float dtype (float64 when ``jax_enable_x64`` is on)."""
    # jnp.result_type(float) without its cost: every check calls this.
    return jax.dtypes.canonicalize_dtype(np.float64)


def is_traced(tree: Any) -> bool:
    """Return whether any leaf of ``tree`` is a JAX tracer."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


def require_concrete(function: str, *trees: Any) -> None:
    """Refuse a traced argument of a ``function`` that computes on the host with values."""
    if is_traced(trees):
        raise ValueError(
            f"{function} is called with traced values (inside jax.jit, vmap or grad); allowed: "
            "concrete values: it computes on the host, so call it outside the transformation "
            "(rollout, batch_rollout, final_poses and the metrics run inside one)"
        )


def array_kind(value: Any) -> str:
    """Return the dtype kind NumPy gives ``value``, ``"b"`` if any element is a bool.

    ``np.asarray([30, 30, True])`` is an integer array, the bool no longer seen.
    """
    kind = np.asarray(value).dtype.kind
    if kind in "iufO" and _holds_bool(value):
        return "b"
    return kind


def real_array(name: str, value: Any, allowed: str, *, objects: bool = False) -> np.ndarray:
    """Return ``value`` as a float64 NumPy array of real numbers, else raise naming it.

    ``None``, bools, complex numbers and strings are refused (NumPy would read
    ``True`` as 1 and ``"1.5"`` as 1.5); ``objects``: also take an object
    array whose items convert (Python integers beyond int64).
    """
    try:
        if value is None or array_kind(value) not in ("iufO" if objects else "iuf"):
            raise TypeError(value)
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        shown = described(value)
        raise ValueError(f"{name} = {shown} is not allowed; allowed: {allowed}") from None


def described(value: Any) -> str:
    """Return ``repr(value)`` on one line, or its type, shape and dtype if it is a large array."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 1024:
        return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    shape, dtype = getattr(value, "shape", None), getattr(value, "dtype", None)
    if shape is not None and dtype is not None and int(np.prod(shape)) > 6:
        return f"{type(value).__name__} of shape {tuple(shape)} and dtype {dtype}"
    if isinstance(value, (str, bytes)):  # shown as given, its spaces kept
        return repr(value)
    return " ".join(repr(value).split())  # an array's repr has a line per row, nested or not


def _holds_bool(value: Any) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return True
    dtype = getattr(value, "dtype", None)  # a NumPy or JAX array of bools among numbers
    if dtype is not None and np.dtype(dtype).kind == "b":
        return True
    if isinstance(value, (list, tuple)):
        return any(_holds_bool(item) for item in value)
    if isinstance(value, np.ndarray) and value.dtype.kind == "O":
        return any(_holds_bool(item) for item in value.flat)
    return False


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """Return ``value`` as an ``int`` in ``[minimum, maximum]`` (not a bool)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer))
    if not ok or value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise ValueError(
            f"{name} = {value!r} is not allowed; allowed: an integer >= {minimum}{upper}"
        )
    return int(value)


def check_substeps(value: Any) -> int:
    """Return the non-ideal loop's ``substeps`` after checking it in the compute dtype.

    Beyond ``1 / (1000 eps)`` sub-steps (8388 in float32) the rounding of
    each addition to the pose swamps a visible part of the motion.
    """
    dtype = np.dtype(float_dtype())
    most = int(1 / (1000 * float(np.finfo(dtype).eps)))
    value = check_int("substeps", value, 1, MAX_STEPS)
    if value > most:
        raise ValueError(
            f"substeps = {value!r} is not allowed in {dtype.name}, whose rounding over that many "
            f"sub-steps per period swamps their motion; allowed: an integer >= 1 and <= {most}"
            + (_FLOAT64_HINT if dtype != np.float64 else "")
        )
    return value


def check_bool(name: str, value: Any) -> bool:
    """Return ``value`` if it is ``True`` or ``False`` (``"no"`` is not a way of saying no)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: True or False")
    return bool(value)


def check_callable(name: str, value: Any) -> Any:
    """Return ``value`` if it is ``None`` or can be called (a progress callback)."""
    if value is not None and not callable(value):
        raise ValueError(f"{name} = {value!r:.80} is not allowed; allowed: a function or None")
    return value


def check_key(name: str, key: Any) -> Any:
    """Return ``key`` if it is a ``jax.random`` key (new style, or a legacy ``uint32[2]``)."""
    if is_traced(key):
        return key
    typed = isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    legacy = np.shape(key) == (2,) and np.asarray(key).dtype == np.uint32
    if not (typed or legacy):
        raise ValueError(
            f"{name} = {key!r:.80} is not allowed; allowed: a jax.random key (jax.random.key(seed))"
        )
    return key


def check_budget(name: str, value: Any) -> float:
    """Return a wall-time budget in s: a finite number ``>= 0`` (0: one round only)."""
    return check_number(name, value, closed=True, high=1e9, unit="s")


def check_path(name: str, value: Any) -> Path:
    """Return ``value`` as a ``Path`` if it is a non-empty ``str`` or ``os.PathLike``."""
    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text:
        raise ValueError(f"{name} = {value!r:.80} is not allowed; allowed: a path (str or Path)")
    return Path(text)


def check_folder(name: str, value: Any) -> Path:
    """Return ``value`` as a folder this process can create or write in, checked now."""
    from wmr_jax._src.io import writable_path

    return writable_path(f"{name} = {os.fspath(check_path(name, value))!r}", value, folder=True)


def check_number(
    name: str,
    value: Any,
    *,
    low: float = 0.0,
    high: float = math.inf,
    closed: bool = False,
    unit: str = "",
) -> float:
    """Return ``value`` as a float in ``(low, high)``, or ``[low, high)`` if ``closed``."""
    try:
        # Python would read True as 1 and "0.5" as 0.5.
        if isinstance(value, (bool, np.bool_, str, bytes)) or np.iscomplexobj(value):
            raise TypeError(value)
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


def check_temperature(name: str, value: Any) -> float:
    """Return a smooth-law temperature as a float in ``[MIN_TEMPERATURE, MAX_TEMPERATURE)``.

    Far above 1 the relaxation no longer resembles the law (docs/model.md §3).
    """
    return check_number(name, value, low=MIN_TEMPERATURE, closed=True, high=MAX_TEMPERATURE)


def check_dt(dt: Any) -> Any:
    """Return the control period ``dt`` as a float: finite, > 0, and so in the compute dtype.

    A period the compute dtype rounds to zero or infinity is refused here.
    """
    if isinstance(dt, jax.core.Tracer):
        return dt
    value = check_number("dt", dt, unit="s")
    info = np.finfo(np.dtype(float_dtype()))
    if not float(info.tiny) <= value <= float(info.max):
        raise ValueError(
            f"dt = {dt!r} is not allowed in {info.dtype.name}; allowed: a number "
            f"between {float(info.tiny):.3g} and {float(info.max):.3g} s"
        )
    return value
