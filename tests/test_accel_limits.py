"""The ideal loop's speed limiter: a robot's acceleration limits on its commands (§4.2.2)."""

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.model import dynamics
from wmr_jax._src.model.robots import ROBOT_UNITS, describe_robot, robot_json, same_robot
from wmr_jax._src.sim import loops, motion

DT = 0.033
STEPS = 150
GAINS = w.Gains(kr=60.0)
# The paper robot made heavy: 100 cm/s² (about 0.1 g) and 20 rad/s². The law
# asks for up to 60 cm/s and 10 rad/s at once; the limiter takes 0.6 s and
# 0.5 s to get there.
HEAVY = w.Robot(accel_max=100.0, angular_accel_max=20.0)


@pytest.fixture(scope="module")
def refs():
    return np.asarray(w.paper_refs())


@pytest.fixture(scope="module")
def limited(refs):
    return jax.tree.map(np.asarray, w.batch_rollout(refs, GAINS, robot=HEAVY, steps=STEPS))


@pytest.fixture(scope="module")
def free(refs):
    return jax.tree.map(np.asarray, w.batch_rollout(refs, GAINS, steps=STEPS))


def _applied(traj):
    """The body speeds the robot followed, from its rim speeds: ``(v, ω)`` per period."""
    left, right = traj.wheel_speeds[..., 0], traj.wheel_speeds[..., 1]
    half_track = float(w.Robot().half_track)
    return 0.5 * (left + right), 0.5 * (right - left) / half_track


def _arrival(traj, refs):
    """Settled arrival times of docs/model.md §6, s (``inf``: not arrived at the end)."""
    tol_r, tol_theta = 1.0, math.radians(5.0)  # the defaults
    poses = traj.poses[:, 1:]
    distance = np.hypot(*(refs[:, None, :2] - poses[..., :2]).transpose(2, 0, 1))
    heading = np.angle(np.exp(1j * (refs[:, None, 2] - poses[..., 2])))
    folded = np.abs(np.angle(np.exp(2j * heading)) / 2)  # backwards counts too
    arrived = (distance <= tol_r) & (folded <= tol_theta)
    # The first sample from which the run stays arrived.
    stays = np.flip(np.cumprod(np.flip(arrived, axis=1), axis=1), axis=1).astype(bool)
    first = np.argmax(stays, axis=1)
    return np.where(stays[:, -1], (first + 1) * DT, np.inf)


def test_the_limited_loop_equals_the_numpy_reference(refs, limited):
    worst = 0.0
    for i, ref in enumerate(refs):
        expected = w.reference_rollout(ref, GAINS, robot=HEAVY, steps=STEPS)
        np.testing.assert_array_equal(limited.region[i], expected["region"])
        for field in ("v", "omega", "wheel_speeds", "distance"):
            np.testing.assert_allclose(
                getattr(limited, field)[i], expected[field], rtol=0, atol=1e-11
            )
        worst = max(worst, float(np.abs(limited.poses[i] - expected["poses"]).max()))
    # Float64 to ~1e-13 cm: the same limiter computed in another order (the
    # reference clamps the change, the loop clamps the command).
    assert worst < 1e-12


def test_the_applied_commands_change_by_at_most_the_limits_from_rest(limited):
    v, omega = _applied(limited)
    dv = np.diff(np.concatenate([np.zeros((len(v), 1)), v], axis=1), axis=1)
    domega = np.diff(np.concatenate([np.zeros((len(omega), 1)), omega], axis=1), axis=1)
    assert np.abs(dv).max() <= HEAVY.accel_max * DT * (1 + 1e-9)
    assert np.abs(domega).max() <= HEAVY.angular_accel_max * DT * (1 + 1e-9)
    # The limiter binds (the law's own command jumps by more) and lets go again.
    assert np.mean(np.abs(v - limited.v) > 1e-9) > 0.1
    assert np.any(np.abs(v - limited.v) < 1e-12)
    # Trajectory.v is the law's command; the distance is the robot's own.
    np.testing.assert_allclose(limited.distance, np.abs(v) * DT, rtol=1e-12, atol=1e-12)


def test_a_small_acceleration_limit_makes_arrival_later(refs, limited, free):
    late, early = _arrival(limited, refs), _arrival(free, refs)
    np.testing.assert_allclose(early, [1.65, 1.782, 1.254, 1.188, 1.782, 1.815, 1.914])
    assert np.all(np.isfinite(early)) and np.all(np.isfinite(late))
    assert np.all(late > early), (late, early)
    assert np.mean(late - early) > 0.5  # s: the ramps cost more than a few periods


def test_without_limits_the_loop_has_no_limiter_and_the_same_results(refs, free):
    # The paper robot (and any robot without limits) runs the program of old:
    # the limiter is left out before tracing, not clipped at infinity.
    for robot in (w.Robot(), w.ROBOTS["pioneer-3dx"]):
        assert loops.for_robot(loops.Options(), robot, DT) == loops.Options()
    assert loops.for_robot(loops.Options(), HEAVY, DT).accel_limit
    assert loops.for_robot(loops.Options(), HEAVY.replace(accel_max=0.0), DT).accel_limit
    # Non-ideal loop: the torque limits the robot; no speed limiter there.
    assert not loops.for_robot(loops.Options(velocity="nonideal"), HEAVY, DT).accel_limit
    # With the limiter on and limits that never bind, the results are bit for
    # bit those of the loop without it (the same compiled program as above).
    never = HEAVY.replace(accel_max=1e30, angular_accel_max=1e30)
    unbound = jax.tree.map(np.asarray, w.batch_rollout(refs, GAINS, robot=never, steps=STEPS))
    for field in free._fields:
        np.testing.assert_array_equal(getattr(unbound, field), getattr(free, field))


