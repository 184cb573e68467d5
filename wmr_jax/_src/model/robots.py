"""Robots as data: presets, JSON files of ``Robot`` fields, ROS ``diff_drive_controller`` YAML.

A JSON file gives ``Robot`` fields in the library's units (``ROBOT_UNITS``; a
field left out keeps the paper robot's value); a YAML file is read by
``ros_yaml.py``. A mistake in a file is one line naming the file, the key,
its value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import types
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from wmr_jax._src.checks import require_unbatched
from wmr_jax._src.model.params import NON_NEGATIVE_ROBOT_FIELDS, Robot, validate_robot

ROBOT_FIELDS = tuple(f.name for f in dataclasses.fields(Robot))

# The unit of each Robot field, as tuned_gains.json records it beside the robot.
ROBOT_UNITS = {
    "half_track": "cm (half the wheel separation)",
    "v_max": "cm/s (wheel rim speed limit)",
    "body_mass": "kg",
    "body_diameter": "cm",
    "wheel_radius": "cm",
    "wheel_mass": "kg (each wheel)",
    "com_offset": "cm",
    "torque_max": "kg*cm^2/s^2 (1 N*m = 1e4)",
    "speed_gain": "1/s",
    "integral_gain": "1/s^2",
    "accel_max": "cm/s^2 (linear command acceleration limit, 0: none)",
    "angular_accel_max": "rad/s^2 (angular command acceleration limit, 0: none)",
}
# The unit alone, for messages ("a number > 0 (cm/s)").
_UNIT = {name: text.split(" (")[0] for name, text in ROBOT_UNITS.items()}

_G = 981.0  # cm/s², standard gravity


class RobotUnitsWarning(UserWarning):
    """A robot's size or speed looks like a unit slip (metres where cm belong, or cm in ROS)."""


# Sizes and speeds outside these wide ranges are most likely written in
# another unit; the run goes on as given.
PLAUSIBLE = {
    "half_track": (0.5, 500.0, "cm"),
    "wheel_radius": (0.2, 100.0, "cm"),
    "v_max": (1.0, 2000.0, "cm/s"),
    # Floors and tyres grip at about 1 g; 0 (no limit) is not a slip.
    "accel_max": (5.0, 10_000.0, "cm/s^2"),
}


# A number as typed: Python's, or one NumPy scalar (an array is a batch).
_TYPED_NUMBERS = (int, float, np.integer, np.floating)


def implausible(values: dict[str, Any]) -> list[tuple[str, Any, tuple[float, float, str]]]:
    """The sizes and speeds among ``values`` outside ``PLAUSIBLE``: ``(field, value, range)``.

    Plain numbers in ``(0, inf)`` only; other values are refused where the robot is used.
    """
    found = []
    for field, bounds in PLAUSIBLE.items():
        value = values.get(field)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, _TYPED_NUMBERS):
            continue
        if 0 < value < math.inf and not bounds[0] <= value <= bounds[1]:
            found.append((field, value, bounds))
    return found


def warn_unit_slips(robot: Robot, where: str, ros: bool) -> None:
    """Warn (``RobotUnitsWarning``) for each size or speed of a file outside ``PLAUSIBLE``."""
    convention = (
        "a ROS file gives metres and m/s: wheel_separation 0.16 for 16 cm"
        if ros
        else "a JSON robot file gives cm and cm/s: half_track 8 for 8 cm"
    )
    for field, value, (low, high, _) in implausible(vars(robot)):
        warnings.warn(
            f"{where}: {field} = {value:.6g} {_UNIT[field]} is outside {low:g}-{high:g} "
            f"{_UNIT[field]}, as if written in another unit ({convention}); it runs as given",
            RobotUnitsWarning,
            stacklevel=4,
        )


# ---------------------------------------------------------------- presets

# The presets' sources and choices, value by value, are in docs/robots.md.
_BURGER_SEPARATION_CM = 16.0
_BURGER_MASS_KG = 1.0
_BURGER_WHEEL_KG = 0.0285
TURTLEBOT3_BURGER = Robot(
    half_track=_BURGER_SEPARATION_CM / 2,
    # The larger rim speed of 22 cm/s straight and 2.84 rad/s turning in place.
    v_max=max(22.0, 2.84 * _BURGER_SEPARATION_CM / 2),
    body_mass=_BURGER_MASS_KG - 2 * _BURGER_WHEEL_KG,
    body_diameter=17.8,  # choice: the robot's width
    wheel_radius=3.3,
    wheel_mass=_BURGER_WHEEL_KG,
    com_offset=0.0,  # choice
    # choice: ~1 g of linear acceleration (a tyre's traction, μ ≈ 1): g M r / 2 per wheel.
    torque_max=round(_G * _BURGER_MASS_KG * 3.3 / 2, -1),
    speed_gain=100.0,  # choice: the paper robot's wheel loop
    integral_gain=0.0,
    accel_max=250.0,
    angular_accel_max=3.2,
)

