"""The Shim–Sung law with gain schedules: gains as functions of the error state (docs/model.md §3).

The gains are tables over ``r_e`` (knots dense near the goal), ``k_turn`` the
turn gain where ``d = 0``. ``shim_sung.commands`` runs with the gains of the
state, then ``|ω| ≤ V_max / L`` and ``|v| ≤ V_max − L |ω|``: every wheel
command is within ``±V_max`` by construction, and constant tables within that
budget give the fixed-gain law exactly.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import quiet
from wmr_jax._src.checks import (
    Parameters,
    batch_sizes,
    check_int,
    field_array,
    require,
    require_one_batch_size,
)
from wmr_jax._src.model.controllers.base import register_controller
from wmr_jax._src.model.controllers.shim_sung import (
    SHIM_SUNG,
    PolarError,
    commands,
    direction_flag,
    polar_error,
)
from wmr_jax._src.model.params import (
    Gains,
    Robot,
    WheelSpeedWarning,
    sampled,
    validate_gains,
    validate_robot,
)

KNOTS = 10  # knots per table by default
# Each knot is a term of the compiled law: many more no longer compile.
MAX_KNOTS = 200
R_KNOT = 81.0  # cm, the last knot: just beyond the 80 cm of the evaluation set (§6)
TABLES = ("kr", "k_theta", "k_turn")
SHAPE_FIELDS = ("phi_m", "r_m", "r_a", "r_e", "alpha")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ScheduleParams(Parameters):
    """Parameters of the gain-scheduled Shim–Sung law (docs/model.md §3).

    Each table is a tuple of ``K ≥ 2`` knot values (each a scalar, or with one
    leading batch axis), the gain at ``r_e = knot_radii(K)[k]``.

    Attributes:
        kr: speed gain ``k_r(r_e)`` knots, cm/s, ``> 0``.
        k_theta: turn gain ``k_θ(r_e)`` knots where ``d ≠ 0``, rad/s, ``> 0``.
        k_turn: turn gain knots where ``d = 0`` (Region 3), rad/s, ``> 0``.
        phi_m, r_m, r_a, r_e, alpha: as in ``Gains``.
        v_max: the wheel-speed limit the commands respect, cm/s.
        half_track: ``L`` of the robot, cm.
    """

    kr: tuple = (60.0,) * KNOTS
    k_theta: tuple = (10.0,) * KNOTS
    k_turn: tuple = (10.0,) * KNOTS
    phi_m: Any = math.radians(70.0)
    r_m: Any = 20.0
    r_a: Any = 20.0
    r_e: Any = 1.0
    alpha: Any = 0.25
    v_max: Any = float(Robot.v_max)  # the paper robot's
    half_track: Any = float(Robot.half_track)
    _TABLES = TABLES

    @classmethod
    def from_gains(
        cls, gains: Gains, *, knots: int = KNOTS, robot: Robot | None = None
    ) -> ScheduleParams:
        """Constant tables equal to ``gains`` (``k_turn = k_θ``): the fixed-gain law."""
        if not isinstance(gains, Gains):
            raise ValueError(f"gains is a {type(gains).__name__}; allowed: a wmr_jax.Gains")
        if robot is not None:
            validate_robot(robot)
        knots = check_int("knots", knots, 2, MAX_KNOTS)
        robot = Robot() if robot is None else robot
        return cls(
            kr=(gains.kr,) * knots,
            k_theta=(gains.k_theta,) * knots,
            k_turn=(gains.k_theta,) * knots,
            **{name: getattr(gains, name) for name in SHAPE_FIELDS},
            v_max=robot.v_max,
            half_track=robot.half_track,
        )


def knot_radii(knots: int = KNOTS) -> np.ndarray:
    """Return the ``r_e`` of each knot, cm: ``R_KNOT (k / (K − 1))²``, ``k = 0 … K−1``."""
    knots = check_int("knots", knots, 2, MAX_KNOTS)
    return R_KNOT * (np.arange(knots) / (knots - 1)) ** 2


def _table(values: tuple, r: jax.Array) -> jax.Array:
    return table_at(values, r, knot_radii(len(values)))


def table_at(values: tuple, r: jax.Array, radii: np.ndarray) -> jax.Array:
    """The piecewise-linear table of knots ``values`` at ``radii`` cm, at ``r`` (constant beyond).

    The first knot plus each increment times its ramp, so that a constant
    table gives its value exactly.
    """
    out = values[0]
    for k in range(1, len(values)):
        ramp = jnp.clip((r - radii[k - 1]) * (1.0 / (radii[k] - radii[k - 1])), 0.0, 1.0)
        out = out + (values[k] - values[k - 1]) * ramp
    return out


def schedule_commands(
    err: PolarError, params: ScheduleParams, *, temperature: float | None = None
) -> tuple[jax.Array, jax.Array]:
    """Return the scheduled command ``(v cm/s, ω rad/s)``; ``|v| + L|ω| ≤ V_max`` always.

    A pure building block: ``params`` is not checked here (``validate_schedule``).
    ``temperature`` relaxes the switches of ``shim_sung``; the caps stay hard.
    """
    d = direction_flag(err, params.phi_m, temperature=temperature)
    k_theta = _table(params.k_theta, err.r)
    # Where d = 0 the robot does not drive (v = 0), so its turn gain may be other.
    k_theta = k_theta + (1 - d * d) * (_table(params.k_turn, err.r) - k_theta)
    gains = _fixed_gains(params, _table(params.kr, err.r), k_theta)
    v, omega = commands(err, gains, temperature=temperature)
    omega_max = params.v_max / params.half_track
    omega = jnp.clip(omega, -omega_max, omega_max)
    budget = params.v_max - params.half_track * jnp.abs(omega)  # ≥ 0 by the clip above
    return jnp.clip(v, -budget, budget), omega


def _fixed_gains(params: ScheduleParams, kr: Any, k_theta: Any) -> Gains:
    """The fixed-gain law's ``Gains``: ``kr``, ``k_theta`` and the schedule's shape fields."""
    return Gains(kr=kr, k_theta=k_theta, **{name: getattr(params, name) for name in SHAPE_FIELDS})


def _command(pose, ref, params, *, temperature=None, frame=None):
    return schedule_commands(polar_error(pose, ref, frame=frame), params, temperature=temperature)


def validate_schedule(params: ScheduleParams) -> ScheduleParams:
    """Check a schedule's tables and shape gains (docs/model.md §3); return it unchanged."""
    if not isinstance(params, ScheduleParams):
        raise ValueError(
            f"params is a {type(params).__name__}; allowed: a wmr_jax.controllers.ScheduleParams"
        )
    sizes = set()
    for name in TABLES:
        table = getattr(params, name)
        if not isinstance(table, (tuple, list)) or len(table) < 2:
            raise ValueError(
                f"params.{name} = {table!r} is not allowed; allowed: a tuple of >= 2 knots"
            )
        sizes.add(len(table))
        if len(table) > MAX_KNOTS:
            raise ValueError(
                f"params.{name} has {len(table)} knots; allowed: 2 to {MAX_KNOTS} "
                "(the table is unrolled into the compiled law)"
            )
        for k, value in enumerate(table):
            _check_positive(f"params.{name}[{k}]", value, "a finite gain > 0")
    if len(sizes) > 1:
        raise ValueError(
            f"the tables have {sorted(sizes)} knots; allowed: kr, k_theta, k_turn of one length"
        )
    validate_gains(_fixed_gains(params, 1.0, 1.0), prefix="params")
    for name, unit in (("v_max", "cm/s"), ("half_track", "cm")):
        _check_positive(f"params.{name}", getattr(params, name), f"a finite {name} > 0, {unit}")
    require_one_batch_size(batch_sizes({"params": params}))  # knots and fields alike
    return params


