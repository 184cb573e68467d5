"""What a robot file's numbers mean (docs/robots.md): ROS calibration multipliers and the messages.

Each expected value is computed here from the file's own numbers (metres to
centimetres by hand), never taken from the reader.
"""

import dataclasses
import json
import re

import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.model.robots import (
    ROBOT_FIELDS,
    describe_robot,
    implausible,
    read_robot,
    robot_json,
    same_robot,
)


def _read(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return w.dynamics.read_robot(path)


def test_ros_calibration_multipliers_scale_the_sizes_they_name(tmp_path):
    # ros2_controllers multiplies the track by wheel_separation_multiplier and
    # each wheel by its own radius multiplier; the model has one radius: their mean.
    read = _read(
        tmp_path,
        "calibrated.yaml",
        "wheel_separation: 0.30\nwheel_separation_multiplier: 1.1\nwheel_radius: 0.05\n"
        "left_wheel_radius_multiplier: 1.04\nright_wheel_radius_multiplier: 0.98\n",
    )
    assert read.robot.half_track == pytest.approx(100 * 0.30 * 1.1 / 2, rel=1e-12)  # 16.5 cm
    assert read.robot.wheel_radius == pytest.approx(100 * 0.05 * (1.04 + 0.98) / 2, rel=1e-12)
    used = read.note.split("used ", 1)[1].split(" -> ", 1)[0].split(", ")
    assert used == [
        "wheel_separation",
        "wheel_separation_multiplier",
        "wheel_radius",
        "left_wheel_radius_multiplier",
        "right_wheel_radius_multiplier",
    ]
    # One multiplier for both wheels (ROS 1's name) scales the radius alone.
    read = _read(
        tmp_path,
        "one.yaml",
        "wheel_separation: 0.30\nwheel_radius: 0.05\nwheel_radius_multiplier: 1.2\n",
    )
    assert read.robot.half_track == pytest.approx(15.0, rel=1e-12)
    assert read.robot.wheel_radius == pytest.approx(6.0, rel=1e-12)
    assert "used wheel_separation, wheel_radius, wheel_radius_multiplier ->" in read.note


def test_a_yaml_syntax_error_names_its_line_and_column(tmp_path):
    lines = ["diff_drive_controller:", "  ros__parameters:", "    wheel_radius: : 0.033"]
    column = lines[2].index(": :") + 3  # 1-based column of the second colon
    path = tmp_path / "broken.yaml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError) as err:
        w.dynamics.read_robot(path)
    message = str(err.value)
    assert message.startswith(f"{str(path)!r} cannot be read: ")
    assert message.endswith(f"mapping values are not allowed here (line 3, column {column})")


def test_two_robots_in_one_file_are_named_by_their_paths(tmp_path):
    text = "".join(
        f"{side}:\n  ros__parameters:\n    wheel_separation: 0.3\n" for side in ("left", "right")
    )
    with pytest.raises(ValueError) as err:
        _read(tmp_path, "two.yaml", text)
    assert str(err.value).endswith(
        "holds 2 sets of diff_drive_controller parameters "
        "(left.ros__parameters, right.ros__parameters); allowed: one robot's"
    )


def test_a_flat_file_is_read_at_the_top_level(tmp_path):
    read = _read(tmp_path, "flat.yaml", "wheel_separation: 0.2\nwheel_radius: 0.05\n")
    assert "parameters at '(top level)': used wheel_separation, wheel_radius" in read.note
    assert read.robot.half_track == pytest.approx(10.0, rel=1e-12)


def test_a_limit_flag_that_is_not_a_boolean_is_refused_naming_the_file(tmp_path):
    text = (
        "wheel_separation: 0.3\nlinear:\n  x:\n    has_velocity_limits: 3\n    max_velocity: 0.5\n"
    )
    path = tmp_path / "flag.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        w.dynamics.read_robot(path)
    assert str(err.value) == (
        f"{str(path)!r}: linear.x.has_velocity_limits = 3 is not allowed; allowed: true or false"
    )


def test_an_unknown_preset_lists_the_presets_and_the_files_allowed():
    with pytest.raises(ValueError) as err:
        w.dynamics.robot_preset("burger")
    presets = ", ".join(w.ROBOTS)
    assert str(err.value) == (
        f"robot preset 'burger' is not known; allowed: {presets}, or a .json or .yaml file"
    )


@pytest.mark.parametrize(
    ("units", "allowed"),
    [
        # docs/model.md: lengths in cm, speeds in cm/s; the unit named, then what it measures.
        ({"v_max": "m/s"}, r"'cm/s \(wheel rim speed limit\)'"),
        ({"half_track": "m"}, r"'cm \(half the wheel separation\)'"),
        ({"mass": "kg"}, "keys among Robot fields"),
    ],
    ids=["v_max", "half_track", "not-a-field"],
)
def test_a_unit_other_than_the_librarys_is_refused_with_the_librarys(tmp_path, units, allowed):
    values = tuning.tuned_json(w.Gains(kr=30.0), robot=w.ROBOTS["pioneer-3dx"])
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps({**values, "robot_units": units}))
    ((key, unit),) = units.items()
    message = re.escape(f"robot_units[{key!r}] = {unit!r} is not allowed; allowed: ") + allowed
    with pytest.raises(ValueError, match=message + re.escape(" (the numbers are read in the")):
        w.load_tuned(path)


