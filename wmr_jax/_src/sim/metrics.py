"""Metrics of docs/model.md §6, so that every experiment measures the same thing.

All functions broadcast over leading batch axes of the trajectory.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    array_kind,
    as_pose_array,
    check_dt,
    check_number,
    is_traced,
    real_array,
    require,
    require_concrete,
)
from wmr_jax._src.model.controllers import shim_sung as law

DEFAULT_TOL_R = 1.0  # cm
DEFAULT_TOL_THETA = math.radians(5.0)
DEFAULT_V_DEAD_BAND = 1.0  # cm/s
DEFAULT_OMEGA_DEAD_BAND = 0.1  # rad/s


class PoseMetrics(NamedTuple):
    """docs/model.md §6 metrics of ``N`` runs, each a NumPy ``(N,)`` array.

    Attributes:
        arrival: arrival time, s; ``inf`` where not arrived at the end.
        path: distance travelled by the centre, cm.
        peak_wheel: largest rim speed ``|v ± L ω|`` over the run, cm/s.
        zigzag: sign changes of ``v`` plus those of ``ω`` beyond the dead bands.
        final_distance: distance to the reference at the end, cm.
        first_arrival: the first time the robot is arrived, whether or not
            it stays, s; ``inf`` if never (``None`` where not computed).
    """

    arrival: np.ndarray
    path: np.ndarray
    peak_wheel: np.ndarray
    zigzag: np.ndarray
    final_distance: np.ndarray
    first_arrival: np.ndarray | None = None

    @property
    def success(self) -> np.ndarray:
        """Whether each run arrived (finite arrival time)."""
        return np.isfinite(self.arrival)


def _check_tolerances(tol_r: Any, tol_theta: Any) -> tuple[Any, Any]:
    """Return the tolerances as checked floats (tracers pass)."""
    if is_traced((tol_r, tol_theta)):
        return tol_r, tol_theta
    tol_r = check_number("tol_r", tol_r, unit="cm")
    return tol_r, check_number("tol_theta", tol_theta, high=math.pi / 2, unit="rad")


def _poses_of(traj: Any) -> Any:
    """Return ``traj.poses`` after checking ``traj`` is a trajectory."""
    poses = getattr(traj, "poses", None)
    if poses is None:
        raise ValueError(
            f"traj is a {type(traj).__name__}; allowed: a Trajectory (from rollout or "
            "batch_rollout), whose poses have shape (..., steps + 1, 3)"
        )
    if is_traced(poses):
        return poses
    if jnp.ndim(poses) < 2 or jnp.shape(poses)[-1] != 3 or jnp.shape(poses)[-2] < 2:
        raise ValueError(
            f"traj.poses has shape {jnp.shape(poses)}; allowed: (..., steps + 1, 3) with "
            "steps >= 1 (the initial pose, then one per control period)"
        )
    if array_kind(poses) in "iuf":
        host = np.asarray(poses)
        bad = ~np.isfinite(host).all(axis=-1)
        if bad.any():
            at = tuple(int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"traj.poses[{', '.join(map(str, at))}] = {host[at].tolist()} is not finite; "
                "allowed: finite numbers (a run that left the range has no metrics)"
            )
    return poses


def _is_arrived(
    poses: jax.Array, refs: jax.Array, tol_r: Any, tol_theta: Any, frame: Any = None
) -> jax.Array:
    err = law.polar_error(poses, refs, frame=frame)
    # |θ̄_e| from the headings, not cosines: a heading exactly tol_theta off is arrived.
    turn = poses[..., 2] - refs[..., 2]
    whole = 2 * jnp.pi * jnp.round(turn / (2 * jnp.pi))
    turn = jnp.abs(jnp.where(jnp.abs(turn) <= jnp.pi, turn, turn - whole))
    folded = jnp.minimum(turn, jnp.pi - turn)
    return (err.r <= tol_r) & (folded <= tol_theta)


def arrived(
    poses: jax.Array,
    refs: jax.Array,
    *,
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
) -> jax.Array:
    """Return whether each pose is arrived: ``r_e ≤ tol_r`` and ``|θ̄_e| ≤ tol_theta``.

    ``poses`` and ``refs`` ``(..., 3)`` broadcast; ``tol_r`` cm, ``tol_theta`` rad ``< π/2``.

    Raises:
        ValueError: for misshapen or non-finite poses, or tolerances out of range.
    """
    tol_r, tol_theta = _check_tolerances(tol_r, tol_theta)
    poses, refs = as_pose_array("poses", poses), as_pose_array("refs", refs)
    _check_broadcast("poses", jnp.shape(poses)[:-1], "refs", jnp.shape(refs)[:-1])
    return _arrived_jit(poses, refs, tol_r, tol_theta)


_arrived_jit = jax.jit(_is_arrived)


def _check_broadcast(a: str, shape_a: tuple, b: str, shape_b: tuple) -> None:
    try:
        np.broadcast_shapes(shape_a, shape_b)
    except ValueError:
        raise ValueError(
            f"{b} has batch shape {shape_b} and {a} {shape_a}; allowed: shapes that broadcast "
            "(one reference per run, or one for all)"
        ) from None


def arrival_time(
    traj: Any,
    refs: Any,
    *,
    dt: float,
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
) -> jax.Array:
    """Return the arrival time of each run in s, ``inf`` where it never settles (docs/model.md §6).

    ``(k + 1) dt`` for the smallest sample ``k`` from which the robot stays
    arrived to the end of the horizon.

    Args:
        traj: a ``Trajectory`` (poses ``(..., steps + 1, 3)``).
        refs: ``(..., 3)`` the references of the runs.
        dt: control period, s.
        tol_r: distance tolerance, cm.
        tol_theta: folded-heading tolerance, rad.

    Raises:
        ValueError: for something that is not a trajectory, bad references,
            ``dt ≤ 0`` or tolerances out of range.
    """
    tol_r, tol_theta = _check_tolerances(tol_r, tol_theta)
    dt = check_dt(dt)
    poses = _poses_of(traj)
    refs = as_pose_array("refs", refs)
    _check_broadcast("traj", jnp.shape(poses)[:-2], "refs", jnp.shape(refs)[:-1])
    samples = as_pose_array("pose", poses[..., 1:, :])
    return _arrival_time_jit(samples, refs[..., None, :], tol_r, tol_theta, dt)


@jax.jit
def _arrival_time_jit(samples, refs, tol_r, tol_theta, dt):
    ok = _is_arrived(samples, refs, tol_r, tol_theta)
    # The run of arrived samples that ends the horizon.
    settled = jnp.sum(jnp.cumprod(ok[..., ::-1], axis=-1), axis=-1)
    steps = ok.shape[-1]
    first = steps - settled
    return jnp.where(settled > 0, (first + 1) * dt, jnp.inf)


def success_rate(times: Any) -> float:
    """Return the fraction of finite arrival times (of ``arrival_time``, say).

    Raises:
        ValueError: for no times, or bools, NaN or negative numbers (``inf``
            is a run that never settled: a failure).
    """
    require_concrete("success_rate", times)
    allowed = "one or more arrival times, s (from arrival_time; inf where a run never settles)"
    if isinstance(times, (str, bytes)) or getattr(times, "poses", None) is not None:
        raise ValueError(f"times = {type(times).__name__} is not allowed; allowed: {allowed}")
    arr = real_array("times", times, allowed)
    if arr.size == 0:
        raise ValueError(f"times has shape {arr.shape} (no runs); allowed: {allowed}")
    require("times", arr, ~np.isnan(arr) & (arr >= 0), allowed)
    # In NumPy: JAX's mean of bools is float32 even in a float64 session.
    finite = np.isfinite(np.asarray(times, dtype=float))
    return float(np.count_nonzero(finite) / finite.size)


def _field_of(traj: Any, name: str) -> Any:
    """Return ``traj.<name>``, ``(..., steps)``, after checking its shape and values."""
    poses = _poses_of(traj)
    value = getattr(traj, name, None)
    if is_traced((poses, value)):
        return value
    batch, steps = jnp.shape(poses)[:-2], jnp.shape(poses)[-2] - 1
    field = f"traj.{name}"
    if name == "region":
        allowed = "integer region labels 0 to 3 (-1 for a controller without regions)"
        kinds = "iu"
    else:
        unit = "cm" if name == "distance" else "cm/s" if name == "v" else "rad/s"
        allowed = f"finite numbers, {unit}" + (", >= 0" if name == "distance" else "")
        kinds = "iuf"
    if value is None or isinstance(value, (str, bytes)) or array_kind(value) not in kinds:
        dtype = getattr(value, "dtype", None)
        shown = repr(value) if dtype is None else f"an array of {dtype} {np.shape(value)}"
        raise ValueError(f"{field} = {shown} is not allowed; allowed: {allowed}")
    arr = np.asarray(value)
    if name == "region":
        ok = (arr >= -1) & (arr <= 3)
    else:
        arr = arr.astype(float)
        ok = np.isfinite(arr) & ((arr >= 0) if name == "distance" else True)
    if arr.shape != (*batch, steps):
        raise ValueError(
            f"{field} has shape {arr.shape}; allowed: {(*batch, steps)}, one value per control "
            f"period of traj.poses {tuple(jnp.shape(poses))}"
        )
    require(field, arr, ok, allowed)
    return jnp.asarray(value)


def path_length(traj: Any) -> jax.Array:
    """Return the distance the centre travelled over the run, cm: the sum of ``traj.distance``."""
    return jnp.sum(_field_of(traj, "distance"), axis=-1)


def _sign_changes(x: jax.Array, dead_band: float) -> jax.Array:
    """Count sign changes along the last axis, ignoring samples with ``|x| ≤ dead_band``."""
    x = jnp.moveaxis(x, -1, 0)

    def body(carry, sample):
        last, count = carry
        last, flipped = _flip(last, sample, dead_band)
        return (last, count + flipped), None

    zeros = jnp.zeros(x.shape[1:], jnp.int32)
    (_, count), _ = jax.lax.scan(body, (zeros, zeros), x)
    return count


def zigzag_count(
    traj: Any,
    *,
    v_dead_band: float = DEFAULT_V_DEAD_BAND,
    omega_dead_band: float = DEFAULT_OMEGA_DEAD_BAND,
) -> jax.Array:
    """Return the number of sign changes of ``v`` plus those of ``ω`` (docs/model.md §6).

    Args:
        traj: a ``Trajectory``.
        v_dead_band: speeds with ``|v| ≤`` this (cm/s) carry no sign.
        omega_dead_band: turn rates with ``|ω| ≤`` this (rad/s) carry no sign.
    """
    v, omega = _field_of(traj, "v"), _field_of(traj, "omega")
    if not is_traced((v_dead_band, omega_dead_band)):
        v_dead_band = check_number("v_dead_band", v_dead_band, closed=True, unit="cm/s")
        omega_dead_band = check_number(
            "omega_dead_band", omega_dead_band, closed=True, unit="rad/s"
        )
    return _zigzags(v, omega, v_dead_band, omega_dead_band)


@jax.jit
def _zigzags(v, omega, v_dead_band, omega_dead_band):
    return _sign_changes(v, v_dead_band) + _sign_changes(omega, omega_dead_band)


def region_time(traj: Any, *, dt: float) -> jax.Array:
    """Return the time spent in each region 0–3, s, shape ``(..., 4)``.

    Zero everywhere for a controller without regions (its labels are −1).
    """
    dt = check_dt(dt)
    one_hot = _field_of(traj, "region")[..., None] == jnp.arange(4)
    return jnp.sum(one_hot, axis=-2) * dt


class Thresholds(NamedTuple):
    """The metrics' tolerances, traced (changing them does not recompile)."""

    tol_r: Any = DEFAULT_TOL_R
    tol_theta: Any = DEFAULT_TOL_THETA
    v_dead_band: Any = DEFAULT_V_DEAD_BAND
    omega_dead_band: Any = DEFAULT_OMEGA_DEAD_BAND


