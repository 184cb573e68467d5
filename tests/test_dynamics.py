"""Exact arc integration (docs/model.md §4)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import dynamics


@pytest.mark.parametrize("omega", [0.0, 1e-12, 1e-6, 1e-3, 0.5, -3.0, 40.0])
def test_arc_step_matches_closed_form(omega):
    pose = jnp.array([1.0, -2.0, 0.7])
    v, h = 35.0, 0.033
    got = np.asarray(dynamics.arc_step(pose, v, omega, h))
    if abs(omega * h) > 1e-4:
        th1 = 0.7 + omega * h
        expected = [
            1.0 + v / omega * (math.sin(th1) - math.sin(0.7)),
            -2.0 - v / omega * (math.cos(th1) - math.cos(0.7)),
            th1,
        ]
        tol = 1e-12  # the closed form cancels by ~1/(ω h) ulps
    else:
        expected = [1.0 + v * h * math.cos(0.7), -2.0 + v * h * math.sin(0.7), 0.7 + omega * h]
        tol = abs(v * h * omega * h) + 1e-14  # straight line: error O(v h · ω h)
    np.testing.assert_allclose(got, expected, rtol=0, atol=tol)


def test_arc_step_composes():
    """Two half steps at constant (v, ω) equal one full step: the integration is exact."""
    pose = jnp.array([0.0, 0.0, 0.2])
    one = dynamics.arc_step(pose, 50.0, 7.0, 0.033)
    two = dynamics.arc_step(dynamics.arc_step(pose, 50.0, 7.0, 0.0165), 50.0, 7.0, 0.0165)
    np.testing.assert_allclose(np.asarray(one), np.asarray(two), atol=1e-13)


@pytest.mark.parametrize("u", [0.0, 1e-9, 0.9e-3, 1.1e-3, 0.3, 2.0])
def test_sinc_value_and_gradient(u):
    value = float(dynamics.sinc(jnp.float64(u)))
    expected = 1.0 if u == 0 else math.sin(u) / u
    assert value == pytest.approx(expected, rel=1e-15, abs=1e-16)
    grad = float(jax.grad(dynamics.sinc)(jnp.float64(u)))
    exact = 0.0 if u == 0 else (u * math.cos(u) - math.sin(u)) / u**2
    # Near 0 the closed form of the derivative itself cancels; compare loosely there.
    assert grad == pytest.approx(exact, rel=1e-6, abs=1e-9)
    assert math.isfinite(grad)


def test_arc_step_gradient_matches_central_differences():
    pose = jnp.array([0.5, 0.2, -0.4])

    def f(params):
        v, omega, h = params
        return jnp.sum(dynamics.arc_step(pose, v, omega, h) * jnp.array([1.0, 2.0, 3.0]))

    for omega in (0.0, 1e-7, 2.5):
        params = jnp.array([40.0, omega, 0.033])
        grad = np.asarray(jax.grad(f)(params))
        step = 1e-6
        fd = [
            (float(f(params.at[i].add(step))) - float(f(params.at[i].add(-step)))) / (2 * step)
            for i in range(3)
        ]
        np.testing.assert_allclose(grad, fd, rtol=1e-7, atol=1e-7)


def test_the_primitives_are_the_same_called_with_values_and_traced():
    """``wmr_jax.dynamics`` is pure: jit and grad run the very function called by hand."""
    robot, command = w.Robot(), jnp.array([10.0, 1.0])
    cos = jax.jit(lambda a: dynamics.sin_cos(a)[0])(1.0)
    np.testing.assert_allclose(float(cos), math.cos(1.0), atol=1e-15)
    slope = jax.grad(lambda omega: dynamics.arc_step(jnp.zeros(3), 10.0, omega, 0.1)[2])(1.0)
    np.testing.assert_allclose(float(slope), 0.1)

    def step(command):
        state, _ = dynamics.advance(dynamics.initial_state([0.0, 0.0, 0.0]), command, robot, 0.033)
        return state.pose[0]

    np.testing.assert_array_equal(float(jax.jit(step)(command)), float(step(command)))
    # The robot moved forwards about v · dt (the wheel loop lags the command a little).
    assert 0.2 < float(step(command)) < 10.0 * 0.033


def test_the_primitives_keep_the_callers_float_dtype_and_empty_batches():
    cos, _ = dynamics.sin_cos(np.float32(0.5))
    assert cos.dtype == np.float32
    assert dynamics.sin_cos(np.float16(0.5))[0].dtype == np.float16
    assert dynamics.arc_step(np.zeros(3, np.float32), 10.0, 1.0, 0.1).dtype == np.float32
    assert dynamics.arc_step(np.zeros((0, 3)), 10.0, 1.0, 0.1).shape == (0, 3)
    assert dynamics.initial_state([0, 0, 0]).pose.dtype == w.studies.float_dtype()


def test_check_stability_names_the_substeps_a_stiff_wheel_loop_needs():
    robot = w.Robot()  # k_p = 100 1/s: 100 · 10 s / 2.5 = 400 sub-steps
    dynamics.check_stability(robot, 10.0, 400)
    with pytest.raises(ValueError, match=r"substeps = 10 is not allowed .*substeps >= 400"):
        dynamics.check_stability(robot, 10.0, 10)
    with pytest.raises(ValueError, match=r"a smaller speed_gain"):
        dynamics.check_stability(robot.replace(speed_gain=1e300), 0.033, 10)
    # A traced mass does not hide a wheel loop that is too stiff for the period.

    def stiff(mass):
        dynamics.check_stability(robot.replace(speed_gain=1e6, body_mass=mass), 0.033, 1)
        return mass

    with pytest.raises(ValueError, match=r"substeps = 1 is not allowed"):
        jax.grad(stiff)(1.0)
