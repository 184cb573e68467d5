"""The time-optimal yardsticks of docs/model.md §8 on hand-checked references."""

import math

import jax
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import tuning

DT = 0.033
V_MAX, L = 125.0, 1.85  # cm/s, cm: the paper's robot
OMEGA_MAX = V_MAX / L  # rad/s, spinning in place at full wheel speed


def _samples(seconds: float) -> float:
    return math.ceil(seconds / DT) * DT


@pytest.mark.parametrize(
    ("ref", "turns"),
    [
        ([30.0, 0.0, 0.0], 0.0),  # straight ahead: drive only
        ([-30.0, 0.0, 0.0], 0.0),  # behind: reverse, no turn (heading counts modulo π)
        ([0.0, 30.0, 0.0], math.pi),  # sideways: a quarter turn, drive, a quarter turn back
        ([0.0, -30.0, math.pi / 2], 0.5 * math.pi),  # sideways, facing the way it drives
        ([30.0, 0.0, math.pi / 2], 0.5 * math.pi),  # ahead, then a quarter turn
        ([30.0, 30.0, 0.0], 0.5 * math.pi),  # 45° there, 45° back
    ],
)
def test_turn_drive_turn_time_and_lower_bound(ref, turns):
    r = math.hypot(ref[0], ref[1])
    bounds = tuning.time_bounds(np.array([ref]), dt=DT)
    assert bounds.turn_drive_turn[0] == pytest.approx(_samples(turns / OMEGA_MAX + r / V_MAX))
    assert bounds.lower_bound[0] == pytest.approx(_samples((r - 1.0) / V_MAX))


def test_bounds_order_and_ratios():
    refs = random_refs(0, 500)
    b = tuning.time_bounds(refs)
    assert np.all(b.lower_bound <= b.turn_drive_turn)
    ratios = tuning.bound_ratios(0.5, b)
    assert ratios["vs_lower_bound"] == pytest.approx(0.5 / np.mean(b.lower_bound))
    # A slower robot has a larger bound; within the tolerance it is zero.
    slow = tuning.time_bounds(refs, robot=w.Robot(v_max=60.0))
    assert np.all(slow.lower_bound >= b.lower_bound)
    assert tuning.time_bounds([0.5, 0.0, 0.0]).lower_bound == 0.0
    with pytest.raises(ValueError, match="dt"):
        tuning.time_bounds(refs, dt=0.0)


def test_one_robot_per_reference_and_the_edges_of_the_bounds():
    refs = np.array([[30.0, 0.0, 0.0], [0.0, 30.0, 0.0]])
    # Each reference with its own robot: the one-robot bounds, row by row.
    both = tuning.time_bounds(refs, robot=w.Robot(v_max=[125.0, 60.0]))
    for i, v_max in enumerate((125.0, 60.0)):
        one = tuning.time_bounds(refs[i], robot=w.Robot(v_max=v_max))
        assert both.turn_drive_turn[i] == pytest.approx(float(one.turn_drive_turn))
    with pytest.raises(ValueError, match=r"robot.v_max has 3 values; allowed: one, or one per"):
        tuning.time_bounds(refs, robot=w.Robot(v_max=[1.0, 2.0, 3.0]))
    # Zero is 0 samples, never −0, and a zero bound cannot be a yardstick.
    zero = tuning.time_bounds([0.5, 0.0, 0.0])
    assert math.copysign(1.0, float(zero.lower_bound)) == 1.0
    with pytest.raises(ValueError, match="bounds > 0"):
        tuning.bound_ratios(0.5, zero)
    assert tuning.bound_ratios(math.inf, tuning.time_bounds(refs))["vs_lower_bound"] == math.inf
    # A positive time takes a sample however long the period: 30 cm at 125 cm/s
    # is 0.24 s, one sample of 1e9 s (not 0, which the rounding slack gave).
    slow = tuning.time_bounds([30.0, 0.0, 0.0], dt=1e9)
    assert float(slow.turn_drive_turn) == float(slow.lower_bound) == 1e9


def test_bounds_are_computed_from_the_references_in_float64():
    """A float32 session must not round the references first (π became 3.1415927 > π)."""
    with jax.enable_x64(False):
        half_turn = tuning.time_bounds([0.0, 0.0, math.pi])  # fold(π) = 0: nothing to do
        far = tuning.time_bounds([1e17, 0.0, 0.0])
        # 1.7 cm at 100 cm/s, tol 1 cm: 0.007 s exactly; float32 gave 8 samples of 1 ms.
        near = tuning.time_bounds([1.7, 0.0, 0.0], robot=w.Robot(v_max=100.0), dt=0.001)
    assert float(half_turn.turn_drive_turn) == 0.0
    assert float(far.lower_bound) >= 1e17 / 125.0 - 1e-2 * 0.033
    assert float(near.lower_bound) == pytest.approx(0.007)
    with pytest.raises(ValueError, match="bounds is a tuple; allowed: a TimeBounds"):
        tuning.bound_ratios(1.0, (1.0, 2.0))