class RunMetrics(NamedTuple):
    """Running metrics of one run (all scalars), streamed without a trajectory."""

    step: jax.Array  # periods folded so far
    settled_from: jax.Array  # first sample of the current run of arrived samples, or −1
    first: jax.Array  # first arrived sample, or −1
    path: jax.Array
    peak_wheel: jax.Array
    v_sign: jax.Array  # last sign of v outside its dead band (0: none yet)
    omega_sign: jax.Array
    zigzag: jax.Array


def stream_start(dtype: Any) -> RunMetrics:
    """The metrics of a run before its first control period."""
    zero, izero = jnp.zeros((), dtype), jnp.zeros((), jnp.int32)
    none = jnp.full((), -1, jnp.int32)
    return RunMetrics(izero, none, none, zero, zero, izero, izero, izero)


def _flip(last: jax.Array, x: jax.Array, dead_band: Any) -> tuple[jax.Array, jax.Array]:
    """Return the updated last sign and 1 if ``x`` flipped it, else 0."""
    sign = jnp.where(x > dead_band, 1, jnp.where(x < -dead_band, -1, 0)).astype(jnp.int32)
    flipped = (sign != 0) & (last != 0) & (sign != last)
    return jnp.where(sign != 0, sign, last), flipped.astype(jnp.int32)


