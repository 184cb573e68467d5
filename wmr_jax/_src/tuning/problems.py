"""The tuning problems as values: fixed gains (7 parameters) and gain schedules (35 by default).

A ``Problem`` is the controller, its feasible set as an image of the unit
cube, the starting point, and how its parameters become a flat row and JSON.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import check_int, is_traced
from wmr_jax._src.model.controllers.base import Controller
from wmr_jax._src.model.controllers.schedule import (
    KNOTS,
    SCHEDULE,
    SHAPE_FIELDS,
    TABLES,
    ScheduleParams,
)
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.tuning import parametrisation as fixed


class Cube:
    """The logits of a searched cube, for any class with ``dim``, ``from_unit`` and ``start``."""

    def from_logits(self, z: Any, robot: Robot) -> Any:
        """``from_unit`` of the logits ``z`` (``u = σ(z)``; real, shaped as ``from_unit`` takes)."""
        if not is_traced(robot):  # refused before z is converted
            robot = validate_one_robot(robot, "from_logits")
        z = fixed.checked_point("z", z, self.dim, unit=False)
        return self.from_unit(1.0 / (1.0 + jnp.exp(-z)), robot)

    def start_logits(self, robot: Robot) -> np.ndarray:
        """Logits of ``start(robot)``, finite."""
        u = self.start(robot)
        return np.log(u) - np.log1p(-u)


@dataclasses.dataclass(frozen=True)
class Problem(Cube):
    """A tuning problem (hashable: a static ``jit`` argument).

    Attributes:
        name: ``"fixed"`` or ``"schedule"``.
        controller: the law being tuned.
        dim: dimension of the unit cube searched.
        from_unit: ``(u (..., dim), robot) -> params``, feasible for every ``u``.
        start: ``robot -> u₀`` ``(dim,)`` strictly inside the cube.
        columns: names of the entries of a flat row.
        row: ``params -> tuple of floats`` (scalar params).
        from_row: ``(row) -> params``.
    """

    name: str
    controller: Controller
    dim: int
    from_unit: Callable[[Any, Robot], Any]
    start: Callable[[Robot], np.ndarray]
    columns: tuple[str, ...]
    row: Callable[[Any], tuple[float, ...]]
    from_row: Callable[[Any], Any]


FIXED = Problem(
    name="fixed",
    controller=SHIM_SUNG,
    dim=7,
    from_unit=fixed.gains_from_unit,
    start=lambda robot: fixed.unit_from_gains(fixed.PAPER_FEASIBLE_GAINS, robot),
    columns=fixed.GAIN_FIELDS,
    row=lambda gains: tuple(fixed.gains_as_dict(gains).values()),
    from_row=lambda row: Gains(**dict(zip(fixed.GAIN_FIELDS, map(float, row), strict=True))),
)

# choice: the box of the schedule. k_r knots may reach V_max (the cap
# |v| ≤ V_max − L|ω| keeps the wheels within it), the turn gains turn_gain_max
# (the cap |ω| ≤ V_max / L does); the shape gains share the fixed problem's box.
_KR = (1e-3, 1.0)  # fraction of V_max
_K_THETA = (1e-3, 1.0)  # fraction of turn_gain_max
_SHAPE_COLUMNS = (*SHAPE_FIELDS, "v_max", "half_track")
# The largest schedule tuned: the loss gradient of larger tables takes long
# to compile and much memory, though rollouts take up to MAX_KNOTS.
MAX_TUNED_KNOTS = 60


def schedule_problem(knots: int = KNOTS) -> Problem:
    """The gain-schedule problem with ``knots`` knots per table: ``3 knots + 5`` parameters.

    One cached ``Problem`` per knot count: the same static argument of every
    compiled step. ``ValueError`` for a count outside 2 … ``MAX_TUNED_KNOTS``.
    """
    return _schedule_problem(check_int("knots", knots, 2, MAX_TUNED_KNOTS))


def turn_gain_max(robot: Robot) -> Any:
    """The largest turn-gain knot of the schedule's box, rad/s (docs/model.md §3.9).

    ``max(V_max / L, 1 / dt₀)`` with ``dt₀ = DEFAULT_DT``: up to the rate at
    which the wheels saturate, or the sampled heading loop's deadbeat gain
    ``k dt₀ = 1`` (§4.2.1) on a robot that turns slowly; the cap
    ``|ω| ≤ V_max / L`` keeps the wheels within ``V_max`` whatever the gain.
    """
    return jnp.maximum(robot.v_max / robot.half_track, 1.0 / DEFAULT_DT)


@functools.cache
def _schedule_problem(knots: int) -> Problem:
    columns = tuple(f"{table}[{k}]" for table in TABLES for k in range(knots)) + _SHAPE_COLUMNS

    def from_unit(u: Any, robot: Robot | None = None) -> ScheduleParams:
        robot = Robot() if robot is None else robot
        u = fixed.checked_point("u", u, 3 * knots + 5, unit=True)
        omega_max = turn_gain_max(robot)
        tables = {
            "kr": robot.v_max * fixed._lerp(u[..., 0:knots], _KR),
            "k_theta": omega_max * fixed._lerp(u[..., knots : 2 * knots], _K_THETA),
            "k_turn": omega_max * fixed._lerp(u[..., 2 * knots : 3 * knots], _K_THETA),
        }
        # The shape gains reuse the fixed map: its columns 2–6 are Φ_m, α and the radii.
        shape_u = jnp.concatenate([jnp.zeros_like(u[..., :2]), u[..., 3 * knots :]], axis=-1)
        shape = fixed.gains_from_unit(shape_u, robot)
        return ScheduleParams(
            **{
                name: tuple(values[..., k] for k in range(knots)) for name, values in tables.items()
            },
            **{name: getattr(shape, name) for name in SHAPE_FIELDS},
            v_max=robot.v_max,
            half_track=robot.half_track,
        )

    def start(robot: Robot) -> np.ndarray:
        """The paper's feasible gains as constant tables (the fixed law's start)."""
        gains = fixed.PAPER_FEASIBLE_GAINS
        # turn_gain_max's bound in float64 (turn_gain_max may round to float32).
        omega_max = max(float(robot.v_max) / float(robot.half_track), 1.0 / DEFAULT_DT)
        kr = fixed._unlerp(gains.kr / float(robot.v_max), _KR)
        kt = fixed._unlerp(gains.k_theta / omega_max, _K_THETA)
        tables = np.clip([kr] * knots + [kt] * (2 * knots), 1e-3, 1 - 1e-3)
        return np.concatenate([tables, fixed.unit_from_gains(gains, robot)[2:]])

    def row(params: ScheduleParams) -> tuple[float, ...]:
        values = [float(x) for table in TABLES for x in getattr(params, table)]
        return tuple(values + [float(getattr(params, name)) for name in _SHAPE_COLUMNS])

    def from_row(values: Any) -> ScheduleParams:
        values = [float(x) for x in values]
        tables = {t: tuple(values[i * knots : (i + 1) * knots]) for i, t in enumerate(TABLES)}
        rest = dict(zip(_SHAPE_COLUMNS, values[3 * knots :], strict=True))
        return ScheduleParams(**tables, **rest)

    return Problem(
        name="schedule",
        controller=SCHEDULE,
        dim=3 * knots + 5,
        from_unit=from_unit,
        start=start,
        columns=columns,
        row=row,
        from_row=from_row,
    )


SCHEDULED = schedule_problem(KNOTS)

PROBLEMS = {problem.name: problem for problem in (FIXED, SCHEDULED)}


def get_problem(name: str | Problem) -> Problem:
    """Return the problem called ``name`` (``"fixed"`` or ``"schedule"``)."""
    if isinstance(name, Problem):
        return name
    if name not in PROBLEMS:
        raise ValueError(f"problem = {name!r} is not allowed; allowed: {sorted(PROBLEMS)}")
    return PROBLEMS[name]


def params_json(problem: Problem, params: Any) -> dict[str, Any]:
    """``tuned_gains.json`` content: ``{"controller": name, "kind": problem, fields…}``."""
    values: dict[str, Any] = {"controller": problem.controller.name, "kind": problem.name}
    if problem is FIXED:
        values.update(fixed.gains_as_dict(params))
        return values
    for table in TABLES:
        values[table] = [float(x) for x in getattr(params, table)]
    for name in _SHAPE_COLUMNS:
        values[name] = float(getattr(params, name))
    return values