def test_robot_units_that_are_not_an_object_are_refused(tmp_path):
    values = tuning.tuned_json(w.Gains(kr=30.0), robot=w.ROBOTS["pioneer-3dx"])
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps({**values, "robot_units": ["cm"]}))
    message = (
        "robot_units = ['cm'] is not allowed; allowed: an object {field: unit} "
        "as wmr-jax tune writes it"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        w.load_tuned(path)


def test_a_mapping_given_for_a_limit_flag_is_refused(tmp_path):
    # Flattened, it would land among the ignored keys and the flag would read as true.
    text = "wheel_separation: 0.3\nlinear:\n  x:\n    has_velocity_limits:\n      a: 1\n"
    with pytest.raises(ValueError, match=re.escape("linear.x.has_velocity_limits is a mapping;")):
        _read(tmp_path, "flag_map.yaml", text)


def test_a_saved_robot_that_is_not_an_object_is_refused_listing_the_fields(tmp_path):
    values = tuning.tuned_json(w.Gains(kr=30.0), robot=w.ROBOTS["pioneer-3dx"])
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps({**values, "robot": [1, 2]}))
    fields = ", ".join(f.name for f in dataclasses.fields(w.Robot))
    message = f"robot is not allowed; allowed: an object of Robot fields ({fields})"
    with pytest.raises(ValueError, match=re.escape(message)):
        w.load_tuned(path)


def test_a_batch_of_robots_is_not_one_robot_to_save():
    with pytest.raises(ValueError) as err:
        robot_json(w.Robot(v_max=[100.0, 120.0]))
    assert str(err.value) == "robot.v_max has shape (2,); allowed: one robot, a number per field"


def test_a_robot_is_described_by_its_wheel_budget_and_the_limits_it_gives():
    paper = w.Robot()
    r, mass = float(paper.wheel_radius), float(paper.body_mass)
    budget = f"L = 8 cm, V_max = 22 cm/s, r = {r:g} cm, M = {mass:g} kg"
    assert describe_robot(w.Robot(half_track=8.0, v_max=22.0)) == f"custom ({budget})"
    # A limit is shown where the robot gives one (above 0), however small.
    limited = w.Robot(half_track=8.0, v_max=22.0, accel_max=0.5, angular_accel_max=30.0)
    assert describe_robot(limited) == (
        f"custom ({budget}, accel_max = 0.5 cm/s^2, angular_accel_max = 30 rad/s^2)"
    )
    assert describe_robot(w.ROBOTS["pioneer-3dx"]).startswith("pioneer-3dx (L = 16.5 cm, ")


def test_robots_are_the_same_to_float32_rounding_and_no_further():
    paper = w.Robot()
    v_max = float(paper.v_max)
    assert same_robot(paper, w.Robot(v_max=v_max * (1 + 5e-7)))  # within float32's rounding
    assert not same_robot(paper, w.Robot(v_max=v_max * (1 + 2e-6)))
    assert not same_robot(paper, w.Robot(v_max=v_max + 0.01))
    # A field that is zero (the centre of mass on the axle) compares absolutely.
    assert same_robot(paper, w.Robot(com_offset=1e-12))
    assert not same_robot(paper, w.Robot(com_offset=1e-6))


