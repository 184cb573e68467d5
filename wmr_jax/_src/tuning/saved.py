"""Tuned parameters as files: ``tuned_gains.json`` and ``load_tuned``.

A ``tuned_gains.json`` holds the parameters with their ``"controller"`` and
``"kind"``, the ``"estimator"`` tuned with them (null: raw feedback), the
``"units"`` of its numbers (a file may give an angle in ``"deg"``), the
``"robot"`` whose wheel budget they were tuned within, and the ``"tuning"``
problem. A file of ``Gains`` field names only loads as fixed gains in radians.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from wmr_jax._src.checks import check_path, require_unbatched
from wmr_jax._src.io import atomic_write_json, json_object_once, os_reason
from wmr_jax._src.model.controllers.schedule import SCHEDULE, SHAPE_FIELDS, TABLES, ScheduleParams
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.model.robots import (
    ROBOT_UNITS,
    check_units,
    is_number,
    robot_from_values,
    robot_json,
    warn_unit_slips,
)
from wmr_jax._src.sim.sensing.loop import ClosedLoop
from wmr_jax._src.tuning.estimation import estimator_from_json, estimator_json
from wmr_jax._src.tuning.parametrisation import GAIN_FIELDS
from wmr_jax._src.tuning.problems import FIXED, SCHEDULED, params_json

_KINDS = {"fixed": (SHIM_SUNG, Gains), "schedule": (SCHEDULE, ScheduleParams)}
_SCHEDULE_FIELDS = (*TABLES, *SHAPE_FIELDS, "v_max", "half_track")

# The unit of each number a tuned_gains.json holds, as its "units" records it:
# the Python API's (angles in radians). "1": a plain number.
PARAM_UNITS = {
    "kr": "cm/s",
    "k_theta": "rad/s",
    "k_turn": "rad/s",
    "phi_m": "rad",
    "r_m": "cm",
    "r_a": "cm",
    "r_e": "cm",
    "alpha": "1",
    "v_max": "cm/s",
    "half_track": "cm",
    "estimator.position": "1",
    "estimator.heading": "1",
    "estimator.wheel_error": "1",
    "estimator.sigma_xy": "cm",
    "estimator.sigma_theta": "rad",
}
# What the tuning commands write beside a tuned_gains.json about its gains;
# ``write_tuned`` removes them, so no folder holds new gains beside the
# judgement of older ones.
JUDGING_TUNED = (
    "evaluation.json",
    "tuning_curve.png",
    "random_search_gains.json",
    "robust_loss.json",
    "robust_evaluation.json",
    "robust_evaluation.md",
)

# The problems a file may say tuned it, and the command that tunes each.
TUNINGS = {"nominal": "wmr-jax tune", "robust": "wmr-jax tune --robust"}

# Angles may be given in degrees instead (a file written by hand).
_DEGREES = "deg"


def tuned_json(
    params: Any, estimator: Any = None, robot: Any = None, *, tuning: str | None = None
) -> dict[str, Any]:
    """Return the ``tuned_gains.json`` content of ``Gains`` or ``ScheduleParams``, a dict to
    ``json.dump`` (``load_tuned`` reads it back).

    Args:
        params: the parameters, or a ``ClosedLoop`` (its params, estimator and robot).
        estimator: the estimator tuned with them (``None``: raw feedback): a
            registered one's name, ``Estimator`` or parameters.
        robot: the ``Robot`` they were tuned for (cm, kg, s); ``None``: not recorded.
        tuning: the problem that tuned them, a key of ``TUNINGS`` (``None``: not recorded).

    Raises:
        ValueError: for anything but one valid parameter set (a scalar per
            field) and robot, naming the field: ``load_tuned`` must read it back.
    """
    if isinstance(params, ClosedLoop):
        robot = params.robot if robot is None else robot
        params, estimator = params.params, params.estimator
    if not isinstance(params, (Gains, ScheduleParams)):
        raise ValueError(
            f"params is a {type(params).__name__}; allowed: a wmr_jax.Gains or a "
            "wmr_jax.controllers.ScheduleParams"
        )
    schedule = isinstance(params, ScheduleParams)
    (SCHEDULE if schedule else SHIM_SUNG).validate(params)
    require_unbatched(params, "params", "one parameter set, a scalar per field")
    values = params_json(SCHEDULED if schedule else FIXED, params)
    sensed = estimator_json(estimator)
    if sensed is not None:
        values["estimator"] = sensed
    names = [k for k in values if k in PARAM_UNITS]
    names += [f"estimator.{k}" for k in values.get("estimator") or {}]
    values["units"] = {name: PARAM_UNITS[name] for name in names if name in PARAM_UNITS}
    if tuning is not None:
        values["tuning"] = _check_tuning(tuning, "tuning")
    if robot is not None:
        robot = validate_one_robot(robot, "tuned_gains.json")
        _check_schedule_robot(params, robot, "robot")
        values["robot"] = robot_json(robot)
        values["robot_units"] = dict(ROBOT_UNITS)
    return values


def write_tuned(folder: Path, values: dict[str, Any]) -> Path:
    """Write ``tuned_json`` ``values`` to ``folder/tuned_gains.json``; drop ``JUDGING_TUNED``."""
    for name in JUDGING_TUNED:
        (folder / name).unlink(missing_ok=True)
    return atomic_write_json(folder / "tuned_gains.json", values)


def _check_tuning(tuning: Any, where: str) -> str:
    if not isinstance(tuning, str) or tuning not in TUNINGS:
        allowed = " or ".join(map(repr, TUNINGS))
        raise ValueError(f"{where} = {tuning!r} is not allowed; allowed: {allowed}")
    return tuning


def tuning_of(path: str | os.PathLike) -> str | None:
    """The problem that tuned a ``tuned_gains.json``: a key of ``TUNINGS``, or ``None`` if unsaid.

    Raises:
        ValueError: one line, if the file cannot be loaded (``load_tuned``).
    """
    return load_tuned_and_tuning(path)[1]


def _check_schedule_robot(params: Any, robot: Robot, where: str) -> None:
    """A schedule caps ``|v| + L|ω|`` with its own ``v_max`` and ``L``: they must be its robot's."""
    if not isinstance(params, ScheduleParams):
        return
    for name in ("v_max", "half_track"):
        mine, theirs = float(getattr(params, name)), float(getattr(robot, name))
        if not math.isclose(mine, theirs, rel_tol=1e-6):  # to float32 rounding
            raise ValueError(
                f"{where}: the schedule's {name} = {mine!r} is not allowed with robot.{name} = "
                f"{theirs!r}; allowed: the same (the schedule was tuned within its robot's "
                "wheel budget)"
            )