def test_the_limiter_is_differentiable_in_the_command_and_the_limit():
    def step(a, v):
        robot = HEAVY.replace(accel_max=a)
        held = motion.HeldCommand(jnp.asarray(10.0), jnp.asarray(0.0))
        return motion.speed_limit(held, v, jnp.asarray(1.0), robot, DT)[0]

    grad = jax.jit(jax.grad(step, argnums=(0, 1)))
    # Binding: v = 10 + a dt, whatever the command.
    assert step(100.0, 50.0) == pytest.approx(10.0 + 100.0 * DT)
    np.testing.assert_allclose(grad(100.0, 50.0), (DT, 0.0))
    # Not binding: the command itself.
    np.testing.assert_allclose(grad(100.0, 11.0), (0.0, 1.0))
    # No limit (0): the command, bit for bit, and finite gradients.
    assert dynamics.rate_limit(jnp.asarray(0.1), 7.0, 0.0, DT) == 0.1
    np.testing.assert_allclose(grad(0.0, 50.0), (0.0, 1.0))


def test_a_ros_yaml_gives_the_limits_and_says_they_apply(tmp_path):
    path = tmp_path / "bot.yaml"
    path.write_text(
        "wheel_separation: 0.3\nwheel_radius: 0.05\n"
        "linear: {x: {max_velocity: 0.5, max_acceleration: 0.8, min_acceleration: -0.4}}\n"
        "angular: {z: {max_acceleration: 2.0, max_jerk: 9.0}}\n"
    )
    read = w.dynamics.read_robot(str(path))
    assert read.robot.accel_max == pytest.approx(80.0) and read.robot.angular_accel_max == 2.0
    assert read.accelerations == {
        "linear.x.max_acceleration": pytest.approx(80.0),
        "angular.z.max_acceleration": 2.0,
    }
    note = read.note
    assert "linear.x.max_acceleration, angular.z.max_acceleration -> " in note
    assert "accel_max 80 cm/s^2, angular_accel_max 2 rad/s^2" in note
    assert "the ideal loop's speed limiter applies these acceleration limits" in note
    # Asymmetric and jerk limits are not modelled: named as ignored.
    assert "ignored: linear.x.min_acceleration, angular.z.max_jerk" in note
    assert "accel_max" not in note.split("values kept: ")[1]
    # Switched off as ROS 1 does: not applied.
    path.write_text(
        "wheel_separation: 0.3\nwheel_radius: 0.05\n"
        "linear: {x: {has_acceleration_limits: false, max_acceleration: 0.8}}\n"
    )
    read = w.dynamics.read_robot(str(path))
    assert read.robot.accel_max == 0.0 and not read.accelerations
    assert "speed limiter" not in read.note
    assert "linear.x.max_acceleration" in read.note.split("ignored: ")[1]


def test_the_limits_are_robot_fields_everywhere(tmp_path):
    burger, paper = w.ROBOTS["turtlebot3-burger"], w.Robot()
    assert (burger.accel_max, burger.angular_accel_max) == (250.0, 3.2)
    assert (paper.accel_max, paper.angular_accel_max) == (0.0, 0.0)
    assert describe_robot(burger).endswith(
        "accel_max = 250 cm/s^2, angular_accel_max = 3.2 rad/s^2)"
    )
    assert "accel" not in describe_robot(paper)
    assert not same_robot(burger, burger.replace(accel_max=0.0))
    assert robot_json(burger)["angular_accel_max"] == 3.2
    assert ROBOT_UNITS["accel_max"].startswith("cm/s^2")
    # A JSON file gives them; 0 is no limit, a negative limit is refused.
    path = tmp_path / "bot.json"
    path.write_text(json.dumps({"accel_max": 120, "angular_accel_max": 0}))
    assert w.load_robot(str(path)) == paper.replace(accel_max=120.0)
    path.write_text(json.dumps({"angular_accel_max": -1}))
    with pytest.raises(ValueError, match="angular_accel_max = -1 is not allowed; allowed: a nu"):
        w.load_robot(str(path))
    with pytest.raises(ValueError, match="robot.accel_max = -5.0 is not allowed"):
        w.rollout([30.0, 0.0, 0.0], robot=paper.replace(accel_max=-5.0), steps=2)
    # tuned_gains.json records them and reads them back; a file written before
    # the limits existed reads as a robot without them.
    saved = tmp_path / "tuned_gains.json"
    saved.write_text(json.dumps(tuning.tuned_json(w.Gains(kr=9.0), robot=burger)))
    assert same_robot(w.load_tuned(saved).robot, burger)
    values = tuning.tuned_json(w.Gains(kr=9.0), robot=burger)
    for name in ("accel_max", "angular_accel_max"):
        del values["robot"][name], values["robot_units"][name]
    saved.write_text(json.dumps(values))
    assert w.load_tuned(saved).robot == burger.replace(accel_max=0.0, angular_accel_max=0.0)


def test_the_robot_fields_are_in_order():
    # New fields come last: a Robot built by position keeps its meaning.
    names = [f.name for f in dataclasses.fields(w.Robot)]
    assert names[-2:] == ["accel_max", "angular_accel_max"]
    assert math.isclose(w.Robot().half_track, 1.85)
