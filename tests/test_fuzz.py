"""Property-based fuzzing of the public entry points (docs/model.md §3–§6).

Every call either returns finite values (arrival times may be ``inf``: not
arrived) or raises ``ValueError``/``TypeError`` whose message names the
argument at fault. Shapes and static options are held fixed so that the
compiled programs are reused (500 examples per test, one to three calls
each: 3,500 judged calls, counted by the last test): breadth, where the
exact tests of ``test_edges.py`` and ``test_meaning_*.py`` pin the refusals'
wording; the ``slow`` marker runs more.
"""

import collections
import functools
import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import wmr_jax as w

EXAMPLES = 500  # per test; 1 + 1 + 2 + 3 calls per example: 3,500 calls in CI

# Calls judged in this process: answered with finite values, or refused by name.
CALLS = collections.Counter()

# Anything a user might pass where a number belongs.
ODD_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e3, max_value=1e3),
    st.integers(min_value=-(10**40), max_value=10**40),
    st.sampled_from([None, "abc", "1.5", [1.0, 2.0], {"a": 1}, 1 + 2j, True, (), np.float32(3.0)]),
)
GOOD_POSE = st.lists(st.floats(min_value=-80, max_value=80), min_size=3, max_size=3)
POSE = st.one_of(
    GOOD_POSE,
    st.lists(ODD_NUMBERS, min_size=3, max_size=3),
    st.lists(st.floats(min_value=-80, max_value=80), min_size=0, max_size=5),
    ODD_NUMBERS,
)
GAIN_FIELDS = ("kr", "k_theta", "phi_m", "r_m", "r_a", "r_e", "alpha")
ROBOT_FIELDS = ("half_track", "v_max", "body_mass", "wheel_radius", "com_offset", "torque_max")


def fuzz_settings(examples=EXAMPLES):
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    )