@pytest.mark.parametrize(
    ("block", "missing", "hint"),
    [
        ("wheel_seperation: 0.16\n    wheel_radius: 0.033\n", "wheel_separation",
         " ('wheel_seperation' is not a diff_drive_controller parameter)"),
        ("wheel_separation: 0.16\n", "wheel_radius", ""),
    ],
    ids=["typo", "no-radius"],
)  # fmt: skip
def test_a_ros_file_without_both_wheel_sizes_is_refused(tmp_path, block, missing, hint):
    # diff_drive_controller needs both; the paper robot's size in place of a
    # misspelt one would be another robot, run without a word.
    with pytest.raises(ValueError) as info:
        _read(tmp_path, "r.yaml", "diff_drive_controller:\n  ros__parameters:\n    " + block)
    assert str(info.value) == (
        f"'{tmp_path / 'r.yaml'}': the diff_drive_controller parameters at "
        f"'diff_drive_controller.ros__parameters' give no {missing}{hint}; allowed: both "
        "wheel_separation and wheel_radius, in metres"
    )


@pytest.mark.parametrize(
    ("given", "typo", "meant"),
    [
        (
            "linear:\n  x:\n    max_velcoity: 0.22\n",
            "linear.x.max_velcoity",
            "linear.x.max_velocity",
        ),
        (
            "angular.z.max_acceleraton: 3.0\n",
            "angular.z.max_acceleraton",
            "angular.z.max_acceleration",
        ),
        (
            "linear.x.has_velocity_limit: true\n",
            "linear.x.has_velocity_limit",
            "linear.x.has_velocity_limits",
        ),
        (
            "wheel_separation_multiplyer: 1.02\n",
            "wheel_separation_multiplyer",
            "wheel_separation_multiplier",
        ),
    ],
)
def test_a_misspelt_ros_parameter_is_refused_not_ignored(tmp_path, given, typo, meant):
    sizes = "wheel_separation: 0.16\nwheel_radius: 0.033\n"
    with pytest.raises(ValueError) as info:
        _read(tmp_path, "r.yaml", sizes + given)
    assert str(info.value) == (
        f"'{tmp_path / 'r.yaml'}': {typo} is not a diff_drive_controller parameter, and "
        f"would be ignored; allowed: {meant}"
    )


def test_ros_parameters_the_model_leaves_out_are_ignored_not_taken_for_misspellings(tmp_path):
    sizes = "wheel_separation: 0.16\nwheel_radius: 0.033\n"
    # The limiter's other limits without the ones the model reads: each is one
    # letter or so from an absent parameter that is read (min_ / max_, de- / ac-).
    others = "".join(
        f"{axis}.{name}: 1.0\n"
        for axis in ("linear.x", "angular.z")
        for name in ("min_velocity", "min_acceleration", "max_deceleration", "max_jerk", "min_jerk")
    )
    # Further from any of them: ignored as well (the reverse limits, the jerk flag).
    others += "linear.x.max_acceleration_reverse: 1.0\nangular.z.has_jerk_limits: false\n"
    read = _read(tmp_path, "others.yaml", sizes + others)
    assert read.robot.v_max == w.Robot().v_max and read.accelerations == {}
    assert "ignored: linear.x.min_velocity, linear.x.min_acceleration" in read.note
    # Limits on one axis only, flags included: the other axis's names are absent.
    angular = (
        "angular:\n  z:\n    has_velocity_limits: true\n    has_acceleration_limits: true\n"
        "    max_velocity: 2.84\n    max_acceleration: 3.2\n"
    )
    read = _read(tmp_path, "angular.yaml", sizes + angular)
    assert read.robot.v_max == pytest.approx(2.84 * 8.0)
    # A near miss of a parameter that is given is only ignored: the name meant is there.
    both = "linear.x.max_velocity: 0.22\nlinear.y.max_velocity: 0.5\n"
    read = _read(tmp_path, "both.yaml", sizes + both)
    assert read.robot.v_max == pytest.approx(22.0) and "ignored: linear.y.max_velocity" in read.note


