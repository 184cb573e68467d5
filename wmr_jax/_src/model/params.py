"""Controller gains and robot parameters as immutable pytrees, with boundary checks.

Every field is a leaf, so gains and robots can be differentiated and vmapped.
Building one checks nothing (JAX rebuilds them on every tree operation); the
entry points call ``validate_gains`` / ``validate_robot`` before tracing.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from typing import Any

import jax
import numpy as np

from wmr_jax._src import quiet
from wmr_jax._src.checks import (
    Parameters,
    check_bool,
    check_dt,
    common_batch_size,
    field_values,
    is_traced,
    real_array,
    require,
    require_concrete,
    require_unbatched,
)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains(Parameters):
    """Gains of the Shim–Sung asymptotic controller (docs/model.md §3, Eq. 6–8).

    Every field may be a Python float, a scalar array, or an array with one
    leading batch axis (a population of gain sets for ``batch_rollout``).

    Attributes:
        kr: linear-velocity gain ``k_r`` in cm/s, ``> 0``.
        k_theta: angular-velocity gain ``k_θ`` in rad/s, ``> 0``.
        phi_m: direction threshold ``Φ_m`` in rad, ``0 < Φ_m < π/2``.
        r_m: distance at which the speed saturates, ``R_m`` in cm.
        r_a: outer radius of Region 1, ``R_a`` in cm.
        r_e: radius of Region 0, ``R_e`` in cm; ``0 < R_e ≤ R_a ≤ R_m``.
        alpha: Region-1 blend offset ``α``, ``0 < α < 0.5``.
    """

    kr: Any = 120.0
    k_theta: Any = 10.0
    phi_m: Any = math.radians(70.0)
    r_m: Any = 20.0
    r_a: Any = 20.0
    # choice (docs/model.md §3): the paper gives neither R_e nor α.
    r_e: Any = 1.0
    alpha: Any = 0.25


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Robot(Parameters):
    """Differential-drive robot of the paper's Table 1 (docs/model.md §1, §4).

    Units: cm, kg, s; torques in kg·cm²/s² (1 N·m = 1e4 kg·cm²/s²): a robot
    8 cm across the wheels is ``Robot(half_track=4.0)``. The defaults are
    Table 1 of the paper.

    Attributes:
        half_track: ``L``, distance from the centre C to each wheel, cm.
        v_max: wheel rim-speed limit ``V_max``, cm/s.
        body_mass: ``M``, kg.
        body_diameter: ``D``, cm (inertia of the body as a uniform disc).
        wheel_radius: ``r``, cm.
        wheel_mass: ``m``, kg (each wheel a uniform disc of radius ``r``).
        com_offset: ``a``, distance of the centre of mass ahead of the axle, cm.
        torque_max: largest torque magnitude per wheel motor, kg·cm²/s².
        speed_gain: proportional gain ``k_p`` of the wheel-speed loop, 1/s
            (time constant ``1/k_p``, ``docs/model.md §4``).
        integral_gain: integral gain ``k_i`` of the wheel-speed loop, 1/s² (0: none).
        accel_max: the ideal loop's speed limiter on the linear-velocity
            command, cm/s² (0: no limit; ``docs/model.md §4.2.2``).
        angular_accel_max: the same for the angular-velocity command, rad/s².
    """

    half_track: Any = 3.7 / 2  # choice (docs/model.md §1): L = D/2
    v_max: Any = 125.0
    body_mass: Any = 0.5
    body_diameter: Any = 3.7
    wheel_radius: Any = 1.5
    wheel_mass: Any = 0.010
    com_offset: Any = 0.0
    # choice: ~0.08 N·m per motor, about 2 g of linear acceleration for Table 1.
    torque_max: Any = 800.0
    # choice: a 10 ms velocity time constant, well inside the 33 ms period.
    speed_gain: Any = 100.0
    integral_gain: Any = 0.0
    # The paper's robot has no speed limiter: it is the massless ideal loop.
    accel_max: Any = 0.0
    angular_accel_max: Any = 0.0


class WheelSpeedWarning(UserWarning):
    """Gains for which ``k_r + L k_θ > V_max``: a wheel may be asked for too much."""


class SamplingWarning(UserWarning):
    """Gains the sampled law cannot follow: ``k_θ dt ≥ 2`` or ``k_r π dt / (2 R_m) ≥ 2``."""


def validate_gains(gains: Gains, prefix: str = "gains") -> Gains:
    """Check ``gains`` against the ranges of docs/model.md §3; return it unchanged."""
    g = field_values(gains, Gains, prefix)
    positive = (("kr", "cm/s"), ("k_theta", "rad/s"), ("r_m", "cm"), ("r_a", "cm"), ("r_e", "cm"))
    for name, unit in positive:
        if g[name] is not None:
            require(f"{prefix}.{name}", g[name], g[name] > 0, f"{name} > 0 {unit}")
    for name, high, allowed in (("phi_m", math.pi / 2, "pi/2 rad"), ("alpha", 0.5, "0.5")):
        if g[name] is not None:
            ok = (g[name] > 0) & (g[name] < high)
            require(f"{prefix}.{name}", g[name], ok, f"0 < {name} < {allowed}")
    for low, high, floor in (("r_e", "r_a", "0 < "), ("r_a", "r_m", "")):
        if g[low] is not None and g[high] is not None:
            allowed = f"{floor}{low} <= {high} ({prefix}.{high} = {g[high]})"
            require(f"{prefix}.{low}", g[low], g[low] <= g[high], allowed)
    return gains


NON_NEGATIVE_ROBOT_FIELDS = ("integral_gain", "accel_max", "angular_accel_max")
# Every other field but com_offset (either sign, inside the body) is a size, mass or gain > 0.
_POSITIVE_ROBOT_FIELDS = tuple(
    f.name
    for f in dataclasses.fields(Robot)
    if f.name not in (*NON_NEGATIVE_ROBOT_FIELDS, "com_offset")
)


def validate_robot(robot: Robot) -> Robot:
    """Check the robot's parameters are physical; return it unchanged."""
    if isinstance(robot, (str, os.PathLike)):  # what the commands' --robot takes
        hint = f"wmr_jax.load_robot({os.fspath(robot)!r}) reads that preset or file"
        raise ValueError(f"robot = {os.fspath(robot)!r} is not allowed; allowed: a Robot ({hint})")
    r = field_values(robot, Robot, "robot")
    for name in _POSITIVE_ROBOT_FIELDS:
        if r[name] is not None:
            require(f"robot.{name}", r[name], r[name] > 0, "> 0")
    for name in NON_NEGATIVE_ROBOT_FIELDS:  # 0: none (no integral action, no limit)
        if r[name] is not None:
            require(f"robot.{name}", r[name], r[name] >= 0, ">= 0")
    if r["com_offset"] is not None and r["body_diameter"] is not None:
        ok = np.abs(r["com_offset"]) < r["body_diameter"] / 2
        allowed = "|com_offset| < body_diameter / 2 (inside the body)"
        require("robot.com_offset", r["com_offset"], ok, allowed)
    return robot