_P3DX_MASS_KG = 9.0
_P3DX_WHEEL_KG = 0.5  # choice
PIONEER_3DX = Robot(
    half_track=33.0 / 2,  # as Player/Stage models it; the datasheet gives none
    v_max=120.0,
    body_mass=_P3DX_MASS_KG - 2 * _P3DX_WHEEL_KG,
    body_diameter=38.1,  # choice: the robot's width
    wheel_radius=19.5 / 2,
    wheel_mass=_P3DX_WHEEL_KG,
    com_offset=0.0,  # choice
    torque_max=round(_G * _P3DX_MASS_KG * 9.75 / 2, -2),  # choice: as the Burger's
    speed_gain=100.0,  # choice
    integral_gain=0.0,
    accel_max=0.0,  # none published
    angular_accel_max=0.0,
)

# Read-only: a preset is shared by every caller (Robot itself is frozen).
ROBOTS: Mapping[str, Robot] = types.MappingProxyType(
    {"paper": Robot(), "turtlebot3-burger": TURTLEBOT3_BURGER, "pioneer-3dx": PIONEER_3DX}
)
"""The preset robots by name: ``paper`` (Table 1 of the paper, ``Robot()``), a
ROBOTIS TurtleBot3 Burger and an Adept MobileRobots Pioneer 3-DX (docs/robots.md)."""


def robot_preset(name: str) -> Robot:
    """Return the preset robot ``name`` (one of ``ROBOTS``).

    Raises:
        ValueError: for another name, listing the presets.
    """
    if not isinstance(name, str) or name not in ROBOTS:
        raise ValueError(
            f"robot preset {name!r:.80} is not known; allowed: {', '.join(ROBOTS)}, or a "
            ".json or .yaml file"
        )
    return ROBOTS[name]


# ---------------------------------------------------------------- comparing and showing


def _floats(robot: Robot) -> dict[str, float]:
    return {name: float(np.asarray(getattr(robot, name))) for name in ROBOT_FIELDS}


def same_robot(a: Robot, b: Robot) -> bool:
    """Whether two single robots have the same fields, to float32 rounding (1e-6 relative)."""
    fa, fb = _floats(a), _floats(b)
    return all(math.isclose(fa[n], fb[n], rel_tol=1e-6, abs_tol=1e-9) for n in ROBOT_FIELDS)


def robot_name(robot: Robot) -> str | None:
    """The name of the preset ``robot`` equals, or ``None``."""
    return next((name for name, preset in ROBOTS.items() if same_robot(robot, preset)), None)


def describe_robot(robot: Robot) -> str:
    """One line: the preset's name (if any), the fields that set the wheel budget, its limits."""
    f = _floats(robot)
    name = robot_name(robot) or "custom"
    limits = "".join(
        f", {field} = {f[field]:.4g} {_UNIT[field]}"
        for field in ("accel_max", "angular_accel_max")
        if f[field] > 0
    )
    return (
        f"{name} (L = {f['half_track']:.4g} cm, V_max = {f['v_max']:.4g} cm/s, "
        f"r = {f['wheel_radius']:.4g} cm, M = {f['body_mass']:.4g} kg{limits})"
    )


def robot_json(robot: Robot) -> dict[str, float]:
    """Return one valid robot (a number per field) as ``{field: float}``, ``ROBOT_FIELDS`` order."""
    robot = validate_robot(robot)
    require_unbatched(robot, "robot", "one robot, a number per field")
    return _floats(robot)


# ---------------------------------------------------------------- values from a file


