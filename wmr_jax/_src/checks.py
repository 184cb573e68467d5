"""Boundary checks of user input, in plain Python before tracing.

Each names the argument, the value it got and what is allowed, and raises
``ValueError``; a JAX tracer cannot be inspected and passes unchecked.
``Parameters`` is the base of every parameter dataclass.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
import warnings
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
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
    refuse_traced(name, value, _ON_HOST)
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


_ON_HOST = "concrete values: it is checked on the host, so call this outside the transformation"
_STATIC = "a concrete number, which the program is compiled for: pass it as a static argument"


def refuse_traced(name: str, value: Any, allowed: str = _STATIC) -> None:
    """Refuse a traced ``value`` where only a concrete one can be checked or compiled for."""
    if is_traced(value):
        raise ValueError(f"{name} is traced (inside jax.jit, vmap or grad); allowed: {allowed}")


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """Return ``value`` as an ``int`` in ``[minimum, maximum]`` (not a bool)."""
    refuse_traced(name, value)
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer))
    if not ok or value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise ValueError(
            f"{name} = {value!r} is not allowed; allowed: an integer >= {minimum}{upper}"
        )
    return int(value)


def check_substeps(value: Any) -> int:
    """Return the non-ideal loop's ``substeps`` after checking it in the compute dtype.

    Beyond ``1 / (1000 eps)`` sub-steps the rounding of
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
    refuse_traced(name, value)
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
    """Return the control period ``dt`` as a float: > 0 and finite in the compute dtype."""
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


def drop_shared_axes(tree: Any) -> Any:
    """``tree`` with each leading axis of size 1 (one value every run shares) taken off."""
    return jax.tree.map(lambda a: a[0] if jnp.ndim(a) >= 1 and jnp.shape(a)[0] == 1 else a, tree)


def require_unbatched(tree: Any, prefix: str, allowed: str) -> None:
    """Raise unless every leaf of ``tree`` is a scalar, naming the first that is not."""
    for key, leaf in jax.tree_util.tree_leaves_with_path(tree):
        if np.ndim(leaf) >= 1:
            where = f"{prefix}{jax.tree_util.keystr(key)}"
            raise ValueError(f"{where} has shape {np.shape(leaf)}; allowed: {allowed}")


FINITE_ALLOWED = "gains and dt that keep the sampled law stable (docs/model.md §4)"


def require_finite_runs(
    finite: Any, dtype: Any, *, first: int = 0, allowed: str = FINITE_ALLOWED
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
    field, not a pytree of leaves), or for a field of ``_TABLES`` a tuple of
    knots (one leaf each); ``replace`` returns a changed copy.
    """

    _TABLES: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name in self._TABLES and isinstance(value, (list, tuple)):
                value = tuple(list_as_array(knot) for knot in value)
            else:
                value = list_as_array(value)
            object.__setattr__(self, field.name, value)

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


def as_poses(
    name: str, value: Any, *, batch: bool | None, check_only: bool = False
) -> jax.Array | None:
    """Return ``value`` as a float pose array after checking shape and finiteness.

    ``batch``: ``False`` for one pose ``(3,)``, ``True`` for ``(N, 3)``, ``None``
    for either; ``check_only``: return ``None``, no converted copy. Headings
    that look like degrees are warned of.
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
            summary, reduced = _device_pose_checks(arr, limit)
            *flags, degrees = jax.device_get(summary).tolist()  # one transfer
            flags = [flag > 0 for flag in flags]
    else:
        flags = [bool(np.any(bad(host))) for bad, _ in problems]
    for flag, (bad, message) in zip(flags, problems, strict=True):
        if flag:
            _raise_row(name, shape, arr, host, bad, message)
    if arr is not None:
        _warn_if_degrees(name, degrees)
        return None if check_only else reduced
    _warn_if_degrees(name, float(np.max(_degrees(host[..., 2], np), initial=0)))
    if check_only:
        return None
    host = host.copy()
    host[..., 2] = reduce_heading(host[..., 2])
    # Rounded on the host and put on the device: no program compiled per shape.
    return jax.device_put(host.astype(float_dtype()))


def _degrees(theta: Any, xp: Any) -> Any:
    """Per heading, ``2|θ| + (θ < 0)`` where it is a whole number beyond 2π and up to 360
    (most likely degrees given as radians), else 0: its maximum names the widest."""
    slipped = (abs(theta) > 2 * np.pi) & (abs(theta) <= 360) & (theta == theta.round())
    return xp.where(slipped, 2 * abs(theta) + (theta < 0), 0)


# Where a warning about an argument points: the first frame outside the package
# (Python 3.12+). Before, at this module: one place for every entry point that
# checks the argument again, so that Python's default filter shows it once.
_CALLER = (
    {"skip_file_prefixes": (str(Path(__file__).resolve().parents[1]),)}
    if sys.version_info >= (3, 12)
    else {"stacklevel": 1}
)


class HeadingUnitsWarning(UserWarning):
    """A heading in radians that is most likely degrees: a whole number beyond 2π, up to 360."""


def _warn_if_degrees(name: str, code: float) -> None:
    """Warn of headings that look like degrees; ``code``: the largest of ``_degrees``."""
    if code:
        value = code // 2 * (-1 if code % 2 else 1)
        warnings.warn(
            f"{name} has heading {value:g} rad, a whole number beyond 2π, most likely degrees; "
            f"headings are radians: np.radians({value:g}) = {np.radians(value):.4f}",
            HeadingUnitsWarning,
            **_CALLER,
        )


@jax.jit
def _device_pose_checks(arr: jax.Array, limit: Any) -> tuple[jax.Array, jax.Array]:
    """Of a device array: whether each check of ``as_poses`` fails and the largest of
    ``_degrees``, in one reduction (one collective when sharded); the headings reduced."""
    rows = jnp.stack(
        [
            jnp.any(~jnp.isfinite(arr), axis=-1),
            jnp.abs(arr[..., 2]) > MAX_HEADING,
            jnp.any(jnp.abs(arr[..., :2]) > limit, axis=-1),
        ],
        axis=-1,
    ).astype(arr.dtype)
    rows = jnp.concatenate([rows, _degrees(arr[..., 2], jnp)[..., None]], axis=-1)
    return jnp.max(rows.reshape(-1, 4), axis=0), arr.at[..., 2].set(reduce_heading(arr[..., 2]))


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
    xp = np if isinstance(theta, np.ndarray) else jnp
    wrapped = xp.remainder(theta + np.pi, 2 * np.pi) - np.pi
    return xp.where(xp.abs(theta) > HEADING_REDUCE_ABOVE, wrapped, theta)


def position_limit(dtype: Any = None) -> float:
    """Return the largest ``|x|``, ``|y|`` (cm) a pose may have in ``dtype`` (default: compute).

    Squared distances must stay finite: ``(2 limit)² · 2`` below the dtype's
    largest number, rounded down to a power of ten.
    """
    largest = float(np.finfo(np.dtype(float_dtype() if dtype is None else dtype)).max)
    return float(10.0 ** math.floor(math.log10(math.sqrt(largest / 8))))


def as_pose_array(name: str, value: Any) -> Any:
    """Return ``value`` as poses of any batch shape ``(..., 3)``, checked as ``as_poses`` does."""
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