def stream_update(
    acc: RunMetrics,
    pose: jax.Array,
    ref: jax.Array,
    out: Any,
    thresholds: Thresholds,
    *,
    frame: Any = None,
) -> RunMetrics:
    """Fold one control period into the metrics (``docs/model.md §6``).

    ``pose``: ``(3,)`` true pose at the end of the period, also as ``frame``
    ``(x, y, cos θ, sin θ)`` if the caller has it; ``out``: its ``StepOutput``.
    """
    ok = _is_arrived(pose, ref, thresholds.tol_r, thresholds.tol_theta, frame)
    k = acc.step
    v_sign, v_flip = _flip(acc.v_sign, out.v, thresholds.v_dead_band)
    omega_sign, omega_flip = _flip(acc.omega_sign, out.omega, thresholds.omega_dead_band)
    rims = jnp.abs(out.wheel_speeds)
    return RunMetrics(
        step=k + 1,
        settled_from=jnp.where(ok, jnp.where(acc.settled_from < 0, k, acc.settled_from), -1),
        first=jnp.where(ok & (acc.first < 0), k, acc.first),
        path=acc.path + out.distance,
        # An elementwise maximum: XLA runs a length-2 reduction as a slow call.
        peak_wheel=jnp.maximum(acc.peak_wheel, jnp.maximum(rims[..., 0], rims[..., 1])),
        v_sign=v_sign,
        omega_sign=omega_sign,
        zigzag=acc.zigzag + v_flip + omega_flip,
    )


def stream_result(acc: RunMetrics, dt: jax.Array) -> dict[str, jax.Array]:
    """Return the finished metrics of a run (times in s, as ``PoseMetrics``)."""

    def time_of(sample):
        return jnp.where(sample >= 0, (sample + 1).astype(acc.path.dtype) * dt, jnp.inf)

    return {
        "arrival_time": time_of(acc.settled_from),
        "first_arrival": time_of(acc.first),
        "success": acc.settled_from >= 0,
        "path_length": acc.path,
        "peak_wheel_speed": acc.peak_wheel,
        "zigzags": acc.zigzag,
    }