def is_number(value: Any) -> bool:
    """Whether a value read from JSON or YAML is a number a float holds (not a bool or str)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False  # JSON's true and YAML's yes are no numbers; nor is "22"
    try:
        float(value)  # an integer of 400 digits is beyond any float
    except OverflowError:
        return False
    return True


def robot_from_values(values: Any, where: str) -> Robot:
    """Return the ``Robot`` of ``{field: number}`` (a subset; the rest keep the paper's values).

    ``where`` (a file name) opens every message: one line naming the key,
    its value and what is allowed.
    """
    if not isinstance(values, Mapping):
        raise ValueError(
            f"{where} is not allowed; allowed: an object of Robot fields "
            f"({', '.join(ROBOT_FIELDS)})"
        )
    for key, value in values.items():
        if key not in ROBOT_FIELDS:
            raise ValueError(
                f"{where}: key {key!r} (= {value!r:.40}) is not allowed; allowed: keys among "
                + ", ".join(ROBOT_FIELDS)
            )
        if not is_number(value) or not math.isfinite(float(value)):
            raise ValueError(
                f"{where}: {key} = {value!r:.40} is not allowed; allowed: a finite number "
                f"({_UNIT[key]})"
            )
        if key == "com_offset":
            continue  # either sign; validate_robot keeps it inside the body below
        zero = key in NON_NEGATIVE_ROBOT_FIELDS  # 0: none (no integral action, no limit)
        low = ">= 0" if zero else "> 0"
        if not (float(value) >= 0 if zero else float(value) > 0):
            raise ValueError(
                f"{where}: {key} = {value!r} is not allowed; allowed: a number {low} ({_UNIT[key]})"
            )
    # Floats, not JSON's integers: a robot's fields may be differentiated.
    robot = Robot(**{key: float(value) for key, value in values.items()})
    try:
        return validate_robot(robot)  # what spans fields (the centre of mass inside the body)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None


def check_units(units: Any, where: str) -> None:
    """Check a file's ``"robot_units"``: each unit named must be the library's for that field."""
    if not isinstance(units, Mapping):
        raise ValueError(
            f"{where}: robot_units = {units!r:.60} is not allowed; allowed: an object "
            "{field: unit} as wmr-jax tune writes it"
        )
    for key, unit in units.items():
        if key not in ROBOT_UNITS or unit != ROBOT_UNITS[key]:
            allowed = repr(ROBOT_UNITS[key]) if key in ROBOT_UNITS else "keys among Robot fields"
            raise ValueError(
                f"{where}: robot_units[{key!r}] = {unit!r:.60} is not allowed; allowed: "
                f"{allowed} (the numbers are read in the library's units)"
            )


# ---------------------------------------------------------------- reading files


class LoadedRobot(NamedTuple):
    """A robot read from a preset name or a file, with what the reading noted.

    Attributes:
        robot: the checked ``Robot``.
        label: the preset name or the file's path.
        note: which fields of a ROS YAML were used and which ignored, one
            line (an identified robot's too); else ``None``.
        accelerations: the YAML's acceleration limits given and switched on,
            ``{"linear.x.max_acceleration": cm/s², "angular.z.max_acceleration":
            rad/s²}``; else ``None``.
    """

    robot: Robot
    label: str
    note: str | None = None
    accelerations: Mapping[str, float] | None = None


def read_robot(source: Any) -> LoadedRobot:
    """Read a robot from a preset name or a ``.json`` / ``.yaml`` file; say what was used.

    Raises:
        ValueError: one line naming the source and what is wrong with it.
    """
    if isinstance(source, str) and source in ROBOTS:
        return LoadedRobot(ROBOTS[source], source)
    text = os.fspath(source) if isinstance(source, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text:
        raise ValueError(
            f"robot = {source!r:.80} is not allowed; allowed: a preset name "
            f"({', '.join(ROBOTS)}) or the path of a .json or .yaml file"
        )
    where = repr(text)
    path = Path(text)
    if path.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise ValueError(
            f"{where} is not allowed; allowed: a preset ({', '.join(ROBOTS)}), or a file "
            "ending in .json (Robot fields) or .yaml/.yml (a ROS diff_drive_controller)"
        )
    if path.is_dir():
        raise ValueError(f"{where} is not allowed: it is a folder; allowed: a file")
    if not path.exists():
        raise ValueError(f"{where} cannot be read: there is no such file")
    try:
        content = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"{where} cannot be read: {' '.join(str(err).split())}") from None
    if path.suffix.lower() == ".json":
        robot, identified = _robot_from_json(content, where)
        warn_unit_slips(robot, where, ros=False)
        if identified:
            note = (
                f"{text}: the identified robot (its half-track and wheel-loop gain); its "
                "wheel scales, latency and tracker noise act in simulate, evaluate and robustness "
                "only, and centre tune --robust's training"
            )
            return LoadedRobot(robot, text, note)
        return LoadedRobot(robot, text)
    from wmr_jax._src.model.ros_yaml import robot_from_ros_yaml

    robot, note, accelerations = robot_from_ros_yaml(content, where)
    warn_unit_slips(robot, where, ros=True)
    return LoadedRobot(robot, text, note, accelerations)


def load_robot(source: Any) -> Robot:
    """Return the robot of a preset name (``ROBOTS``) or a ``.json`` / ``.yaml`` file, checked.

    A JSON file gives ``Robot`` fields in cm, kg, s (any subset); a YAML file
    is a ROS ``diff_drive_controller``'s (``read_robot`` also says what was used).

    Raises:
        ValueError: one line naming the file, the key, its value and what is allowed.
    """
    return read_robot(source).robot


def _robot_from_json(content: str, where: str) -> tuple[Robot, bool]:
    """The robot of a JSON file, and whether it is the ``robot`` block of an ``identify`` output."""
    from wmr_jax._src.io import json_object_once

    try:
        values = json.loads(content, object_pairs_hook=json_object_once)
    except (ValueError, RecursionError) as err:
        raise ValueError(f"{where} cannot be read: {' '.join(str(err).split())}") from None
    identified = isinstance(values, dict) and "wheel_scale" in values and "robot" in values
    if identified:
        values = values["robot"]
    elif isinstance(values, dict) and "controller" in values:  # wmr-jax tune's tuned_gains.json
        raise ValueError(
            f"{where} is a tuned gains file (it names a controller), not a robot; allowed: a "
            "JSON object of Robot fields (a tuned file's own robot comes with it as --gains)"
        )
    if not isinstance(values, dict):
        raise ValueError(
            f"{where} is not allowed; allowed: a JSON object of Robot fields in cm, kg, s "
            f"(keys among {', '.join(ROBOT_FIELDS)})"
        )
    return robot_from_values(values, where), identified
