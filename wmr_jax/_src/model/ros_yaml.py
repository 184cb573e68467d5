"""The robot of a ROS ``diff_drive_controller`` parameter file (``docs/robots.md``).

ros2_controllers (or ROS 1) parameters, nested under ``<node>:
ros__parameters:`` or flat; metres become centimetres. The acceleration limits
become ``accel_max`` and ``angular_accel_max``, which the ideal loop's speed
limiter applies (``docs/model.md §4.2.2``).
"""

from __future__ import annotations

import difflib
import math
from typing import Any

from wmr_jax._src.model.params import Robot
from wmr_jax._src.model.robots import _UNIT, ROBOT_FIELDS, is_number, robot_from_values

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
    """``{"linear": {"x": {"max_velocity": v}}}`` as ``{"linear.x.max_velocity": v}``, each once."""
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

    A ``limit`` may also be ``.nan``, which ros2_controllers reads as "no limit": ``None``.
    """
    if key not in params:
        return None
    value = params[key]
    if limit and is_number(value) and math.isnan(float(value)):
        return None
    if not is_number(value) or not (math.isfinite(float(value)) and float(value) > 0):
        raise ValueError(
            f"{where}: {key} = {value!r:.40} is not allowed; allowed: a finite number > 0 ({unit})"
        )
    return float(value)


def _axis_limit(params: dict, axis: str, kind: str, unit: str, where: str, used: list) -> Any:
    """The ``{axis}.max_{kind}`` limit given and switched on (file's unit), else ``None``.

    Without the ``has_{kind}_limits`` flag a limit given is a limit, as recent
    ros2_controllers read it. The keys read are appended to ``used``.
    """
    flag, key = f"{axis}.has_{kind}_limits", f"{axis}.max_{kind}"
    enabled = params.get(flag, True)
    if not isinstance(enabled, bool):
        raise ValueError(
            f"{where}: {flag} = {enabled!r:.40} is not allowed; allowed: true or false"
        )
    if flag in params:
        used.append(flag)
    value = _positive(params, key, unit, where, limit=True)
    if value is None or not enabled:
        return None
    used.append(key)
    return value


def _multiplier(params: dict[str, Any], keys: tuple[str, ...], where: str) -> tuple[float, list]:
    """The mean of the calibration multipliers given among ``keys`` (1 if none), and their keys."""
    given = [(k, _positive(params, k, "a factor", where)) for k in keys if k in params]
    if not given:
        return 1.0, []
    return sum(v for _, v in given) / len(given), [k for k, _ in given]


# The parameters read besides _BLOCK_KEYS, and the speed limiter's that are
# known but not modelled (ignored as such, never taken for a misspelling).
_READ = (
    "wheel_separation_multiplier",
    *(f"{side}wheel_radius_multiplier" for side in ("", "left_", "right_")),
    *(
        f"{axis}.{name}_{kind}{'_limits' if name == 'has' else ''}"
        for axis in ("linear.x", "angular.z")
        for name in ("max", "has")
        for kind in ("velocity", "acceleration")
    ),
)
_NOT_MODELLED = ("min_velocity", "min_acceleration", "max_deceleration", "max_jerk", "min_jerk")


def _refuse_misspelt(ignored: list[str], params: dict[str, Any], where: str) -> None:
    """Refuse an ignored key that is a near miss of a parameter read and not given."""
    absent = [key for key in _READ if key not in params]
    for key in ignored:
        if key.rsplit(".", 1)[-1].startswith(_NOT_MODELLED):
            continue
        close = difflib.get_close_matches(key, absent, n=1, cutoff=0.9)
        if close:
            raise ValueError(
                f"{where}: {key} is not a diff_drive_controller parameter, and would be "
                f"ignored; allowed: {close[0]}"
            )


def robot_from_ros_yaml(content: str, where: str) -> tuple[Robot, str, dict[str, float]]:
    """The robot of a ``diff_drive_controller`` parameter file, the note of its fields, limits."""
    import yaml

    try:
        tree = yaml.load(content, Loader=_yaml_loader())  # a SafeLoader: plain data only
    except (yaml.YAMLError, RecursionError) as err:
        mark = getattr(err, "problem_mark", None)
        problem = getattr(err, "problem", None)
        text = str(err)
        if problem is not None and mark is not None:
            text = f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
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
    place = ".".join(path) or "(top level)"
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
        keys_r = tuple(f"{side}wheel_radius_multiplier" for side in ("", "left_", "right_"))
        factor, keys = _multiplier(params, keys_r, where)
        used += ["wheel_radius", *keys]
        values["wheel_radius"] = _centi(radius * factor)  # m -> cm
        shown.append(f"wheel_radius {values['wheel_radius']:.6g} cm")

    half_track = values.get("half_track", float(Robot().half_track))
    speeds = []
    for axis, unit, to_rim in (
        ("linear.x", "m/s", _centi),  # m/s -> cm/s
        ("angular.z", "rad/s", lambda w: w * half_track),  # at the rim, turning in place
    ):
        value = _axis_limit(params, axis, "velocity", unit, where, used)
        if value is not None:
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
        value = _axis_limit(params, axis, "acceleration", unit, where, used)
        if value is not None:
            accelerations[f"{axis}.max_acceleration"] = values[field] = convert(value)
            shown.append(f"{field} {values[field]:.6g} {_UNIT[field]}")

    missing = [key for key in _BLOCK_KEYS if key not in used]
    if missing:
        # diff_drive_controller needs both; the paper robot's in their place
        # would be a robot of another size, run without a word.
        unknown = [key for key in params if "." not in key and key not in used]
        close = difflib.get_close_matches(missing[0], unknown, n=1)
        hint = f" ({close[0]!r} is not a diff_drive_controller parameter)" if close else ""
        raise ValueError(
            f"{where}: the diff_drive_controller parameters at '{place}' give no "
            f"{missing[0]}{hint}; allowed: both wheel_separation and wheel_radius, in metres"
        )
    ignored = [k for k in params if k not in used]
    _refuse_misspelt(ignored, params, where)
    robot = robot_from_values(values, where)
    # No acceleration limit given is none (the paper robot's 0), not a value kept.
    limits = ("accel_max", "angular_accel_max")
    kept = [name for name in ROBOT_FIELDS if name not in values and name not in limits]
    note = (
        f"robot from {where}, diff_drive_controller parameters at '{place}': used "
        f"{', '.join(used) or 'nothing'} -> {', '.join(shown) or 'no field'}"
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