def _kind_of(values: dict[str, Any], where: str) -> str:
    for name in ("kind", "controller"):
        if name in values and not isinstance(values[name], str):  # null is no name either
            raise ValueError(
                f"{where}: {name} = {values[name]!r} is not allowed; allowed: a string"
            )
    kind = values.get("kind")
    controller = values.get("controller")
    if kind is None and controller is None:
        return "fixed"  # Gains field names only, as in a file written by hand
    by_name = {c.name: k for k, (c, _) in _KINDS.items()}
    if kind is None:
        kind = by_name.get(controller)
    if kind not in _KINDS or (controller is not None and by_name.get(controller) != kind):
        raise ValueError(
            f"{where}: controller {controller!r} / kind {kind!r} is not allowed; allowed: "
            f"kind 'fixed' (controller 'shim-sung') or 'schedule' ('shim-sung-schedule')"
        )
    return kind


def _in_library_units(values: dict[str, Any], fields: tuple, where: str) -> dict[str, Any]:
    """``values`` with its angles in radians, after checking its ``"units"`` are the library's."""
    if "units" not in values:
        return values  # no units given (a file written by hand): the library's
    units = values["units"]
    if not isinstance(units, dict):
        raise ValueError(
            f"{where}: units = {units!r:.60} is not allowed; allowed: an object "
            "{field: unit} as wmr-jax tune writes it"
        )
    estimator = values.get("estimator")
    known = [*fields, *(k for k in PARAM_UNITS if k.startswith("estimator."))]
    out = dict(values)
    for key, unit in units.items():
        if key not in known:
            raise ValueError(
                f"{where}: units[{key!r}] is not allowed; allowed: keys among {', '.join(known)}"
            )
        mine = PARAM_UNITS[key]
        allowed = (mine, _DEGREES) if mine == "rad" else (mine,)
        if unit not in allowed:
            raise ValueError(
                f"{where}: units[{key!r}] = {unit!r:.60} is not allowed; allowed: "
                f"{' or '.join(map(repr, allowed))}"
            )
        if unit != _DEGREES:
            continue
        if key.startswith("estimator."):
            name = key.split(".", 1)[1]
            if isinstance(estimator, dict) and is_number(estimator.get(name)):
                estimator = {**estimator, name: math.radians(estimator[name])}
                out["estimator"] = estimator
        elif is_number(values.get(key)):
            out[key] = math.radians(values[key])
    return out


def _no_gains(values: dict[str, Any], where: str) -> ValueError:
    """The refusal of a JSON object that holds none of the gains, naming its first keys."""
    keys = ", ".join(repr(k) for k in list(values)[:3]) or "none"
    return ValueError(
        f"{where} holds no gains (its keys: {keys}{', ...' if len(values) > 3 else ''}); "
        "allowed: a tuned_gains.json, as wmr-jax tune writes beside evaluation.json"
    )


