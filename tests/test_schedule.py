"""The gain-scheduled Shim–Sung law: the wheel bound, the fixed law as a special case."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax.controllers import SHIM_SUNG

SCHEDULE = tuning.SCHEDULE
ROBOT = w.Robot()
V_MAX, L = float(ROBOT.v_max), float(ROBOT.half_track)


def _random_states(seed: int, n: int):
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-100, 100, (n, 2)), rng.uniform(-10, 10, n)])
    # Many states near the reference, where the law switches most.
    refs = poses + np.column_stack(
        [rng.standard_normal((n, 2)) * rng.choice([0.3, 3.0, 60.0], (n, 1)), rng.uniform(-4, 4, n)]
    )
    return jnp.asarray(poses), jnp.asarray(refs)


def _wild_schedule(seed: int) -> tuning.ScheduleParams:
    """Knots far beyond the wheel budget: only the construction keeps the bound."""
    rng = np.random.default_rng(seed)
    k = len(tuning.knot_radii())
    return tuning.ScheduleParams(
        kr=tuple(rng.uniform(1.0, 400.0, k)),
        k_theta=tuple(rng.uniform(0.5, 300.0, k)),
        k_turn=tuple(rng.uniform(0.5, 300.0, k)),
        phi_m=1.3,
        r_m=3.0,
        r_a=2.0,
        r_e=0.4,
        alpha=0.45,
    )


@pytest.mark.parametrize("temperature", [None, 0.05])
def test_every_command_obeys_the_wheel_bound_at_1e5_random_states(temperature):
    poses, refs = _random_states(0, 100_000)
    params = _wild_schedule(1)
    v, omega = SCHEDULE.command(poses, refs, params, temperature=temperature)
    wheel = np.abs(np.asarray(v)) + L * np.abs(np.asarray(omega))
    assert wheel.max() <= V_MAX * (1 + 1e-12)
    # The bound is reached (the budget is used), not met by standing still.
    assert wheel.max() > 0.99 * V_MAX and np.mean(np.abs(np.asarray(v)) > 1.0) > 0.3


@pytest.mark.filterwarnings("ignore::wmr_jax.SamplingWarning")  # wild on purpose
def test_whole_rollouts_keep_every_wheel_within_v_max():
    refs = random_refs(3, 64)
    traj = w.batch_rollout(refs, _wild_schedule(2), controller=SCHEDULE, steps=120)
    assert np.abs(np.asarray(traj.wheel_speeds)).max() <= V_MAX * (1 + 1e-12)


def test_constant_knots_are_the_fixed_law_exactly():
    gains = w.Gains(kr=60.0, k_theta=12.0, phi_m=1.2, r_m=15.0, r_a=8.0, r_e=0.8, alpha=0.3)
    params = tuning.ScheduleParams.from_gains(gains)
    poses, refs = _random_states(4, 20_000)
    for temperature in (None, 0.05):
        # Both compiled, as rollouts run them (XLA and op-by-op rounding may differ).
        fixed = jax.jit(lambda p, r, g, t=temperature: SHIM_SUNG.command(p, r, g, temperature=t))(
            poses, refs, gains
        )
        scheduled = jax.jit(
            lambda p, r, g, t=temperature: SCHEDULE.command(p, r, g, temperature=t)
        )(poses, refs, params)
        # The same operations on the same values: equal up to the rounding of
        # XLA's fusion of two different programs (a few ulp), never more.
        for a, b in zip(fixed, scheduled, strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-13)
    refs = random_refs(5, 200)
    # Inside the rollout loop XLA compiles both alike: bit for bit.
    np.testing.assert_array_equal(
        np.asarray(w.final_poses(refs, gains)),
        np.asarray(w.final_poses(refs, params, controller=SCHEDULE)),
    )
    one = w.rollout([30.0, -20.0, 2.0], params, controller=SCHEDULE)
    assert np.array_equal(
        np.asarray(one.region), np.asarray(w.rollout([30.0, -20.0, 2.0], gains).region)
    )


def test_the_relaxed_schedule_has_finite_gradients_for_every_knot():
    refs = random_refs(6, 4)
    params = tuning.ScheduleParams.from_gains(w.Gains(kr=60.0))
    # Compiled as the tuner runs it: one program for the loss and its gradient.
    loss = lambda p: tuning.tuning_loss(p, refs, temperature=0.05, horizon=0.7)  # noqa: E731
    grad = jax.jit(jax.grad(loss))(params)
    for name in ("kr", "k_theta", "k_turn"):
        values = np.asarray(getattr(grad, name))
        assert np.all(np.isfinite(values)), name
    assert np.any(np.asarray(grad.kr) != 0) and np.any(np.asarray(grad.k_turn) != 0)


def test_bad_schedules_are_refused_in_one_line():
    with pytest.raises(ValueError, match="one length"):
        w.rollout([10.0, 0.0, 0.0], tuning.ScheduleParams(kr=(60.0,) * 4), controller=SCHEDULE)
    with pytest.raises(ValueError, match=r"k_theta\[2\]"):
        bad = tuning.ScheduleParams(k_theta=(10.0, 10.0, -1.0) + (10.0,) * 7)
        w.rollout([10.0, 0.0, 0.0], bad, controller=SCHEDULE)
    assert math.isclose(tuning.knot_radii()[-1], 81.0)
    # Strings and bools are no gains (NumPy reads "60" and True as numbers);
    # the shape gains are named as the schedule's fields, not as Gains'.
    params = tuning.ScheduleParams()
    for change, message in (
        ({"kr": ("60",) * 10}, r"params.kr\[0\] = '60' is not allowed"),
        ({"kr": (True,) + (60.0,) * 9}, r"params.kr\[0\] = True is not allowed"),
        ({"v_max": True}, r"params.v_max = True is not allowed; allowed: a finite v_max > 0"),
        ({"phi_m": 2.0}, r"params.phi_m = 2.0 is not allowed"),
        ({"k_turn": (1.0,) * 2000}, r"params.k_turn has 2000 knots; allowed: 2 to 200"),
        # An empty knot is refused as an empty Gains field is, not run as a batch of 0.
        ({"kr": (np.ones(0),) + (60.0,) * 9}, r"params.kr\[0\] has shape \(0,\); allowed: a"),
    ):
        with pytest.raises(ValueError, match=message):
            w.final_poses([[10.0, 0.0, 0.0]], params.replace(**change), controller=SCHEDULE)
    with pytest.raises(ValueError, match=r"params.v_max = -1.0 is not allowed"):
        w.final_poses([[10.0, 0.0, 0.0]], params.replace(v_max=-1.0), controller=SCHEDULE)
    for knots in (1, "3", 10**12):
        with pytest.raises(ValueError, match=f"knots = {knots!r} is not allowed"):
            tuning.ScheduleParams.from_gains(w.Gains(), knots=knots)


def test_lists_are_values_and_batches_must_agree():
    """A list for a field or a knot is one batched value, as in Gains; batch sizes must agree."""
    refs = random_refs(0, 3)
    params = tuning.ScheduleParams()
    want = np.asarray(w.final_poses(refs, params, controller=SCHEDULE, steps=5))
    for change in (
        {"phi_m": [params.phi_m] * 3},
        {"v_max": (params.v_max,) * 3},
        {"kr": ([60.0, 60.0, 60.0],) + (60.0,) * 9},
        {"kr": list(params.kr)},
    ):
        got = w.final_poses(refs, params.replace(**change), controller=SCHEDULE, steps=5)
        np.testing.assert_array_equal(np.asarray(got), want)
    for change, message in (
        ({"kr": (np.ones(2), np.ones(3)) + (60.0,) * 8}, r"params.kr\[0\]: 2, params.kr\[1\]: 3"),
        (
            {"kr": (np.ones(2),) + (60.0,) * 9, "phi_m": np.ones(3)},
            r"params.kr\[0\]: 2, params.phi_m: 3",
        ),
    ):
        with pytest.raises(ValueError, match=rf"batch sizes differ \({message}"):
            w.final_poses(refs, params.replace(**change), controller=SCHEDULE, steps=5)
    with pytest.raises(ValueError, match="params.r_m = an integer of about 401 digits"):
        w.final_poses(refs, params.replace(r_m=10**400), controller=SCHEDULE, steps=5)
    with pytest.raises(ValueError, match="gains.kr = an integer of about 401 digits"):
        w.rollout([10.0, 0.0, 0.0], w.Gains(kr=10**400), steps=5)


def test_a_schedule_float32_cannot_hold_is_refused_there():
    params = tuning.ScheduleParams()
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match=r"params.kr\[1\] = 1e-50 is below float32's"):
            kr = (60.0, 1e-50) + (60.0,) * 8
            w.final_poses([[10.0, 0.0, 0.0]], params.replace(kr=kr), controller=SCHEDULE)
        with pytest.raises(ValueError, match=r"params.v_max = 1e\+39 is beyond float32"):
            w.final_poses([[10.0, 0.0, 0.0]], params.replace(v_max=1e39), controller=SCHEDULE)


def test_a_schedule_the_sampled_law_cannot_settle_with_warns():
    # The runs of test_lists_are_values_and_batches_must_agree: its compiled program.
    refs = random_refs(0, 3)
    # At the goal the tables take their first knots: k_θ dt = 200 * 0.033 = 6.6.
    fast = tuning.ScheduleParams(kr=(100.0,) * 10, k_theta=(200.0,) * 10, k_turn=(200.0,) * 10)
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 6\.6"):
        w.final_poses(refs, fast, controller=SCHEDULE, steps=5)
    # Large knots away from the goal are the schedule's point and do not warn.
    far = (10.0,) * 5 + (60.0,) * 5
    wide = tuning.ScheduleParams(kr=(60.0,) * 10, k_theta=far, k_turn=far)
    with warnings.catch_warnings():
        warnings.simplefilter("error", w.SamplingWarning)
        w.final_poses(refs, wide, controller=SCHEDULE, steps=5)


def test_the_sampling_margin_of_gains_near_float32s_limit_is_finite():
    """k_r = 3e38 fits float32, its margin does not: computed in float64, no NumPy overflow."""
    huge = tuning.ScheduleParams(kr=(3e38,) * 10)
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.warns(w.SamplingWarning, match=r"k_r\*pi\*dt/\(2\*R_m\) = 7\.78e\+35"):
            w.final_poses(random_refs(0, 2), huge, controller=SCHEDULE, steps=2)


def test_the_schedule_box_is_bounded_by_the_robot():
    # docs/model.md §3.9: k_r knots in (0, V_max], k_theta and k_turn knots in
    # (0, max(V_max / L, 1 / dt)]; the corners of the unit cube reach those bounds.
    from wmr_jax._src.tuning.problems import schedule_problem

    problem = schedule_problem(4)
    # A robot that turns fast: V_max / L = 80 rad/s bounds the turn gains.
    fast = problem.from_unit(np.ones(problem.dim), w.Robot(half_track=5.0, v_max=400.0))
    for table in (fast.k_theta, fast.k_turn):
        np.testing.assert_allclose([float(k) for k in table], [80.0] * 4, rtol=1e-6)
    # One that turns slowly (12 rad/s): the sampled heading loop's deadbeat gain, 1 / dt.
    robot = w.Robot(half_track=5.0, v_max=60.0)
    top = problem.from_unit(np.ones(problem.dim), robot)
    bottom = problem.from_unit(np.zeros(problem.dim), robot)
    omega_max = 1.0 / 0.033
    np.testing.assert_allclose([float(k) for k in top.kr], [60.0] * 4, rtol=1e-6)
    for table in (top.k_theta, top.k_turn):
        np.testing.assert_allclose([float(k) for k in table], [omega_max] * 4, rtol=1e-6)
    np.testing.assert_allclose([float(k) for k in bottom.kr], [60.0e-3] * 4, rtol=1e-6)
    np.testing.assert_allclose([float(k) for k in bottom.k_theta], [omega_max * 1e-3] * 4,
                               rtol=1e-6)  # fmt: skip
    assert float(top.v_max) == 60.0 and float(top.half_track) == 5.0
