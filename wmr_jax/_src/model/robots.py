"""Robots as data: presets, JSON files of ``Robot`` fields, ROS ``diff_drive_controller`` YAML.

A robot is named by a preset (``ROBOTS``: ``paper``, ``turtlebot3-burger``,
``pioneer-3dx``) or read from a file:

* ``.json``: one object of ``Robot`` fields in the library's units (cm, kg,
  s; ``ROBOT_UNITS``); a field left out keeps the paper robot's value.
* ``.yaml`` / ``.yml``: the parameters of a ros2_controllers (or ROS 1)
  ``diff_drive_controller``, nested under ``<node>: ros__parameters:`` or
  flat; metres become centimetres (``docs/robots.md``). Its acceleration
  limits become ``accel_max`` and ``angular_accel_max``, which the ideal
  loop's speed limiter applies (``docs/model.md §4.2.2``).

Every file is checked before anything runs, and a mistake is one line
naming the file, the key, its value and what is allowed. The sources of the
presets' numbers are in each preset's comment and in ``docs/robots.md``.
"""

from __future__ import annotations

import dataclasses
import difflib
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
from wmr_jax._src.model.params import Robot, validate_robot

__all__ = [
    "LoadedRobot",
    "RobotUnitsWarning",
    "ROBOTS",
    "ROBOT_FIELDS",
    "ROBOT_UNITS",
    "describe_robot",
    "load_robot",
    "read_robot",
    "robot_from_values",
    "robot_json",
    "robot_name",
    "robot_preset",
    "same_robot",
]

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


# Sizes and speeds no wheeled robot this model describes has (the paper's
# soccer robot: L = 1.85 cm; a warehouse robot: L of some 30 cm, 2 m/s): a
# value outside is most likely written in another unit. The range is wide
# on purpose; the run goes on as given.
PLAUSIBLE = {
    "half_track": (0.5, 500.0, "cm"),
    "wheel_radius": (0.2, 100.0, "cm"),
    "v_max": (1.0, 2000.0, "cm/s"),
}


# A number as typed: Python's, or one NumPy scalar (an array is a batch).
_TYPED_NUMBERS = (int, float, np.integer, np.floating)


def implausible(values: dict[str, Any]) -> list[tuple[str, Any, tuple[float, float, str]]]:
    """The sizes and speeds among ``values`` outside ``PLAUSIBLE``: ``(field, value, range)``.

    Numbers only (arrays and tracers are batches and programs), and within
    ``(0, inf)``: other values are refused where the robot is used.
    """
    found = []
    for field, bounds in PLAUSIBLE.items():
        value = values.get(field)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, _TYPED_NUMBERS):
            continue
        if 0 < value < math.inf and not bounds[0] <= value <= bounds[1]:
            found.append((field, value, bounds))
    return found


def _warn_unit_slips(robot: Robot, where: str, ros: bool) -> None:
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

# ROBOTIS TurtleBot3 Burger. Sourced: wheel separation 0.160 m and wheel radius
# 0.033 m (ROBOTIS turtlebot3, turtlebot3_bringup/param/burger.yaml, "wheels:
# separation / radius"); maximum translational velocity 0.22 m/s, maximum
# rotational velocity 2.84 rad/s, size 138 x 178 x 192 mm, weight 1 kg with SBC,
# battery and sensors (ROBOTIS e-Manual, TurtleBot3 > Specifications > Hardware
# Specifications); each wheel 0.0285 kg (ROBOTIS turtlebot3_simulations, Gazebo
# model of the Burger, wheel link mass 2.8498940e-02 kg); acceleration limits
# 2.5 m/s^2 and 3.2 rad/s^2 (ROBOTIS turtlebot3,
# turtlebot3_navigation2/param/burger.yaml: the local planner's "acc_lim_x: 2.5",
# "acc_lim_theta: 3.2", and the recoveries' "rotational_acc_lim: 3.2").
_BURGER_SEPARATION_CM = 16.0
_BURGER_MASS_KG = 1.0
_BURGER_WHEEL_KG = 0.0285
TURTLEBOT3_BURGER = Robot(
    half_track=_BURGER_SEPARATION_CM / 2,
    # The rim limit is at least either published speed: 22 cm/s straight and
    # 2.84 rad/s × 8 cm = 22.72 cm/s turning in place (the rule of the ROS YAML).
    v_max=max(22.0, 2.84 * _BURGER_SEPARATION_CM / 2),
    body_mass=_BURGER_MASS_KG - 2 * _BURGER_WHEEL_KG,
    # choice: the body as a disc as wide as the robot (178 mm).
    body_diameter=17.8,
    wheel_radius=3.3,
    wheel_mass=_BURGER_WHEEL_KG,
    # choice: not published; the centre of mass on the axle.
    com_offset=0.0,
    # choice: not published as a wheel torque; ~1 g of linear acceleration
    # (the traction limit of a tyre on a floor, μ ≈ 1): g M r / 2 per wheel.
    torque_max=round(_G * _BURGER_MASS_KG * 3.3 / 2, -1),
    # choice: the paper robot's wheel loop, a 10 ms velocity time constant.
    speed_gain=100.0,
    integral_gain=0.0,
    accel_max=250.0,  # 2.5 m/s², the limits ROBOTIS configures for the Burger
    angular_accel_max=3.2,
)