def test_sizes_and_speeds_in_the_wrong_unit_warn_and_run_as_given(tmp_path):
    # A ROS file written in cm: a robot 16 m wide with 3.3 m wheels, at 22 m/s.
    ros = "wheel_separation: 16\nwheel_radius: 3.3\nlinear:\n  x:\n    max_velocity: 22\n"
    with pytest.warns(w.RobotUnitsWarning) as caught:
        read = _read(tmp_path, "cm.yaml", ros)
    assert (read.robot.half_track, read.robot.wheel_radius) == (800.0, 330.0)  # as given
    texts = [str(c.message) for c in caught]
    where = repr(str(tmp_path / "cm.yaml"))
    assert texts == [
        f"{where}: {field} = {value} is outside {bounds}, as if written in another unit (a ROS "
        "file gives metres and m/s: wheel_separation 0.16 for 16 cm); it runs as given"
        for field, value, bounds in (
            ("half_track", "800 cm", "0.5-500 cm"),
            ("wheel_radius", "330 cm", "0.2-100 cm"),
            ("v_max", "2200 cm/s", "1-2000 cm/s"),
        )
    ]
    # A JSON file in metres and m/s: L = 8 cm written 0.08.
    with pytest.warns(w.RobotUnitsWarning) as caught:
        _read(tmp_path, "m.json", json.dumps({"half_track": 0.08, "v_max": 0.22}))
    texts = [str(c.message) for c in caught]
    assert len(texts) == 2 and "half_track = 0.08 cm is outside 0.5-500 cm" in texts[0]
    assert "v_max = 0.22 cm/s is outside 1-2000 cm/s" in texts[1]
    assert texts[0].endswith(
        "(a JSON robot file gives cm and cm/s: half_track 8 for 8 cm); it runs as given"
    )
    # At the bounds, and every preset, no warning.
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", w.RobotUnitsWarning)
        edge = {"half_track": 0.5, "v_max": 2000.0, "wheel_radius": 100.0}
        _read(tmp_path, "edge.json", json.dumps(edge))
        _read(
            tmp_path,
            "edge2.json",
            json.dumps({"half_track": 500.0, "v_max": 1.0, "wheel_radius": 0.2}),
        )
        for name in w.ROBOTS:
            (tmp_path / f"{name}.json").write_text(json.dumps(robot_json(w.ROBOTS[name])))
            w.dynamics.read_robot(tmp_path / f"{name}.json")


def test_a_ros_parameter_given_dotted_and_nested_is_refused(tmp_path):
    # Which of the two ROS would read depends on how the file is loaded: neither is guessed.
    text = (
        "wheel_separation: 0.16\nwheel_radius: 0.033\nlinear.x.max_velocity: 0.22\n"
        "linear:\n  x:\n    max_velocity: 0.3\n"
    )
    with pytest.raises(ValueError) as info:
        _read(tmp_path, "twice.yaml", text)
    assert str(info.value) == (
        f"'{tmp_path / 'twice.yaml'}': linear.x.max_velocity is given twice (= 0.22 and 0.3, "
        "dotted and nested); allowed: each parameter once"
    )
    # Inside a block too, the file named: linear: {x.max_velocity, x: {max_velocity}}.
    nested = "wheel_separation: 0.16\nwheel_radius: 0.033\nlinear:\n  x.max_velocity: 0.22\n" \
        "  x:\n    max_velocity: 0.3\n"  # fmt: skip
    with pytest.raises(ValueError) as info:
        _read(tmp_path, "deep.yaml", nested)
    assert str(info.value).startswith(
        f"'{tmp_path / 'deep.yaml'}': linear.x.max_velocity is given twice (= 0.22 and 0.3,"
    )
    # Each spelling alone is read alike.
    for name, limit in (("dotted", "linear.x.max_velocity: 0.3\n"),
                        ("nested", "linear:\n  x:\n    max_velocity: 0.3\n")):  # fmt: skip
        robot = _read(tmp_path, f"{name}.yaml", "wheel_separation: 0.16\nwheel_radius: "
                      "0.033\n" + limit).robot  # fmt: skip
        assert robot.v_max == 30.0


