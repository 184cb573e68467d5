"""Robots as data: presets, JSON and ROS YAML files, and the robot that travels with tuned gains."""

import json
import re

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.model.robots import ROBOT_UNITS, robot_json, same_robot
from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
from wmr_jax.cli import main

TB3 = "turtlebot3-burger"
# A TurtleBot3-like diff_drive_controller, nested as ros2_controllers reads it.
TB3_YAML = """\
/**:
  diff_drive_controller:
    ros__parameters:
      left_wheel_names: ["wheel_left_joint"]
      right_wheel_names: ["wheel_right_joint"]
      wheel_separation: 0.160
      wheel_radius: 0.033
      odom_frame_id: odom
      linear:
        x:
          max_velocity: 0.22
          max_acceleration: 2.5
      angular:
        z:
          max_velocity: 2.84
"""
STEPS = "400"  # one compiled rollout for every simulate below


def _file(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _peak(out: str) -> float:
    return float(re.search(r"peak wheel speed ([0-9.]+) cm/s", out).group(1))


def test_presets_load_and_validate():
    assert list(w.ROBOTS) == ["paper", TB3, "pioneer-3dx"]
    assert w.dynamics.robot_preset("paper") == w.Robot() and w.load_robot("paper") == w.Robot()
    for name, robot in w.ROBOTS.items():
        assert w.load_robot(name) is robot and w.dynamics.robot_preset(name) is robot
        assert robot_json(robot) == {k: float(v) for k, v in vars(robot).items()}
        w.rollout([20.0, 10.0, 0.0], paper_feasible_gains(robot), robot=robot, steps=3)
    burger, pioneer = w.ROBOTS[TB3], w.ROBOTS["pioneer-3dx"]
    # The published numbers, in cm, kg, s: 160 mm apart, 33 mm wheels, 0.22 m/s, 1 kg.
    assert (burger.half_track, burger.wheel_radius) == (8.0, 3.3)
    assert burger.v_max >= 22.0
    assert burger.body_mass + 2 * burger.wheel_mass == pytest.approx(1.0, rel=1e-12)
    assert (pioneer.wheel_radius, pioneer.v_max) == (9.75, 120.0)
    assert pioneer.body_mass + 2 * pioneer.wheel_mass == 9.0
    with pytest.raises(ValueError, match="preset 'burger' is not known; allowed: paper, "):
        w.dynamics.robot_preset("burger")


def test_a_robot_given_by_name_or_path_in_python_points_to_load_robot(tmp_path):
    """The commands' --robot takes a name or file; in Python the refusal says how to read one."""
    path = tmp_path / "robot.json"
    path.write_text('{"half_track": 8.0, "v_max": 22.0}')
    for given in ("turtlebot3-burger", path):
        expected = re.escape(f"wmr_jax.load_robot({str(given)!r}) reads that preset or file")
        with pytest.raises(
            ValueError, match=rf"^robot = .* is not allowed; allowed: a Robot \({expected}\)$"
        ):
            w.final_poses([[30.0, 0.0, 0.0]], robot=given)
        with pytest.raises(ValueError, match=expected):
            tuning.ScheduleParams.from_gains(w.Gains(), robot=given)
        assert w.load_robot(given).v_max in (w.ROBOTS["turtlebot3-burger"].v_max, 22.0)


def test_a_json_subset_keeps_the_other_defaults(tmp_path):
    path = _file(tmp_path, "bot.json", '{"v_max": 40, "half_track": 10.5}')
    robot = w.load_robot(path)
    assert robot == w.Robot().replace(v_max=40.0, half_track=10.5)
    assert isinstance(robot.v_max, float)  # JSON's integer read as a float


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("bot.json", '{"v_mx": 40}', "key 'v_mx' (= 40) is not allowed; allowed: keys among"),
        ("bot.json", '{"v_max": "40"}', "v_max = '40' is not allowed; allowed: a finite number"),
        ("bot.json", '{"v_max": true}', "v_max = True is not allowed; allowed: a finite number"),
        ("bot.json", '{"wheel_mass": -0.1}', "wheel_mass = -0.1 is not allowed; allowed: a num"),
        ("bot.json", '{"com_offset": 9}', "robot.com_offset = 9.0 is not allowed; allowed: |"),
        ("bot.json", "[40]", "is not allowed; allowed: a JSON object of Robot fields"),
        ("bot.json", '{"v_max": 1, "v_max": 2}', "the key 'v_max' is given twice"),
        ("bot.json", "{", "cannot be read"),
        ("bot.yaml", "- 0.16\n", "is not allowed; allowed: a YAML mapping"),
        ("bot.yaml", "wheel_separation: -0.16\n", "wheel_separation = -0.16 is not allowed; al"),
        ("bot.yaml", "wheel_radius: '0.03'\n", "wheel_radius = '0.03' is not allowed; allowed"),
        ("bot.yaml", "odom_frame_id: odom\n", "holds no diff_drive_controller parameters"),
        ("bot.yaml", "a:\n  wheel_radius: 0.1\nb:\n  wheel_radius: 0.2\n", "holds 2 sets"),
        ("bot.yaml", "wheel_radius: 0.1\nwheel_radius: 0.2\n", "'wheel_radius' is given twice"),
        ("bot.txt", "{}", "allowed: a preset (paper, turtlebot3-burger, pioneer-3dx), or a file"),
    ],
)
def test_bad_robot_files_are_refused_by_name(tmp_path, name, content, message):
    path = _file(tmp_path, name, content)
    with pytest.raises(ValueError) as err:
        w.load_robot(path)
    text = str(err.value)
    assert text.startswith(repr(path)) and message in text and "\n" not in text, text


