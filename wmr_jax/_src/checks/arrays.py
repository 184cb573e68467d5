"""Checks of parameter fields and batches: values, batch axes, representable numbers.

``Parameters`` is the base of every parameter dataclass; ``field_values``
checks its fields, the ``batch_sizes`` family that batched arguments agree.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import numpy as np

from wmr_jax._src.checks.values import _FLOAT64_HINT, array_kind, float_dtype, real_array


def _shown(arr: np.ndarray, bad: np.ndarray) -> str:
    """Describe the offending value(s) of ``arr``: a scalar, or where the first one is."""
    if arr.ndim == 0:
        return repr(float(arr))
    where = np.argwhere(np.broadcast_to(bad, arr.shape))
    first = f"[{', '.join(str(int(i)) for i in where[0])}] = {float(arr[tuple(where[0])])!r}"
    if len(where) == 1:
        return f"array of shape {arr.shape} (element {first})"
    return f"array of shape {arr.shape} ({len(where)} of {arr.size} elements, e.g. {first})"


def require(name: str, value: np.ndarray | None, ok: Any, allowed: str) -> None:
    """Raise unless ``ok`` holds everywhere; ``value`` ``None`` (a tracer) passes."""
    if value is None or (ok if isinstance(ok, (bool, np.bool_)) else np.all(ok)):
        return
    ok = np.asarray(ok)
    raise ValueError(f"{name} = {_shown(value, ~ok)} is not allowed; allowed: {allowed}")


def field_values(
    obj: Any, cls: type, prefix: str, *, skip: tuple[str, ...] = ()
) -> dict[str, np.ndarray | None]:
    """Return the numeric fields of a parameter dataclass as checked NumPy arrays.

    Every field not in ``skip`` must be a finite number, a scalar or with one
    leading batch axis; tracers map to ``None``. ``prefix`` names ``obj`` in
    messages.
    """
    if not isinstance(obj, cls):
        raise ValueError(f"{prefix} is a {type(obj).__name__}; allowed: a wmr_jax.{cls.__name__}")
    out: dict[str, np.ndarray | None] = {}
    for field in dataclasses.fields(cls):
        if field.name in skip:
            continue
        name, value = f"{prefix}.{field.name}", getattr(obj, field.name)
        tracer = isinstance(value, jax.core.Tracer)
        out[field.name] = None if tracer else field_array(name, value)
    require_one_batch_size(
        {f"{prefix}.{k}": v.shape[0] for k, v in out.items() if v is not None and v.ndim}
    )
    return out


def field_array(name: str, value: Any, allowed: str = "a finite number") -> np.ndarray:
    """Return one parameter value as a checked float array: finite, representable, ndim <= 1."""
    arr = real_array(name, value, allowed, objects=True)
    if arr.ndim > 1 or arr.size == 0:
        raise ValueError(
            f"{name} has shape {arr.shape}; allowed: a scalar or one leading batch axis "
            "of size >= 1"
        )
    require(name, arr, np.isfinite(arr), allowed)
    require_representable(name, arr)
    return arr


def require_one_batch_size(sizes: dict[str, int]) -> int | None:
    """Return the common batch size ``N`` of ``sizes`` (name → size; 1 is shared), or ``None``."""
    if not sizes:
        return None
    n = max(sizes.values())
    if any(size not in (1, n) for size in sizes.values()):
        listed = ", ".join(f"{k}: {v}" for k, v in sizes.items())
        raise ValueError(f"batch sizes differ ({listed}); allowed: one common N, or 1")
    return n


def batch_sizes(trees: dict[str, Any], poses: dict[str, Any] | None = None) -> dict[str, int]:
    """The leading size of every batched input, by name (``refs``, ``gains.kr``, ...).

    ``trees``: name → parameter tree, leaves scalars or ``(N,)``; ``poses``:
    name → poses ``(3,)`` or ``(N, 3)``.
    """
    poses = poses or {}
    sizes = {name: np.shape(value)[0] for name, value in poses.items() if np.ndim(value) == 2}
    for prefix, tree in trees.items():
        for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
            if np.ndim(leaf) == 1:
                sizes[f"{prefix}{jax.tree_util.keystr(path)}"] = np.shape(leaf)[0]
    return sizes


def common_batch_size(trees: dict[str, Any], poses: dict[str, Any] | None = None) -> int:
    """The batch size ``N`` shared by every batched input (``batch_sizes``); 1 if none is."""
    return require_one_batch_size(batch_sizes(trees, poses)) or 1


def require_unbatched(tree: Any, prefix: str, allowed: str) -> None:
    """Raise unless every leaf of ``tree`` is a scalar, naming the first that is not."""
    for key, leaf in jax.tree_util.tree_leaves_with_path(tree):
        if np.ndim(leaf) >= 1:
            where = f"{prefix}{jax.tree_util.keystr(key)}"
            raise ValueError(f"{where} has shape {np.shape(leaf)}; allowed: {allowed}")


def require_finite_runs(
    finite: Any,
    dtype: Any,
    *,
    first: int = 0,
    allowed: str = "gains and dt that keep the sampled law stable (docs/model.md §4)",
) -> None:
    """Raise unless every run's flag in ``finite`` is set (a run that left the dtype's range).

    ``finite``: one flag per run (a scalar for a single run); ``first``: the
    batch row of its first flag, for the message.
    """
    finite = np.asarray(finite)
    if finite.all():
        return
    bad = np.flatnonzero(~finite.reshape(-1))
    where = "the run" if finite.ndim == 0 else f"{bad.size} run(s), e.g. run {first + int(bad[0])},"
    name = np.dtype(dtype).name
    wider = ", or float64" if name != "float64" else ""
    raise ValueError(
        f"{where} left the range of {name} (a pose became inf or NaN); allowed: {allowed}{wider}"
    )


@functools.cache
def _float_limits(dtype: np.dtype) -> tuple[float, float]:
    """``(largest, smallest normal)`` magnitude of a float dtype."""
    info = np.finfo(dtype)
    return float(info.max), float(info.tiny)


def require_representable(name: str, value: np.ndarray, *, tiny_ok: bool = False) -> None:
    """Raise unless ``value`` stays finite, and nonzero if it is, in the compute dtype.

    ``tiny_ok`` allows values below the smallest normal number (data, not parameters).
    """
    dtype = np.dtype(float_dtype())
    largest, tiny = _float_limits(dtype)
    if value.ndim == 0 and value.dtype.kind in "fiu":
        # One number: Python arithmetic, much cheaper than the array path.
        magnitude = abs(float(value))
        if magnitude <= largest and (tiny_ok or magnitude == 0 or magnitude >= tiny):
            return
    small = (value != 0) & (np.abs(value) < tiny) & (not tiny_ok)
    if np.any(small):
        raise ValueError(
            f"{name} = {_shown(value, small)} is below {dtype.name}'s smallest normal number "
            f"({tiny:.3g}); allowed: a magnitude of at least {tiny:.3g} (or 0, where the "
            "field allows 0)" + (_FLOAT64_HINT if dtype != np.float64 else "")
        )
    ok = np.abs(value) <= largest
    if not np.all(ok):
        wider = _FLOAT64_HINT if dtype != np.float64 else ""
        raise ValueError(
            f"{name} = {_shown(value, ~ok)} is beyond {dtype.name} (largest {largest:.3g}); "
            f"allowed: a smaller number{wider}"
        )


class Parameters:
    """What every parameter dataclass shares (``Gains``, ``Robot``, the baselines' gains).

    A list or tuple given for a field becomes one NumPy array (one batched
    field, not a pytree of leaves), and ``replace`` returns a changed copy.
    """

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            object.__setattr__(self, field.name, list_as_array(getattr(self, field.name)))

    def replace(self, **changes: Any) -> Any:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)


def list_as_array(value: Any) -> Any:
    """A list or tuple of numbers as one float NumPy array; anything else as it is."""
    if not isinstance(value, (list, tuple)):
        return value
    try:
        if array_kind(value) not in "iuf":
            return value
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return value


def as_float_tree(tree: Any) -> Any:
    """Convert every concrete leaf to the default float dtype: one ``jit`` signature for all."""
    dtype = float_dtype()

    def convert(leaf):
        if isinstance(leaf, jax.core.Tracer):
            return leaf
        if isinstance(leaf, jax.Array):
            return leaf if leaf.dtype == dtype else leaf.astype(dtype)
        # Host values stay NumPy: jit transfers them with the call, cheaper.
        return np.asarray(leaf, dtype)

    return jax.tree.map(convert, tree)