def test_a_robot_built_in_python_takes_cm_as_given_and_never_warns():
    """``Robot(...)`` is in cm by definition: only files and flags are read in a unit.

    The constructor cannot tell a user's call from the copies JAX and the
    library make of a robot, so it warns about nothing; the units warning
    belongs to the loaders (``test_sizes_and_speeds_in_the_wrong_unit_warn...``).
    """
    import warnings

    import jax

    with warnings.catch_warnings():
        warnings.simplefilter("error", w.RobotUnitsWarning)
        robot = w.Robot(half_track=0.08, v_max=0.22)
        assert (robot.half_track, robot.v_max) == (0.08, 0.22)
        copy = robot.replace(half_track=0.09, body_mass=2.0)
        assert (copy.half_track, copy.body_mass, copy.v_max) == (0.09, 2.0, 0.22)
        assert jax.tree.map(lambda x: x, robot) == robot
        assert dataclasses.replace(w.Robot(), v_max=0.3).v_max == 0.3


def test_an_identify_output_gives_its_robot_block_and_says_so(tmp_path):
    identified = {"wheel_scale": [1.01, 0.99], "robot": {"half_track": 9.5, "v_max": 30.0}}
    path = tmp_path / "identified.json"
    path.write_text(json.dumps(identified))
    loaded = read_robot(path)
    assert (loaded.robot.half_track, loaded.robot.v_max) == (9.5, 30.0)
    assert loaded.note.startswith(f"{path}: the identified robot")
    # Without the identification's wheel scales, "robot" is an unknown Robot field.
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"robot": {"half_track": 9.5}}))
    with pytest.raises(ValueError, match="robot"):
        read_robot(plain)
    # Robot fields beside the scales but no robot block: read at the top level.
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps({"wheel_scale": 1.0, "half_track": 9.5}))
    with pytest.raises(ValueError, match="wheel_scale"):
        read_robot(flat)


def test_a_tuned_gains_file_given_as_a_robot_is_named_as_one(tmp_path):
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps({"controller": "shim-sung", "kr": 60.0, "robot": {}}))
    with pytest.raises(ValueError) as err:
        read_robot(path)
    assert str(err.value) == (
        f"'{path}' is a tuned gains file (it names a controller), not a robot; allowed: a JSON "
        "object of Robot fields (a tuned file's own robot comes with it as --gains)"
    )


def test_a_json_file_that_is_not_an_object_lists_the_robot_fields(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[8.0, 22.0]")
    with pytest.raises(ValueError) as err:
        read_robot(path)
    assert str(err.value).endswith(f"(keys among {', '.join(ROBOT_FIELDS)})")


def test_plausibility_looks_at_every_number_and_at_positive_finite_ones_only():
    # A value that is not a number does not hide the fields after it.
    assert [f for f, *_ in implausible({"half_track": "8", "v_max": 1e5})] == ["v_max"]
    # Booleans, zero and infinity are refused where the robot is used, not called implausible.
    assert implausible({"half_track": True, "wheel_radius": 0.0, "v_max": float("inf")}) == []
    assert implausible({"half_track": 1000.0}) == [("half_track", 1000.0, (0.5, 500.0, "cm"))]
    # An acceleration in m/s² (2.5 for 250 cm/s²), or cm/s² in a ROS file; 0 is "no limit".
    assert implausible({"accel_max": 2.5}) == [("accel_max", 2.5, (5.0, 1e4, "cm/s^2"))]
    assert implausible({"accel_max": 25000.0}) == [("accel_max", 25000.0, (5.0, 1e4, "cm/s^2"))]
    assert implausible({"accel_max": 0.0}) == implausible({"accel_max": 250.0}) == []


def test_a_unit_warning_points_at_the_line_that_loads_the_robot(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"half_track": 0.08}))
    with pytest.warns(w.RobotUnitsWarning) as caught:
        w.load_robot(path)
    assert [c.filename for c in caught] == [__file__]