def test_a_missing_robot_file_is_named_on_the_command_line(tmp_path, capsys):
    missing = str(tmp_path / "gone.json")
    assert main(["simulate", "--ref", "30", "20", "45", "--robot", missing]) == 2
    err = capsys.readouterr().err
    assert err == f"wmr-jax: error: --robot {missing!r} cannot be read: there is no such file\n"


def test_a_ros_yaml_converts_metres_to_centimetres(tmp_path, capsys):
    read = w.dynamics.read_robot(_file(tmp_path, "tb3.yaml", TB3_YAML))
    half_track = 0.160 * 100 / 2  # cm: half the separation
    v_max = max(0.22 * 100, 2.84 * half_track)  # cm/s: the rim reaches either limit
    assert read.robot.half_track == pytest.approx(half_track, rel=1e-12) == 8.0
    assert read.robot.wheel_radius == pytest.approx(0.033 * 100, rel=1e-12)
    assert read.robot.v_max == pytest.approx(v_max, rel=1e-12) == pytest.approx(22.72)
    assert read.robot.body_mass == w.Robot().body_mass  # not in the file: the paper's
    assert read.accelerations == {"linear.x.max_acceleration": pytest.approx(250.0)}
    note = read.note
    assert "used wheel_separation, wheel_radius, linear.x.max_velocity, angular.z.max" in note
    assert "accel_max 250 cm/s^2; the ideal loop's speed limiter applies these acceleration" in note
    assert "ignored: left_wheel_names, right_wheel_names, odom_frame_id" in note
    # Flat, with a limit switched off (ROS 1's has_velocity_limits): that limit is unused.
    flat = "wheel_separation: 0.5\nwheel_radius: 0.1\nlinear:\n  x:\n    has_velocity_limits: "
    flat += "false\n    max_velocity: 9.0\nangular.z.max_velocity: 4.0\n"
    read = w.dynamics.read_robot(_file(tmp_path, "flat.yml", flat))
    assert read.robot.half_track == 25.0 and read.robot.v_max == pytest.approx(4.0 * 25.0)
    assert "linear.x.max_velocity" in read.note.split("ignored: ")[1]
    # The command prints the note as one line before the run.
    argv = ["simulate", "--ref", "30", "20", "45", "--robot", str(tmp_path / "tb3.yaml")]
    assert main([*argv, "--steps", STEPS, "--kr", "5", "--k-theta", "1"]) == 0
    assert [line for line in capsys.readouterr().out.splitlines() if "ignored:" in line]