def validate_one_robot(robot: Robot | None, purpose: str) -> Robot:
    """``validate_robot`` for code that needs one robot (default ``Robot()``), not a batch."""
    robot = validate_robot(Robot() if robot is None else robot)
    require_unbatched(robot, "robot", f"one robot (a number per field) for {purpose}")
    return robot


def wheel_speed_bound(gains: Gains, robot: Robot | None = None) -> Any:
    """Return ``k_r + L k_θ`` cm/s, the largest rim speed the law commands (docs/model.md §3).

    Works on scalars, batches and tracers (checked when given values).
    """
    robot = Robot() if robot is None else robot
    if not is_traced((gains, robot)):
        validate_gains(gains)
        validate_robot(robot)
        common_batch_size({"gains": gains, "robot": robot})
    return gains.kr + robot.half_track * gains.k_theta


def check_feasible(
    gains: Gains, robot: Robot | None = None, *, warn: bool = False, stacklevel: int = 2
) -> np.ndarray:
    """Return whether ``k_r + L k_θ ≤ V_max`` (elementwise for batched gains).

    Args:
        gains: controller gains (concrete values).
        robot: the robot; default ``Robot()``.
        warn: if true, emit a ``WheelSpeedWarning`` when the condition fails.
        stacklevel: passed to ``warnings.warn`` (which caller the warning names).
    """
    require_concrete("check_feasible", gains, robot)
    warn = check_bool("warn", warn)
    robot = validate_robot(Robot() if robot is None else robot)
    gains = validate_gains(gains)
    common_batch_size({"gains": gains, "robot": robot})
    return feasible(gains, robot, warn=warn, stacklevel=stacklevel + 1)