def _check_positive(name: str, value: Any, allowed: str) -> None:
    if not isinstance(value, jax.core.Tracer):
        arr = field_array(name, value, allowed)
        require(name, arr, arr > 0, allowed)


def _check_robot(params: ScheduleParams, robot: Robot) -> None:
    # The bound holds for the params' v_max and L; warn if the robot's are tighter.
    tighter = np.asarray(robot.v_max) < np.asarray(params.v_max) * (1 - 1e-6)
    other_l = ~np.isclose(np.asarray(robot.half_track), np.asarray(params.half_track))
    if (np.any(tighter) or np.any(other_l)) and quiet.warns():
        warnings.warn(
            "the schedule bounds |v| + L|omega| by its own v_max and half_track, which differ "
            "from the robot's: wheel commands may saturate (docs/model.md §3)",
            WheelSpeedWarning,
            stacklevel=5,
        )


def _check_sampling(params: ScheduleParams, dt: Any) -> None:
    # Settling is decided at the goal, where the law is the fixed-gain one with
    # the first knots and no cap is active (docs/model.md §4).
    at_goal = _fixed_gains(params, params.kr[0], params.k_theta[0])
    sampled(at_goal, dt, stacklevel=5)  # the schedule and dt checked by the rollout


# The fixed-gain law's regions and smooth relaxation, with scheduled gains.
SCHEDULE = register_controller(
    dataclasses.replace(
        SHIM_SUNG,
        name="shim-sung-schedule",
        command=_command,
        params_type=ScheduleParams,
        validate=validate_schedule,
        check_robot=_check_robot,
        check_sampling=_check_sampling,
    )
)
"""The gain-scheduled Shim–Sung law (``ScheduleParams``), registered by name."""