def test_simulate_on_a_turtlebot_keeps_its_wheels_within_its_v_max(capsys):
    robot = w.ROBOTS[TB3]
    gains = paper_feasible_gains(robot)
    argv = ["simulate", "--ref", "30", "20", "45", "--robot", TB3, "--steps", STEPS]
    assert main([*argv, "--kr", str(gains.kr), "--k-theta", str(gains.k_theta)]) == 0
    out = capsys.readouterr().out
    assert "robot          : turtlebot3-burger (L = 8 cm, V_max = 22.72 cm/s" in out
    assert 0.0 < _peak(out) <= robot.v_max and "arrival time   : never" not in out
    # The paper's Fig. 7 gains ask this robot's wheels for far more: said, and seen.
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "exceeds v_max = 22.72 cm/s" in captured.err
    assert _peak(captured.out) > 2 * robot.v_max


def test_paper_feasible_gains_fit_a_slow_robot():
    assert paper_feasible_gains() is tuning.PAPER_FEASIBLE_GAINS  # the paper robot: as they were
    slow = w.Robot(v_max=20.0, half_track=8.0)
    gains = paper_feasible_gains(slow)
    assert gains.kr + slow.half_track * gains.k_theta <= slow.v_max
    assert gains.kr + slow.half_track * gains.k_theta == pytest.approx(slow.v_max, rel=1e-12)
    assert gains.kr / gains.k_theta == pytest.approx(6.0)  # the paper's shape, 60 : 10
    assert np.all(w.controllers.check_feasible(gains, slow))
    with pytest.raises(ValueError, match="robot.v_max = -1.0 is not allowed"):
        paper_feasible_gains(w.Robot(v_max=-1.0))


def test_tune_writes_the_robot_and_load_tuned_returns_it(tmp_path, capsys):
    robot = w.ROBOTS[TB3]
    argv = ["tune", "--out", str(tmp_path), "--robot", TB3, "--no-random-search"]
    # In float32, as a command line session computes: the file keeps the robot unrounded.
    with jax.enable_x64(False):
        assert main([*argv, "--iters", "2", "--poses", "2", "--eval-poses", "4"]) == 0
    assert "for the robot turtlebot3-burger (L = 8 cm" in capsys.readouterr().out
    saved = json.loads((tmp_path / "tuned_gains.json").read_text())
    assert saved["robot"] == robot_json(robot) and saved["robot_units"] == ROBOT_UNITS
    loop = w.load_tuned(tmp_path / "tuned_gains.json")
    assert loop.robot == robot and np.all(w.controllers.check_feasible(loop.params, robot))
    report = json.loads((tmp_path / "evaluation.json").read_text())
    # Every row, the paper's baseline included, within this robot's wheels, row by row.
    assert all(row["peak_wheel_speed_ok"] for row in report["rows"].values())
    assert report["rows"]["paper_feasible"]["peak_wheel_speed"] <= robot.v_max * (1 + 1e-6)
    assert report["robot"] == robot_json(robot)