# Adept MobileRobots Pioneer 3-DX. Sourced (the P3-DX datasheet and the
# Pioneer 3 Operations Manual, as widely published): wheel diameter 195 mm,
# maximum forward speed 1.2 m/s, weight 9 kg, width 381 mm (the body, not the
# wheel track). The wheel separation is not in the datasheet: 33 cm wheel to
# wheel, as Player/Stage models the Pioneer DX (B. Gerkey, playerstage-users,
# 2003); ARIA's p3dx.p gives DiffConvFactor 0.0056, i.e. 2 / 0.0056 = 357 mm
# (an odometry factor, "unused in newer firmware"). A JSON file can give yours.
_P3DX_MASS_KG = 9.0
_P3DX_WHEEL_KG = 0.5
PIONEER_3DX = Robot(
    half_track=33.0 / 2,
    v_max=120.0,
    body_mass=_P3DX_MASS_KG - 2 * _P3DX_WHEEL_KG,
    # choice: the body as a disc as wide as the robot (381 mm).
    body_diameter=38.1,
    wheel_radius=19.5 / 2,
    # choice: not published; a 19.5 cm pneumatic wheel with its hub, ~0.5 kg.
    wheel_mass=_P3DX_WHEEL_KG,
    com_offset=0.0,  # choice: not published
    # choice: ~1 g of linear acceleration, as the Burger's.
    torque_max=round(_G * _P3DX_MASS_KG * 9.75 / 2, -2),
    speed_gain=100.0,  # choice: the paper robot's wheel loop
    integral_gain=0.0,
    # Not found in a published source (ARIA's p3dx.p leaves TransAccel and
    # RotAccel to the robot's firmware): no speed limiter. A file can give them.
    accel_max=0.0,
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
    """Whether two single robots have the same fields, to float32 rounding (1e-6 relative).

    A robot that went through a float32 session is still the robot it was.
    """
    fa, fb = _floats(a), _floats(b)
    return all(math.isclose(fa[n], fb[n], rel_tol=1e-6, abs_tol=1e-9) for n in ROBOT_FIELDS)


def robot_name(robot: Robot) -> str | None:
    """The name of the preset ``robot`` equals, or ``None``."""
    return next((name for name, preset in ROBOTS.items() if same_robot(robot, preset)), None)


def describe_robot(robot: Robot) -> str:
    """One line: the preset's name (if any), the fields that set the wheel budget, its limits.

    The acceleration limits are named where the robot gives them (above 0).
    """
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
    """Return one robot as ``{field: float}`` in ``ROBOT_FIELDS`` order (JSON-ready).

    Raises:
        ValueError: for anything but one valid robot (a number per field).
    """
    robot = validate_robot(robot)
    require_unbatched(robot, "robot", "one robot, a number per field")
    return _floats(robot)


# ---------------------------------------------------------------- values from a file


def _is_number(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False  # JSON's true and YAML's yes are no numbers; nor is "22"
    try:
        float(value)  # an integer of 400 digits is beyond any float
    except OverflowError:
        return False
    return True


def robot_from_values(values: Any, where: str) -> Robot:
    """Return the ``Robot`` of ``{field: number}`` (a subset; the rest keep the paper's values).

    Args:
        values: the parsed object (a JSON object of ``Robot`` fields).
        where: what the values came from, first in every message (a file name).

    Raises:
        ValueError: one line naming ``where``, the key, its value and what is
            allowed: an unknown key, a value that is no finite number, or one
            out of range.
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
        if not _is_number(value) or not math.isfinite(float(value)):
            raise ValueError(
                f"{where}: {key} = {value!r:.40} is not allowed; allowed: a finite number "
                f"({_UNIT[key]})"
            )
        if key == "com_offset":
            continue  # either sign; validate_robot keeps it inside the body below
        # 0: no integral action, no acceleration limit.
        zero = key in ("integral_gain", "accel_max", "angular_accel_max")
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
    """Check a file's ``"robot_units"``: each unit named must be the library's for that field.

    Raises:
        ValueError: one line naming ``where``, the field and both units.
    """
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
        note: one line saying which fields of a ROS YAML were used (and into
            which ``Robot`` fields) and which ignored; ``None`` for presets
            and JSON.
        accelerations: the YAML's acceleration limits as read,
            ``{"linear.x.max_acceleration": cm/s²,
            "angular.z.max_acceleration": rad/s²}`` (those given and switched
            on); they are the robot's ``accel_max`` and ``angular_accel_max``.
            ``None`` for presets and JSON.
    """

    robot: Robot
    label: str
    note: str | None = None
    accelerations: Mapping[str, float] | None = None


_SUFFIXES = (".json", ".yaml", ".yml")


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
    if path.suffix.lower() not in _SUFFIXES:
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
        identified = _identified_block(content)
        robot = _robot_from_json(content if identified is None else identified, where)
        _warn_unit_slips(robot, where, ros=False)
        if identified is not None:
            note = (
                f"{text}: the identified robot (its half-track and wheel-loop gain); its "
                "wheel scales, latency and tracker noise act in simulate, evaluate and robustness "
                "only, and centre tune --robust's training"
            )
            return LoadedRobot(robot, text, note)
        return LoadedRobot(robot, text)
    robot, note, accelerations = _robot_from_ros_yaml(content, where)
    _warn_unit_slips(robot, where, ros=True)
    return LoadedRobot(robot, text, note, accelerations)


def load_robot(source: Any) -> Robot:
    """Return the robot of a preset name or a ``.json`` / ``.yaml`` file, checked.

    ``"paper"``, ``"turtlebot3-burger"``, ``"pioneer-3dx"`` (``ROBOTS``); a
    JSON object of ``Robot`` fields in cm, kg, s (any subset: the rest keep
    the paper robot's values); or a ROS ``diff_drive_controller`` YAML
    (``read_robot`` also returns which of its fields were used).

    Raises:
        ValueError: one line naming the file, the key, its value and what is allowed.
    """
    return read_robot(source).robot


def _identified_block(content: str) -> str | None:
    """The ``robot`` block of an ``identify`` output (``identified.json``), else ``None``."""
    try:
        values = json.loads(content)
    except (ValueError, RecursionError):
        return None
    if isinstance(values, dict) and "wheel_scale" in values and "robot" in values:
        return json.dumps(values["robot"])
    return None


def _robot_from_json(content: str, where: str) -> Robot:
    from wmr_jax._src.io import json_object_once

    try:
        values = json.loads(content, object_pairs_hook=json_object_once)
    except (ValueError, RecursionError) as err:
        raise ValueError(f"{where} cannot be read: {' '.join(str(err).split())}") from None
    if not isinstance(values, dict):
        raise ValueError(
            f"{where} is not allowed; allowed: a JSON object of Robot fields in cm, kg, s "
            f"(keys among {', '.join(ROBOT_FIELDS)})"
        )
    return robot_from_values(values, where)


# ---------------------------------------------------------------- ROS diff_drive_controller

# The parameter blocks are found by these keys (every diff_drive_controller has them).
_BLOCK_KEYS = ("wheel_separation", "wheel_radius")
_MAX_DEPTH = 12


def _yaml_mapping_once(loader: Any, node: Any, deep: bool = False) -> Any:
    """Build a YAML mapping, refusing a key given twice (YAML keeps the last without a word)."""
    import yaml

    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            twice = key in seen
            seen.add(key)
        except TypeError:  # an unhashable key: SafeLoader names it below
            continue
        if twice:
            raise yaml.constructor.ConstructorError(
                None, None, f"the key {key!r} is given twice", key_node.start_mark
            )
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


def _yaml_loader() -> type:
    import yaml

    # yaml.safe_load's loader (plain data, no objects), with repeated keys refused.
    class _Loader(yaml.SafeLoader):
        pass

    _Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _yaml_mapping_once)
    return _Loader


def _blocks(tree: Any, path: tuple[str, ...], seen: set[int], out: list) -> None:
    """Collect the mappings that hold ``wheel_separation`` or ``wheel_radius``, with their paths."""
    if not isinstance(tree, dict) or id(tree) in seen or len(path) > _MAX_DEPTH:
        return  # an alias shares its mapping: walked once
    seen.add(id(tree))
    if any(key in tree for key in _BLOCK_KEYS):
        out.append((path, tree))
        return
    for key, value in tree.items():
        _blocks(value, (*path, str(key)), seen, out)


def _flat(tree: dict, prefix: str = "", depth: int = 0, where: str = "") -> dict[str, Any]:
    """``{"linear": {"x": {"max_velocity": v}}}`` as ``{"linear.x.max_velocity": v}``.

    Raises:
        ValueError: for a parameter given twice, dotted and nested
            (``linear.x.max_velocity`` beside ``linear: x: max_velocity``).
    """
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and depth < _MAX_DEPTH:
            inner = _flat(value, name + ".", depth + 1, where)
        else:
            inner = {name: value}
        for twice in inner.keys() & out.keys():
            raise ValueError(
                f"{where}: {twice} is given twice (= {out[twice]!r:.20} and {inner[twice]!r:.20}, "
                "dotted and nested); allowed: each parameter once"
            )
        out.update(inner)
    return out


def _centi(value: float) -> float:
    """``100 value`` (m to cm), without the binary noise of the product (0.033 m is 3.3 cm)."""
    return float(f"{100.0 * value:.15g}")


def _positive(
    params: dict[str, Any], key: str, unit: str, where: str, *, limit: bool = False
) -> float | None:
    """The finite positive number of ``key`` (in the file's unit), ``None`` if absent.

    A ``limit`` (a velocity or acceleration bound) may also be ``.nan``, which
    ros2_controllers reads as "no limit": ``None`` too. A NaN size is refused.
    """
    if key not in params:
        return None
    value = params[key]
    if limit and _is_number(value) and math.isnan(float(value)):
        return None
    if not _is_number(value) or not (math.isfinite(float(value)) and float(value) > 0):
        raise ValueError(
            f"{where}: {key} = {value!r:.40} is not allowed; allowed: a finite number > 0 ({unit})"
        )
    return float(value)


def _limited(params: dict[str, Any], axis: str, where: str, kind: str = "velocity") -> bool:
    """Whether the file enables the ``kind`` limit of ``axis`` (``has_velocity_limits``, ...).

    Without the flag, a limit given is a limit, as recent ros2_controllers
    read it (they dropped the flags; ``.nan`` is no limit there).
    """
    key = f"{axis}.has_{kind}_limits"
    value = params.get(key, True)
    if not isinstance(value, bool):
        raise ValueError(f"{where}: {key} = {value!r:.40} is not allowed; allowed: true or false")
    return value


def _multiplier(params: dict[str, Any], keys: tuple[str, ...], where: str) -> tuple[float, list]:
    """The mean of the calibration multipliers given among ``keys`` (1 if none), and their keys."""
    given = [(k, _positive(params, k, "a factor", where)) for k in keys if k in params]
    given = [(k, v) for k, v in given if v is not None]
    if not given:
        return 1.0, []
    return sum(v for _, v in given) / len(given), [k for k, _ in given]


def _robot_from_ros_yaml(content: str, where: str) -> tuple[Robot, str, dict[str, float]]:
    """The robot of a ``diff_drive_controller`` parameter file, the note of its fields, limits."""
    import yaml

    try:
        tree = yaml.load(content, Loader=_yaml_loader())  # a SafeLoader: plain data only
    except (yaml.YAMLError, RecursionError) as err:
        mark = getattr(err, "problem_mark", None)
        problem = getattr(err, "problem", None)
        text = (
            str(err)
            if problem is None or mark is None
            else (f"{problem} (line {mark.line + 1}, column {mark.column + 1})")
        )
        raise ValueError(f"{where} cannot be read: {' '.join(text.split())}") from None
    if not isinstance(tree, dict):
        raise ValueError(
            f"{where} is not allowed; allowed: a YAML mapping holding diff_drive_controller "
            "parameters (wheel_separation, wheel_radius, in metres)"
        )
    found: list = []
    _blocks(tree, (), set(), found)
    if not found:
        raise ValueError(
            f"{where} holds no diff_drive_controller parameters; allowed: a mapping with "
            "wheel_separation and wheel_radius (m), flat or under <node>: ros__parameters:"
        )
    if len(found) > 1:
        places = ", ".join(".".join(p) or "(top level)" for p, _ in found)
        raise ValueError(
            f"{where} holds {len(found)} sets of diff_drive_controller parameters ({places}); "
            "allowed: one robot's"
        )
    path, block = found[0]
    params = _flat(block, where=where)
    # A value the model reads, given as a mapping, would otherwise be flattened
    # under its name and ignored with the unknown keys.
    read = (*_BLOCK_KEYS, "max_velocity", "max_acceleration", "multiplier", "has_")
    for key in params:
        parent = key.rsplit(".", 1)[0] if "." in key else ""
        if parent and any(part in parent.rsplit(".", 1)[-1] for part in read):
            raise ValueError(
                f"{where}: {parent} is a mapping; allowed: a number (or true/false for a "
                "has_*_limits flag)"
            )
    values: dict[str, float] = {}
    used: list[str] = []
    shown: list[str] = []

    separation = _positive(params, "wheel_separation", "m", where)
    if separation is not None:
        factor, keys = _multiplier(params, ("wheel_separation_multiplier",), where)
        used += ["wheel_separation", *keys]
        values["half_track"] = _centi(separation * factor / 2)  # m -> cm, half of it
        shown.append(f"half_track {values['half_track']:.6g} cm")
    radius = _positive(params, "wheel_radius", "m", where)
    if radius is not None:
        # ROS 2 scales each wheel; this model has one radius: their mean.
        keys_r = (
            "wheel_radius_multiplier",
            "left_wheel_radius_multiplier",
            "right_wheel_radius_multiplier",
        )
        factor, keys = _multiplier(params, keys_r, where)
        used += ["wheel_radius", *keys]
        values["wheel_radius"] = _centi(radius * factor)  # m -> cm
        shown.append(f"wheel_radius {values['wheel_radius']:.6g} cm")

    half_track = values.get("half_track", float(Robot().half_track))
    speeds = []
    for axis, key, unit, to_rim in (
        ("linear.x", "linear.x.max_velocity", "m/s", _centi),  # m/s -> cm/s
        # rad/s -> cm/s at the rim, turning in place: ω L.
        ("angular.z", "angular.z.max_velocity", "rad/s", lambda w: w * half_track),
    ):
        flag = f"{axis}.has_velocity_limits"
        limited = _limited(params, axis, where)
        if flag in params:
            used.append(flag)
        value = _positive(params, key, unit, where, limit=True)
        if value is not None and limited:
            used.append(key)
            speeds.append(to_rim(value))
    if speeds:
        # The rim must reach either limit: it is at least the larger.
        values["v_max"] = max(speeds)
        shown.append(f"v_max {values['v_max']:.6g} cm/s")

    # The speed limiter's acceleration limits, symmetric: ±max_acceleration
    # (min_acceleration, max_deceleration and the *_reverse limits of an
    # asymmetric limiter are not modelled, and land among the ignored).
    accelerations = {}
    for axis, field, unit, convert in (
        ("linear.x", "accel_max", "m/s^2", _centi),  # m/s² -> cm/s²
        ("angular.z", "angular_accel_max", "rad/s^2", float),
    ):
        flag, key = f"{axis}.has_acceleration_limits", f"{axis}.max_acceleration"
        limited = _limited(params, axis, where, "acceleration")
        if flag in params:
            used.append(flag)
        value = _positive(params, key, unit, where, limit=True)
        if value is not None and limited:
            used.append(key)
            accelerations[key] = values[field] = convert(value)
            shown.append(f"{field} {values[field]:.6g} {_UNIT[field]}")

    missing = [key for key in _BLOCK_KEYS if key not in used]
    if missing:
        # diff_drive_controller needs both; the paper robot's in their place
        # would be a robot of another size, run without a word.
        unknown = [key for key in params if "." not in key and key not in used]
        close = difflib.get_close_matches(missing[0], unknown, n=1)
        hint = f" ({close[0]!r} is not a diff_drive_controller parameter)" if close else ""
        raise ValueError(
            f"{where}: the diff_drive_controller parameters at "
            f"'{'.'.join(path) or '(top level)'}' give no {missing[0]}{hint}; allowed: both "
            "wheel_separation and wheel_radius, in metres"
        )
    ignored = [k for k in params if k not in used]
    robot = robot_from_values(values, where)
    # No acceleration limit given is none (the paper robot's 0), not a value kept.
    kept = [
        name
        for name in ROBOT_FIELDS
        if name not in values and name not in ("accel_max", "angular_accel_max")
    ]
    note = (
        f"robot from {where}, diff_drive_controller parameters at "
        f"'{'.'.join(path) or '(top level)'}': used {', '.join(used) or 'nothing'} -> "
        f"{', '.join(shown) or 'no field'}"
        + (
            "; the ideal loop's speed limiter applies these acceleration limits to its "
            "commands (docs/model.md §4.2.2)"
            if accelerations
            else ""
        )
        + f"; ignored: {', '.join(ignored) or 'nothing'}"
        + (f"; the paper robot's values kept: {', '.join(kept)}" if kept else "")
    )
    return robot, note, accelerations
