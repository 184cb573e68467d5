"""Exact arc integration (docs/model.md §4)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

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