def feasible(gains: Gains, robot: Robot, *, warn: bool, stacklevel: int) -> np.ndarray:
    """``check_feasible`` of gains and a robot already checked (the rollouts' warning)."""
    # To the rounding of the coarsest precision given: float32 gains at the bound are at
    # it (cast to float64 first, 106.5 + 1.85 * 10 exceeds 125 by 2e-7); float64 ones a
    # hair above it are not.
    values = [np.asarray(v) for v in (gains.kr, gains.k_theta, robot.half_track, robot.v_max)]
    floats = [v.dtype for v in values if v.dtype.kind == "f"] or [np.dtype(np.float64)]
    ulp = max(np.finfo(d).eps for d in floats)
    kr, k_theta, half_track, v_max = (v.astype(np.float64) for v in values)
    bound = kr + half_track * k_theta
    ok = bound <= v_max * (1 + 4 * ulp)
    if warn and not np.all(ok) and quiet.warns():
        worst = float(np.max(bound))
        # The defaults are the paper's Fig. 7 gains, which break the bound on purpose.
        default = all(
            np.all(np.asarray(getattr(gains, f.name)) == getattr(Gains(), f.name))
            for f in dataclasses.fields(Gains)
        )
        why = "; these are the default gains, the paper's Fig. 7 (docs/paper.md)" if default else ""
        warnings.warn(
            f"k_r + L*k_theta = {worst:.4g} cm/s exceeds v_max = {float(np.max(v_max)):.4g} cm/s: "
            f"wheel commands may saturate (docs/model.md §3){why}",
            WheelSpeedWarning,
            stacklevel=stacklevel,
        )
    return ok


def sampling_margins(gains: Gains, dt: Any) -> tuple[Any, Any]:
    """Return ``(k_θ dt, k_r π dt / (2 R_m))``, the per-period gains of the sampled law.

    Near the goal each settles only while its factor stays below 2 (docs/model.md §4).
    """
    if not is_traced((gains, dt)):  # dt may be an array of periods
        validate_gains(gains)
        periods = real_array("dt", dt, "periods > 0 s")
        require("dt", periods, np.isfinite(periods) & (periods > 0), "finite periods > 0 s")
    return _margins(gains, dt)


def _margins(gains: Gains, dt: Any) -> tuple[Any, Any]:
    return gains.k_theta * dt, gains.kr * (math.pi / 2) * dt / gains.r_m


def check_sampling(gains: Gains, dt: Any, *, stacklevel: int = 2) -> bool:
    """Warn (``SamplingWarning``) and return False if either sampling margin is 2 or more.

    Raises:
        ValueError: for gains out of range or a ``dt`` that is not a period.
    """
    gains, dt = validate_gains(gains), check_dt(dt)
    return sampled(gains, dt, stacklevel=stacklevel + 1)


def sampled(gains: Gains, dt: float, *, stacklevel: int) -> bool:
    """``check_sampling`` of gains and a period already checked (the rollouts' warning)."""
    # In float64: a k_r float32 can hold (3e38) has a margin beyond float32.
    wide = jax.tree.map(lambda leaf: np.asarray(leaf, dtype=np.float64), gains)
    heading, distance = (float(np.max(m)) for m in _margins(wide, np.float64(dt)))
    if heading < 2 and distance < 2:
        return True
    if not quiet.warns():
        return False
    # A period of a second or more is most likely milliseconds given as seconds.
    ms = f"; dt = {dt:g} is in s (a period in milliseconds needs /1000)" if dt >= 1 else ""
    warnings.warn(
        f"k_theta*dt = {heading:.3g} and k_r*pi*dt/(2*R_m) = {distance:.3g}: the sampled law "
        f"overshoots and cannot settle unless both are below 2 (docs/model.md §4){ms}",
        SamplingWarning,
        stacklevel=stacklevel,
    )
    return False
