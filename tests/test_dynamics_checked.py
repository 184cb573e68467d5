"""``wmr_jax.dynamics`` called by hand: values are checked, traces pass through."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import dynamics

ROBOT = w.Robot()
STATE = dynamics.initial_state([0.0, 0.0, 0.0])
COMMAND = np.array([10.0, 1.0])


@pytest.mark.parametrize("angle", [3e9, 1e7, -2.5e5, 1e20])
def test_sin_cos_of_a_huge_angle_is_its_sine_and_cosine(angle):
    # The fast polynomials alone gave cos(3e9) as 9.7e11 in float32.
    for dtype in (np.float32, np.float64):
        with jax.enable_x64(dtype == np.float64):
            cos, sin = dynamics.sin_cos(dtype(angle))
            exact = (math.cos(float(dtype(angle))), math.sin(float(dtype(angle))))
            np.testing.assert_allclose([float(cos), float(sin)], exact, atol=1e-6)
    np.testing.assert_allclose(float(dynamics.sinc(1e10)), math.sin(1e10) / 1e10, atol=1e-15)


def test_arc_step_reduces_a_huge_heading_instead_of_moving_far():
    got = np.asarray(dynamics.arc_step(np.array([0.0, 0.0, 5e9]), 10.0, 0.0, 1.0))
    theta = math.remainder(5e9, 2 * math.pi)
    # 5e9 rad itself is known only to half its ulp, 5e-7 rad: 5e-6 cm at 10 cm.
    np.testing.assert_allclose(got[:2], [10 * math.cos(theta), 10 * math.sin(theta)], atol=1e-5)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: dynamics.arc_step(np.zeros(2), 10.0, 1.0, 0.1), r"pose has shape \(2,\)"),
        (lambda: dynamics.arc_step(np.zeros(3), 10.0, 1.0, -0.1), r"h = -0.1 .*>= 0 s"),
        (lambda: dynamics.arc_step(np.zeros(3), 1j, 1.0, 0.1), r"v = 1j is not allowed"),
        (lambda: dynamics.arc_step(np.zeros(3), 10.0, 1e9, 1.0), r"omega \* h = .*at most"),
        (
            lambda: dynamics.arc_step(np.zeros((4, 3)), np.ones(3), 1.0, 0.1),
            r"do not broadcast: pose\[\.\.\., 0\] \(4,\), v \(3,\)",
        ),
        (lambda: dynamics.sin_cos("a"), r"angle = 'a' is not allowed"),
        (lambda: dynamics.initial_state(np.zeros(5)), r"init has shape \(5,\)"),
        (lambda: dynamics.initial_state([0, 0, True]), r"init = \[0, 0, True\]"),
        (lambda: dynamics.limit_wheels(np.array([200.0, 5.0]), ROBOT, mode="clipp"), "'clipp'"),
        (lambda: dynamics.limit_wheels(np.array([1.0]), ROBOT), r"velocity has shape \(1,\)"),
        (lambda: dynamics.kinetic_energy(np.array([1.0]), ROBOT), r"velocity has shape"),
        # A batched robot must match the batch it moves, and half floats are not computed in.
        (
            lambda: dynamics.kinetic_energy(np.zeros((4, 2)), ROBOT.replace(v_max=[1.0, 2.0, 3.0])),
            r"velocity\[\.\.\., 0\] \(4,\), robot.v_max \(3,\)",
        ),
        (
            lambda: dynamics.limit_wheels(np.zeros((4, 2)), ROBOT.replace(v_max=[1.0, 2.0, 3.0])),
            r"do not broadcast",
        ),
        (
            lambda: dynamics.arc_step(np.zeros(3, np.float16), 1.0, 0.0, 1.0),
            r"pose is an array of float16; allowed: float32 or float64",
        ),
        (lambda: dynamics.inertia(ROBOT.replace(body_mass=-10.0)), r"robot\.body_mass = -10"),
        (
            lambda: dynamics.body_acceleration(np.zeros(2), np.ones(1), ROBOT),
            r"torques has shape \(1,\)",
        ),
        (
            lambda: dynamics.wheel_torques(
                np.zeros(2), np.ones(2), np.zeros(2), ROBOT.replace(torque_max=-5.0)
            ),
            r"torque_max = -5",
        ),
        (lambda: dynamics.advance(STATE, np.array([1.0]), ROBOT, 0.033), r"command has shape"),
        # Speeds whose squares (kinetic energy) or moves leave the dtype's range.
        (
            lambda: dynamics.advance(STATE, np.array([1e200, 0.0]), ROBOT, 0.033),
            r"command = .*1e\+200.*speeds of magnitude <= 1e\+153",
        ),
        (
            lambda: dynamics.advance(
                STATE._replace(velocity=np.array([0.0, -1e200])), COMMAND, ROBOT, 0.033
            ),
            r"state.velocity = .*-1e\+200",
        ),
        (lambda: dynamics.arc_step(np.zeros(3), 1e150, 0.0, 1e4), r"v \* h = 1e\+154"),
        (lambda: dynamics.advance(STATE, COMMAND, ROBOT, -0.033), r"dt = -0.033"),
        (lambda: dynamics.advance(STATE, COMMAND, ROBOT, 0.033, substeps=-1), r"substeps = -1"),
        (lambda: dynamics.advance(STATE, COMMAND, ROBOT, 0.033, substeps=2.5), r"substeps = 2.5"),
        (lambda: dynamics.advance(STATE, COMMAND, ROBOT, 10.0), r"substeps >= 400"),
        (
            lambda: dynamics.advance(STATE, COMMAND, ROBOT, 0.033, wheel_limit="bogus"),
            r"wheel_limit = 'bogus' is not allowed",
        ),
        (
            lambda: dynamics.advance(STATE, COMMAND, ROBOT.replace(v_max=[100.0, 125.0]), 0.033),
            r"robot\.v_max has shape \(2,\); allowed: one robot",
        ),
        (lambda: dynamics.advance((0, 0, 0), COMMAND, ROBOT, 0.033), r"state = .*RobotState"),
        (
            lambda: dynamics.check_stability(ROBOT.replace(integral_gain=-1e9), 0.033, 1),
            r"robot\.integral_gain = -1000000000\.0",
        ),
        (lambda: dynamics.check_stability(ROBOT, math.nan, 1), r"dt = nan"),
        (lambda: dynamics.check_stability(ROBOT, 0.033, 0), r"substeps = 0"),
        (
            lambda: dynamics.check_stability(ROBOT.replace(speed_gain=1e300), 0.033, 10),
            r"a smaller speed_gain",
        ),
    ],
)
def test_bad_values_are_named_before_any_work(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_traced_arguments_pass_through_unchecked():
    # Inside jit and grad the functions run as the rollouts use them.
    cos = jax.jit(lambda a: dynamics.sin_cos(a)[0])(1.0)
    np.testing.assert_allclose(float(cos), math.cos(1.0), atol=1e-15)
    slope = jax.grad(lambda omega: dynamics.arc_step(jnp.zeros(3), 10.0, omega, 0.1)[2])(1.0)
    np.testing.assert_allclose(float(slope), 0.1)

    def step(command):
        state, _ = dynamics.advance(STATE, command, ROBOT, 0.033)
        return state.pose[0]

    by_hand = step(jnp.asarray(COMMAND))
    np.testing.assert_allclose(float(jax.jit(step)(jnp.asarray(COMMAND))), float(by_hand))


def test_numpy_baseline_checks_as_final_poses_does():
    refs = np.array([[30.0, 30.0, 0.0]])
    for kwargs, message in (
        ({"dt": -0.033}, r"dt = -0.033"),
        ({"steps": 0}, r"steps = 0"),
        ({"gains": w.Gains(kr=-60.0)}, r"gains\.kr = -60"),
        ({"init": (0.0, 0.0)}, r"init has shape \(2,\)"),
    ):
        with pytest.raises(ValueError, match=message):
            w.studies.numpy_final_poses(refs, **kwargs)
    with pytest.raises(ValueError, match=r"refs has shape \(1, 4\)"):
        w.studies.numpy_final_poses(np.zeros((1, 4)))
    with pytest.raises(ValueError, match=r"refs = \[\[30.0, 30.0, 0.0\], \[1.0\]\] is not"):
        w.studies.numpy_final_poses([[30.0, 30.0, 0.0], [1.0]])  # NumPy's own error before


def test_checked_functions_keep_the_callers_float_dtype_and_empty_batches():
    # float32 stays float32 with float64 enabled; float16 keeps its dtype.
    cos, _ = dynamics.sin_cos(np.float32(0.5))
    assert cos.dtype == np.float32
    assert dynamics.sin_cos(np.float16(0.5))[0].dtype == np.float16
    assert dynamics.arc_step(np.zeros(3, np.float32), 10.0, 1.0, 0.1).dtype == np.float32
    assert dynamics.arc_step(np.zeros((0, 3)), 10.0, 1.0, 0.1).shape == (0, 3)


def test_concrete_arguments_are_checked_beside_traced_ones():
    # A traced mass does not hide a wheel loop that is too stiff for the period.
    def stiff(mass):
        robot = ROBOT.replace(speed_gain=1e6, body_mass=mass)
        dynamics.check_stability(robot, 0.033, 1)
        return mass

    with pytest.raises(ValueError, match=r"substeps = 1 is not allowed"):
        jax.grad(stiff)(1.0)
    # Mapping over poses with concrete, bad gains still names the gains.
    bad = w.AstolfiGains(k_rho=-3.0)
    with pytest.raises(ValueError, match=r"gains\.k_rho = -3"):
        jax.vmap(lambda q: w.controllers.astolfi_control(q, [30.0, 30.0, 0.0], bad))(
            jnp.zeros((4, 3))
        )
    with pytest.raises(ValueError, match=r"dt = -0.033"):
        jax.jit(lambda s: dynamics.advance(s, COMMAND, ROBOT, -0.033))(STATE)