def test_a_tuned_file_runs_on_its_robot_and_refuses_another(tmp_path, capsys):
    robot = w.ROBOTS[TB3]
    gains = paper_feasible_gains(robot)
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps(tuning.tuned_json(gains, robot=robot)))
    argv = ["simulate", "--ref", "30", "20", "45", "--gains", str(path), "--steps", STEPS]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "robot          : turtlebot3-burger" in out and _peak(out) <= robot.v_max
    assert main([*argv, "--robot", TB3]) == 0  # the same robot, named: fine
    capsys.readouterr()
    assert main([*argv, "--robot", "pioneer-3dx"]) == 2
    err = capsys.readouterr().err
    # One short line: the file's robot by name and what is allowed, no robots spelled out.
    assert err == (
        f"wmr-jax: error: --robot 'pioneer-3dx' is not allowed with --gains {str(path)!r}, "
        "tuned for turtlebot3-burger (gains fit one robot's wheel budget); allowed: that robot, "
        "or no --robot\n"
    )
    # evaluate judges the file on the robot it records, within that robot's wheels.
    refs = _file(tmp_path, "refs.csv", "30,20,0.5\n")
    judge = ["evaluate", "--gains", str(path), "--refs", refs, "--horizon", "10", "--float32"]
    assert main(judge) == 0
    out = capsys.readouterr().out
    assert "| robot " in out and "turtlebot3-burger (L = 8 cm, V_max = 22.72 cm/s" in out
    assert "| V_max " in out and "22.72 cm/s, every wheel command within it" in out
    # Another robot than the file's is refused there too, in one line.
    assert main([*judge, "--robot", "pioneer-3dx"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"wmr-jax: error: --robot 'pioneer-3dx' is not allowed with --gains {str(path)!r}, "
    )
    assert err.count("\n") == 1


def test_load_tuned_reads_the_robot_back_and_checks_it(tmp_path):
    path = tmp_path / "tuned_gains.json"
    pioneer = w.ROBOTS["pioneer-3dx"]
    path.write_text(json.dumps(tuning.tuned_json(w.Gains(kr=30.0), robot=pioneer)))
    assert same_robot(w.load_tuned(path).robot, pioneer)
    # A robot in metres inside the file is flagged as a --robot file's would be, and runs.
    metres = w.Robot(half_track=0.08, v_max=0.22)
    in_metres = tuning.tuned_json(w.Gains(kr=0.1, k_theta=1.0), robot=metres)
    path.write_text(json.dumps(in_metres))
    with pytest.warns(w.RobotUnitsWarning) as caught:
        assert w.load_tuned(path).robot.half_track == 0.08
    assert [str(c.message).split(" is outside")[0] for c in caught] == [
        f"{str(path)!r}: robot: half_track = 0.08 cm",
        f"{str(path)!r}: robot: v_max = 0.22 cm/s",
    ]
    path.write_text(json.dumps(tuning.tuned_json(w.Gains(kr=30.0))))  # as before robots
    assert w.load_tuned(path).robot is None
    values = tuning.tuned_json(w.Gains(kr=30.0), robot=pioneer)
    for change, message in (
        ({"robot": {**values["robot"], "mass": 3}}, "robot: key 'mass' (= 3) is not allowed"),
        ({"robot": {"v_max": -1}}, "robot: v_max = -1 is not allowed; allowed: a number > 0"),
        ({"robot_units": {"v_max": "m/s"}}, "robot_units['v_max'] = 'm/s' is not allowed"),
    ):
        path.write_text(json.dumps({**values, **change}))
        with pytest.raises(ValueError, match=re.escape(message)):
            w.load_tuned(path)
    # A schedule caps its commands with its robot's V_max and L: they must agree
    # (to float32 rounding: a schedule tuned in float32 carries its robot's V_max so).
    with pytest.raises(ValueError, match="the schedule's v_max = 125.0 is not allowed with"):
        tuning.tuned_json(tuning.ScheduleParams(), robot=pioneer)
    burger = w.ROBOTS[TB3]
    rounded = tuning.ScheduleParams(v_max=float(np.float32(burger.v_max)), half_track=8.0)
    path.write_text(json.dumps(tuning.tuned_json(rounded, robot=burger)))
    assert w.load_tuned(path).robot == burger


def test_a_ros_yaml_nan_is_no_limit_but_no_size(tmp_path):
    """ros2_controllers reads a .nan limit as none; a .nan wheel size is no robot."""
    text = "wheel_separation: 0.4\nwheel_radius: 0.1\nlinear.x.max_velocity: .nan\n"
    read = w.dynamics.read_robot(_file(tmp_path, "nan_limit.yaml", text))
    assert read.robot.v_max == w.Robot().v_max and read.robot.half_track == 20.0
    for key, size in (("wheel_separation", "0.4"), ("wheel_radius", "0.1")):
        bad = text.replace(f"{key}: {size}", f"{key}: .nan")
        with pytest.raises(ValueError, match=f"{key} = nan is not allowed; allowed: a finite"):
            w.dynamics.read_robot(_file(tmp_path, f"nan_{key}.yaml", bad))


def test_a_ros_yaml_value_given_as_a_mapping_is_refused(tmp_path):
    """A limit written one level too deep was flattened under its name and ignored."""
    text = "wheel_separation: 0.4\nwheel_radius: 0.1\nlinear:\n  x:\n    max_velocity:\n"
    text += "      value: 0.5\n"
    with pytest.raises(ValueError, match="linear.x.max_velocity is a mapping; allowed: a number"):
        w.dynamics.read_robot(_file(tmp_path, "deep.yaml", text))