def check_call(call, names, *, never=False):
    """Run ``call``; its result must be finite, or its error must name one of ``names``.

    ``never``: ``+inf`` is a result too (an arrival time for a run that never arrives).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # legal but warned gains are fine here
        try:
            result = call()
        except (ValueError, TypeError) as err:
            message = str(err)
            assert any(name in message for name in names), (names, message)
            assert "\n" not in message.strip(), message
            CALLS["refused"] += 1
            return None
    for leaf in _leaves(result):
        assert np.all(np.isfinite(leaf) | (never & (leaf == np.inf))), result
    CALLS["answered"] += 1
    return result


def _leaves(result):
    if isinstance(result, tuple):  # a Trajectory, Diagnostics or (v, ω)
        return [np.asarray(x, dtype=float).reshape(-1) for x in result]
    return [np.asarray(result, dtype=float).reshape(-1)]


@fuzz_settings()
@given(
    ref=POSE,
    init=st.one_of(st.just([0.0, 0.0, 0.0]), POSE),
    field=st.sampled_from(GAIN_FIELDS),
    value=st.one_of(ODD_NUMBERS, st.floats(min_value=0.01, max_value=200)),
    dt=st.one_of(st.just(0.033), ODD_NUMBERS),
    # The temperature is static (each value compiles): two good ones, any bad one.
    temperature=st.one_of(
        st.sampled_from([None, 0.05]),
        st.sampled_from([0.0, -1.0, 10.5, 1e30, math.nan, math.inf, "0.1", [0.1], True]),
    ),
)
def test_rollout(ref, init, field, value, dt, temperature):
    names = ["ref", "init", f"gains.{field}", "dt", "temperature", "left the range"]
    check_call(
        lambda: w.rollout(
            ref, w.Gains(**{field: value}), init=init, dt=dt, steps=4, temperature=temperature
        ),
        names,
    )


@fuzz_settings()
@given(
    refs=st.one_of(
        st.lists(GOOD_POSE, min_size=3, max_size=3),
        st.lists(POSE, min_size=3, max_size=3),
        st.just([]),  # the batch size is static too: 3 or nothing
        ODD_NUMBERS,
    ),
    kr=st.one_of(st.just(60.0), ODD_NUMBERS, st.lists(ODD_NUMBERS, min_size=3, max_size=3)),
    field=st.sampled_from(ROBOT_FIELDS),
    value=st.one_of(ODD_NUMBERS, st.floats(min_value=0.01, max_value=500)),
    controller=st.sampled_from(["shim-sung", "aicardi", "astolfi-corke", "pid", 3]),
    entry=st.sampled_from(["batch_rollout", "final_poses"]),
)
def test_batches_and_robots(refs, kr, field, value, controller, entry):
    params = w.Gains(kr=kr) if controller == "shim-sung" else None
    names = ["refs", "gains.kr", "gains['kr']", f"robot.{field}", "controller", "batch sizes"]
    names.append("left the range")
    check_call(
        lambda: getattr(w, entry)(
            refs, params, robot=w.Robot(**{field: value}), controller=controller, steps=4
        ),
        names,
    )


@fuzz_settings()
@given(
    refs=POSE,
    dt=st.one_of(st.just(0.033), ODD_NUMBERS),
    tol_r=st.one_of(st.just(1.0), ODD_NUMBERS),
    tol_theta=st.one_of(st.just(math.radians(5)), ODD_NUMBERS),
    use_traj=st.booleans(),
)
def test_metrics(refs, dt, tol_r, tol_theta, use_traj):
    traj = _traj() if use_traj else np.zeros((4, 3))
    names = ["traj", "refs", "dt", "tol_r", "tol_theta"]
    check_call(
        lambda: w.arrival_time(traj, refs, dt=dt, tol_r=tol_r, tol_theta=tol_theta),
        names,
        never=True,
    )
    check_call(
        lambda: w.studies.arrived(_traj().poses, refs, tol_r=tol_r, tol_theta=tol_theta), names
    )


@fuzz_settings()
@given(
    pose=POSE,
    ref=POSE,
    field=st.sampled_from(GAIN_FIELDS),
    value=ODD_NUMBERS,
    seed=st.one_of(st.integers(min_value=-5, max_value=2**33), ODD_NUMBERS),
    # Large valid counts are real work, not edge cases: small ones and invalid ones only
    # (each valid count is a shape, compiled once: 0, 1 and two ordinary ones).
    n=st.one_of(
        st.integers(min_value=-2, max_value=3),
        st.sampled_from([2**27 + 1, 10**40, 2.5, "3", None, True, [2]]),
    ),
)
def test_law_sampler_and_checks(pose, ref, field, value, seed, n):
    gains = w.Gains(**{field: value})
    check_call(lambda: w.sample_poses(seed, n), ["seed", "n"])
    check_call(lambda: w.controllers.check_feasible(gains), [f"gains.{field}", "gains"])
    check_call(
        lambda: w.control(pose, ref, gains),
        ["gains", "pose", "ref"],
    )


@functools.cache
def _traj():
    """One run for the metrics to measure: run when first needed, not at collection.

    The horizon of ``test_rollout`` (``steps=4``), whose compiled program it shares.
    """
    return w.rollout([30.0, 30.0, 0.0], steps=4)


@pytest.mark.slow
@fuzz_settings(examples=25_000)
@given(ref=POSE, field=st.sampled_from(GAIN_FIELDS), value=ODD_NUMBERS)
def test_rollout_long(ref, field, value):
    names = ["ref", f"gains.{field}", "left the range"]
    check_call(lambda: w.rollout(ref, w.Gains(**{field: value}), steps=4), names)


def test_every_generated_call_was_judged():
    """The four tests above ran (in this process) and judged 3,000 calls or more."""
    if not CALLS:
        pytest.skip("run with the rest of this file")
    assert sum(CALLS.values()) >= 3_000, CALLS
    # Most generated inputs are odd on purpose; hundreds must still be answered.
    assert CALLS["refused"] > 2000 and CALLS["answered"] > 200, CALLS