def load_tuned(path: str | os.PathLike) -> ClosedLoop:
    """Load a ``tuned_gains.json`` of ``wmr-jax tune`` (fixed gains or a schedule, and estimator).

    ``rollout(ref, loop.params, controller=loop.controller)`` runs the
    result; ``disturbed_metrics(..., estimator=loop.estimator)`` runs it
    whole. A hand-written file of ``Gains`` field names only may leave
    fields out (they keep the paper's values).

    Args:
        path: the JSON file.

    Returns:
        ``ClosedLoop(controller, params, estimator, robot)``: ``SHIM_SUNG``
        with ``Gains`` or ``SCHEDULE`` with ``ScheduleParams``, ``None`` (raw
        feedback) or the estimator parameters saved with them (``ObserverParams``,
        ``EKFParams``, or a registered estimator's),
        and the ``Robot`` they were tuned for (``None`` if the file records
        none); checked.

    Raises:
        ValueError: one line naming the file and what is wrong with it.
    """
    return load_tuned_and_tuning(path)[0]


def load_tuned_and_tuning(path: str | os.PathLike) -> tuple[ClosedLoop, str | None]:
    """``load_tuned``'s loop and ``tuning_of``'s answer, from one reading of the file.

    (A pipe, such as ``/dev/stdin``, can be read only once.)
    """
    path = check_path("path", path)
    where = f"{os.fspath(path)!r}"
    try:
        values = json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=json_object_once)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        # RecursionError: arrays nested beyond Python's recursion limit.
        raise ValueError(f"{where} cannot be read: {os_reason(err)}") from None
    return tuned_from_values(values, where)


def tuned_from_values(values: Any, where: str) -> tuple[ClosedLoop, str | None]:
    """``load_tuned_and_tuning`` of a ``tuned_gains.json``'s content; ``where`` names it."""
    if not isinstance(values, dict):
        raise ValueError(f"{where} is not allowed; allowed: a JSON object")
    kind = _kind_of(values, where)
    controller, cls = _KINDS[kind]
    fields = GAIN_FIELDS if kind == "fixed" else _SCHEDULE_FIELDS
    named = ("kind", "controller", "estimator", "units", "robot", "robot_units", "tuning")
    bad = sorted({k for k in values if k not in named} - set(fields))
    # A file without gains would load as the law's defaults: refused as such.
    holds_gains = bool(values.keys() & set(fields))
    if bad:
        if not holds_gains:
            raise _no_gains(values, where)
        if not values.keys() & {"kind", "controller"} and set(bad) <= set(_SCHEDULE_FIELDS):
            raise ValueError(
                f"{where}: key {bad[0]!r} is a schedule's, but the file names no kind; allowed: "
                "'kind': 'schedule' (as wmr-jax tune --schedule writes), or Gains fields only"
            )
        raise ValueError(
            f"{where}: key {bad[0]!r} is not allowed; allowed: keys among {', '.join(fields)}"
        )
    if "tuning" in values:
        _check_tuning(values["tuning"], f"{where}: tuning")
    values = _in_library_units(values, fields, where)  # angles in radians from here on
    whole = kind == "schedule" or "units" in values or "tuning" in values  # as tune writes it
    estimator = estimator_from_json(values.get("estimator"), where, whole=whole)
    robot = None
    if "robot_units" in values:
        check_units(values["robot_units"], where)
    if "robot" in values:
        robot = robot_from_values(values["robot"], f"{where}: robot")
        warn_unit_slips(robot, f"{where}: robot", ros=False)
    if not holds_gains:
        raise _no_gains(values, where)
    numbers = {k: v for k, v in values.items() if k not in named}
    for name, value in numbers.items():
        table = kind == "schedule" and name in TABLES
        if table:
            ok = isinstance(value, list) and len(value) >= 2 and all(map(is_number, value))
        else:
            ok = is_number(value)
        if not ok:
            shape = "a list of >= 2 numbers" if table else "a number"
            raise ValueError(f"{where}: {name} = {value!r} is not allowed; allowed: {shape}")
    # In a file as wmr-jax tune writes it, a missing field is damage, not a default.
    if whole:
        missing = [name for name in fields if name not in numbers]
        if missing:
            written = "" if kind == "schedule" else " (a file that records its units is whole)"
            raise ValueError(f"{where}: the field {missing[0]!r} is missing{written}")
    # Floats, not JSON's integers: the gains must be differentiable.
    numbers = {
        k: tuple(map(float, v)) if isinstance(v, list) else float(v) for k, v in numbers.items()
    }
    try:
        params = controller.validate(cls(**numbers))
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    if robot is not None:
        _check_schedule_robot(params, robot, where)
    return ClosedLoop(controller, params, estimator, robot), values.get("tuning")
