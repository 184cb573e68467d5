"""Edges of the public API: every input gives a correct result or one clear error.

Each test here pins one way a careful user can go wrong (docs/model.md §3–§6):
values beyond the compute dtype, huge headings, malformed arguments to the
metrics, batched and list-valued gains, ties of the smooth law, the polar
baselines at their goal, and the boundaries of the checks themselves.
"""

import math
import warnings

import jax
import numpy as np
import pytest
from conftest import run_metrics

import wmr_jax as w
from wmr_jax import tuning

REF = [30.0, 30.0, 0.0]
# The horizon of the single runs that need one: each distinct number of steps
# (a static option) is a compilation, so the tests share this one.
STEPS = 60


def error():
    """The error coordinates of the origin with respect to ``REF``."""
    return w.controllers.polar_error([0.0, 0.0, 0.0], REF)


# ---------------------------------------------------------------- the dtype's range


@pytest.mark.parametrize("ref", [[1e39, 0.0, 0.0], [1e20, 0.0, 0.0], [0.0, -1e19, 0.0]])
def test_positions_beyond_float32_are_refused(ref):
    with jax.enable_x64(False), pytest.raises(ValueError, match=r"ref = .* is too far for float32"):
        w.rollout(ref, steps=3)
    with jax.enable_x64(False), pytest.raises(ValueError, match=r"init = .* is too far"):
        w.rollout(REF, init=ref, steps=3)


def test_more_substeps_than_float32_resolves_are_refused():
    # At 10**6 sub-steps a float32 run ended 2.7 cm short of the float64 one
    # after 0.66 s: each sub-step's motion drowns in the rounding of the pose.
    message = r"substeps = 1000000 is not allowed in float32, .* <= 8388, or float64"
    with jax.enable_x64(False), pytest.raises(ValueError, match=message):
        w.rollout(REF, steps=3, velocity="nonideal", substeps=10**6)
    with jax.enable_x64(False):
        # The ideal loop has no sub-steps, and the limit itself runs.
        assert np.isfinite(np.asarray(w.rollout(REF, steps=2, substeps=10**6).poses)).all()
        assert np.isfinite(
            np.asarray(w.rollout(REF, steps=1, velocity="nonideal", substeps=8388).poses)
        ).all()


def test_float64_reaches_further():
    traj = w.rollout([1e20, 0.0, 0.0], w.Gains(kr=60.0), steps=STEPS)
    assert np.all(np.isfinite(np.asarray(traj.poses)))
    assert float(traj.poses[-1, 0]) > 0  # it drives towards the reference


@pytest.mark.parametrize("field", ["kr", "k_theta", "r_m"])
def test_gains_beyond_float32_are_refused(field):
    with (
        jax.enable_x64(False),
        pytest.raises(ValueError, match=f"gains.{field} = 1e\\+39 is beyond"),
    ):
        w.rollout(REF, w.Gains(**{field: 1e39}), steps=3)


def test_a_run_that_leaves_the_range_is_an_error_not_nans():
    with warnings.catch_warnings(), jax.enable_x64(False):
        warnings.simplefilter("ignore")
        # 3e38 cm/s for 10 s: the robot's position overflows float32.
        with pytest.raises(ValueError, match="left the range of float32"):
            w.rollout([1e3, 0.0, 0.0], w.Gains(kr=3e38), dt=10.0, steps=3)
        with pytest.raises(ValueError, match=r"run\(s\), e.g. run 1"):
            w.final_poses([[1.0, 0.0, 0.0], [1e3, 0.0, 0.0]], w.Gains(kr=3e38), dt=10.0, steps=3)


def test_gains_the_sampled_law_cannot_follow_warn():
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 3\.3"):
        w.rollout(REF, w.Gains(k_theta=100.0), steps=STEPS)
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 1e\+03"):
        w.rollout(REF, dt=100.0, steps=STEPS)
    # A period of a second or more: most likely milliseconds, said so; not below.
    with pytest.warns(w.SamplingWarning) as caught:
        w.rollout(REF, dt=1.0, steps=STEPS)
    (said,) = [str(c.message) for c in caught if c.category is w.SamplingWarning]
    assert said.endswith("§4); dt = 1 is in s (a period in milliseconds needs /1000)")
    with pytest.warns(w.SamplingWarning) as caught:
        w.rollout(REF, dt=0.99, steps=STEPS)
    (said,) = [str(c.message) for c in caught if c.category is w.SamplingWarning]
    assert said.endswith("(docs/model.md §4)")
    # The paper's gains and the tuned ones of the README are well inside.
    assert w.controllers.check_sampling(w.Gains(), 0.033) and w.controllers.check_sampling(
        w.Gains(kr=60.0), 0.033
    )
    heading, distance = w.controllers.sampling_margins(w.Gains(kr=89.7, r_m=2.79, r_a=2.79), 0.033)
    assert float(heading) < 2 and 1.6 < float(distance) < 2
    # Called with values, the helpers check them as a rollout would.
    with pytest.raises(ValueError, match=r"gains.r_a = 20.0 is not allowed; allowed: r_a <= r_m"):
        w.controllers.sampling_margins(w.Gains(r_m=2.79), 0.033)
    with pytest.raises(ValueError, match=r"dt = -0.1 is not allowed"):
        w.controllers.sampling_margins(w.Gains(), -0.1)
    heading, _ = w.controllers.sampling_margins(
        w.Gains(k_theta=10.0), np.array([0.01, 0.02])
    )  # per period
    np.testing.assert_allclose(heading, [0.1, 0.2])
    with pytest.raises(ValueError, match=r"robot.half_track = -2.0 is not allowed"):
        w.controllers.wheel_speed_bound(w.Gains(), w.Robot(half_track=-2.0))


@pytest.mark.parametrize("dt", [1e-46, 1e39])
def test_a_period_float32_cannot_hold_is_refused_before_the_run(dt):
    with jax.enable_x64(False), pytest.raises(ValueError, match=r"dt = .* not allowed in float32"):
        w.rollout(REF, w.Gains(kr=60.0), dt=dt, steps=3)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dt": True}, r"dt = True is not allowed"),
        ({"dt": "0.033"}, r"dt = '0.033' is not allowed"),
        ({"temperature": "0.1"}, r"temperature = '0.1' is not allowed"),
        ({"ref": [True, False, True]}, r"ref = \[True, False, True\] is not allowed"),
        # NumPy reads a bool among numbers as 0 or 1, and the array no longer shows it.
        ({"ref": [30, 30, True]}, r"ref = \[30, 30, True\] is not allowed"),
        ({"init": [0, 0, False]}, r"init = \[0, 0, False\] is not allowed"),
        ({"ref": np.array([30, 30, True], dtype=object)}, r"ref = .* allowed: real numbers"),
        ({"ref": np.array([30 + 1j, 30, 0])}, r"ref = .* allowed: real numbers"),
        ({"ref": jax.numpy.array([30 + 1j, 30, 0])}, r"ref has dtype complex"),
        # An integer beyond any float, and no pose at all, are named as any other.
        ({"ref": [10**400, 0, 0]}, r"ref = \[1000.* allowed: real numbers"),
        ({"init": None}, r"init = None is not allowed; allowed: real numbers"),
    ],
)
def test_bools_strings_and_complex_numbers_are_not_numbers(kwargs, message):
    args = {"ref": REF, **kwargs}
    ref = args.pop("ref")
    with pytest.raises(ValueError, match=message):
        w.rollout(ref, w.Gains(kr=60.0), steps=3, **args)


@pytest.mark.parametrize("dtype", [complex, bool, str])
def test_a_batch_that_is_not_numbers_is_named_on_one_line(dtype):
    """A 2-D array's repr has a line per row: the message showed them all."""
    refs = np.ones((2, 3), dtype)
    for call in (lambda: w.final_poses(refs, steps=3), lambda: w.final_poses([REF], init=refs)):
        with pytest.raises(ValueError, match=r"^(refs|init) = array\(\[\[.*\], \[") as info:
            call()
        assert "\n" not in str(info.value)
    # Nested in a list, an array is on one line too.
    with pytest.raises(ValueError, match=r"^ref = \[array\(\[\[1., 0.\], \[0., 1.\]\]\), 1.0"):
        w.rollout([np.eye(2), 1.0, 2.0], steps=3)
    # A string is shown as given, its spaces kept.
    with pytest.raises(ValueError, match=r"^init = 'a  b' is not allowed"):
        w.rollout(REF, init="a  b", steps=3)


def test_temperature_and_steps_have_upper_bounds():
    with pytest.raises(ValueError, match=r"temperature = 1e\+30 is not allowed"):
        w.rollout(REF, temperature=1e30, steps=3)
    with pytest.raises(ValueError, match=r"steps = 2147483648 is not allowed"):
        w.rollout(REF, steps=2**31)


# ---------------------------------------------------------------- headings


def test_huge_headings_are_reduced_on_the_way_in():
    theta = 1e10
    reduced = math.remainder(theta, 2 * math.pi)  # float64 on the host
    for kwargs, same in (
        ({"ref": [20.0, 5.0, theta]}, {"ref": [20.0, 5.0, reduced]}),
        ({"ref": REF, "init": [0.0, 0.0, theta]}, {"ref": REF, "init": [0.0, 0.0, reduced]}),
    ):
        a = np.asarray(w.rollout(steps=STEPS, **kwargs).poses[1:])
        b = np.asarray(w.rollout(steps=STEPS, **same).poses[1:])
        assert np.all(np.isfinite(a))
        # 1e10 rad is itself only known to ulp(1e10) ≈ 2e-6 rad: reductions by
        # different float64 formulas agree to that, and so do the runs.
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_headings_beyond_what_float64_resolves_are_refused():
    # ulp(1e30) ≈ 1e14 rad: such a heading is no angle at all.
    with pytest.raises(ValueError, match=r"ref = .* has a heading beyond 1e\+12 rad"):
        w.rollout([30.0, 30.0, 1e30], steps=3)
    with pytest.raises(ValueError, match=r"init\[1\] = .* has a heading beyond"):
        w.final_poses([REF, REF], init=[[0.0, 0.0, 0.0], [0.0, 0.0, -1e13]], steps=3)


# ---------------------------------------------------------------- metrics


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda t: w.arrival_time(t, [np.nan, 30.0, 0.0], dt=0.033),
            "refs = .* is not finite",
        ),
        (lambda t: w.arrival_time(t, REF, dt=-1.0), "dt = -1.0 is not allowed"),
        (lambda t: w.arrival_time(t, [30.0, 30.0], dt=0.033), r"refs has shape \(2,\)"),
        (lambda t: w.arrival_time(t, [30.0, 30.0, 0.0, 1.0], dt=0.033), r"refs has shape \(4,\)"),
        (lambda t: w.arrival_time(np.zeros((5, 3)), REF, dt=0.033), "traj is a ndarray"),
        (lambda t: w.arrival_time(t, np.zeros((4, 3)), dt=0.033), "refs has batch shape"),
        (lambda t: w.arrival_time(t, REF, dt=0.033, tol_theta=5.0), "tol_theta = 5.0"),
        (lambda t: w.studies.arrived(np.zeros((2, 3)), np.zeros((3, 3))), "refs has batch shape"),
        (lambda t: w.studies.region_time(t, dt=-1.0), "dt = -1.0 is not allowed"),
        (
            lambda t: w.studies.zigzag_count(t, v_dead_band=-1.0),
            "v_dead_band = -1.0 is not allowed",
        ),
        (lambda t: w.studies.zigzag_count(t, omega_dead_band=np.nan), "omega_dead_band = nan"),
        (lambda t: w.studies.path_length(np.zeros((5, 3))), "traj is a ndarray"),
        (lambda t: w.success_rate([]), r"times has shape \(0,\) \(no runs\); allowed: one or"),
        (lambda t: w.success_rate(t), "times = Trajectory is not allowed"),
        (lambda t: w.success_rate([True, False]), r"times = \[True, False\] is not allowed"),
        (lambda t: w.success_rate([0.5, -0.1]), r"times = .*-0.1.* is not allowed"),
        (lambda t: w.success_rate([0.5, np.nan]), r"times = .*nan.* is not allowed"),
        (
            lambda t: w.studies.path_length(t._replace(distance=t.distance.at[1, 2].set(np.nan))),
            r"traj.distance = .*nan.* allowed: finite numbers, cm, >= 0",
        ),
        (
            lambda t: w.studies.path_length(t._replace(distance=-t.distance)),
            "traj.distance = .* allowed: finite numbers, cm, >= 0",
        ),
        (
            lambda t: w.studies.path_length(t._replace(distance=t.distance[:, 1:])),
            r"traj.distance has shape \(3, 3\); allowed: \(3, 4\), one value per control period",
        ),
        (lambda t: w.studies.path_length(t._replace(distance=None)), "traj.distance = None is not"),
        (
            lambda t: w.studies.zigzag_count(t._replace(v=t.v > 0)),
            r"traj.v = an array of bool \(3, 4\) is not allowed; allowed: finite numbers, cm/s",
        ),
        (
            lambda t: w.studies.zigzag_count(t._replace(omega=t.omega[0])),
            r"traj.omega has shape \(4,\); allowed: \(3, 4\)",
        ),
        (
            lambda t: w.studies.region_time(t._replace(region=t.region + 4), dt=0.033),
            "traj.region = .* allowed: integer region labels 0 to 3",
        ),
        (
            lambda t: w.studies.region_time(t._replace(region=t.region * 1.0), dt=0.033),
            r"traj.region = an array of float\d+ \(3, 4\) is not allowed",
        ),
        (
            lambda t: w.arrival_time(t._replace(poses=t.poses[:, :1]), REF, dt=0.033),
            r"traj.poses has shape \(3, 1, 3\); allowed: \(..., steps \+ 1, 3\) with steps >= 1",
        ),
    ],
)
def test_bad_metric_arguments_are_named(call, message):
    traj = w.batch_rollout(np.array([REF, REF, [10.0, 0.0, 0.0]]), steps=4)
    with pytest.raises(ValueError, match=message):
        call(traj)


# ---------------------------------------------------------------- batched gains


def test_an_empty_batch_of_gains_or_robots_is_refused():
    with pytest.raises(ValueError, match=r"gains.kr has shape \(0,\); allowed: a scalar"):
        w.final_poses(REF, w.Gains(kr=np.zeros(0)), steps=3)
    with pytest.raises(ValueError, match=r"robot.v_max has shape \(0,\)"):
        w.final_poses(REF, robot=w.Robot(v_max=[]), steps=3)


def test_rollout_runs_one_robot_and_says_where_batches_go():
    with pytest.raises(ValueError, match=r"gains.kr has shape \(4,\).*use batch_rollout"):
        w.rollout(REF, w.Gains(kr=np.linspace(30, 120, 4)), steps=3)


def test_lists_are_fields_and_size_one_axes_are_shared():
    kr = [40.0, 80.0, 120.0]
    as_list = w.batch_rollout(REF, w.Gains(kr=kr), steps=20)
    as_array = w.batch_rollout(REF, w.Gains(kr=np.array(kr)), steps=20)
    one_ref = w.batch_rollout([REF], w.Gains(kr=kr), steps=20)
    final = w.final_poses([REF], w.Gains(kr=kr), steps=20)
    for traj in (as_list, one_ref):
        np.testing.assert_array_equal(np.asarray(traj.poses), np.asarray(as_array.poses))
    np.testing.assert_array_equal(np.asarray(final), np.asarray(as_array.poses[:, -1]))
    assert w.controllers.AicardiGains(k=(1.0, 2.0)).k.shape == (2,)
    with pytest.raises(ValueError, match=r"batch sizes differ \(refs: 2, gains\.kr: 3\)"):
        w.batch_rollout([REF, REF], w.Gains(kr=kr), steps=3)


def _one_run_each(run, batched, singles):
    """``run(batched)`` equals ``run(single)`` for each single, run by run (leaf by leaf)."""
    together = jax.tree.map(np.asarray, run(batched))
    for i, single in enumerate(singles):
        alone = jax.tree.map(np.asarray, run(single))
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a[i], b[0]), together, alone)


def test_every_batched_entry_point_shares_one_reference_with_each_run_of_batched_params():
    """README: a batch axis of size 1 is shared by every run (a raw vmap error before)."""
    from wmr_jax import studies

    kr = [40.0, 80.0, 120.0]
    gains, each = w.Gains(kr=kr), [w.Gains(kr=[k]) for k in kr]
    one = np.array([REF])
    disturbance = studies.sample_disturbance(jax.random.key(0), one, 20, noise_xy=0.5)
    ekf, ekfs = (
        w.studies.EKFParams(sigma_xy=[0.2, 0.9]),
        [w.studies.EKFParams(sigma_xy=s) for s in (0.2, 0.9)],
    )
    chain = np.array([[[20.0, 0.0, 0.0], REF]])
    track = np.broadcast_to(np.array(REF), (1, 20, 3))
    for run, batched, singles in (
        (lambda g: w.sweep(one, g, steps=20), gains, each),
        (lambda g: studies.disturbed_rollout(disturbance, g), gains, each),
        (lambda e: studies.disturbed_metrics(disturbance, estimator=e), ekf, ekfs),
        (lambda g: studies.evaluate_poses(one, g, steps=20), gains, each),
        (lambda g: studies.batch_chain_rollout(chain, g, steps=20), gains, each),
        (lambda g: studies.batch_track_rollout(track, g), gains, each),
    ):  # fmt: skip
        _one_run_each(run, batched, singles)
    # One init per run shares the reference and the references of the track.
    inits = np.array([[0.0, 0.0, 0.0], [5.0, -5.0, 1.0]])
    both = studies.batch_track_rollout(track, init=inits)
    second = studies.batch_track_rollout(track, init=inits[1:])
    np.testing.assert_allclose(np.asarray(both.error)[1], np.asarray(second.error)[0])
    chained = studies.batch_chain_rollout(chain, init=inits, steps=20)
    alone = studies.batch_chain_rollout(chain, init=inits[1:], steps=20)
    np.testing.assert_allclose(np.asarray(chained.leg)[1], np.asarray(alone.leg)[0])
    # One start shared by several references, as batch_rollout shares it.
    two = np.array([REF, [20.0, -10.0, 1.0]])
    np.testing.assert_allclose(
        w.sweep(two, steps=20, init=np.zeros((1, 3)))["final_x"], w.sweep(two, steps=20)["final_x"]
    )
    # Other sizes are still refused, naming the sizes given (not the repeated reference).
    with pytest.raises(ValueError, match=r"gains.kr has 3 values; allowed: one, or one per"):
        w.sweep(np.array([REF, REF]), gains, steps=5)
    two_robots = w.Robot(v_max=[100.0, 120.0])
    with pytest.raises(ValueError, match=r"^batch sizes differ \(gains.kr: 3, robot.v_max: 2\)"):
        w.sweep(one, gains, robot=two_robots, steps=5)
    with pytest.raises(ValueError, match=r"^batch sizes differ \(gains.kr: 3, estimator.sigma_xy"):
        studies.disturbed_metrics(disturbance, gains, estimator=ekf)
    with pytest.raises(ValueError, match=r"^init = \[\[0, 0, 0\], \[0, 0\]\] is not allowed"):
        w.sweep(one, init=[[0, 0, 0], [0, 0]], steps=5)
    with pytest.raises(ValueError, match=r"batch sizes differ"):
        studies.disturbed_rollout(
            studies.sample_disturbance(jax.random.key(0), np.array([REF, REF]), 5), gains
        )


def test_a_study_that_judges_one_loop_refuses_a_batch_of_parameters():
    """Its table would mix the runs of several loops into one row."""
    from wmr_jax import studies

    batched = w.Gains(kr=[40.0, 80.0])
    with pytest.raises(ValueError, match=r"^loop.params.kr has shape \(2,\); allowed: scalars"):
        studies.evaluate_loop(batched, np.array([REF]))
    with pytest.raises(ValueError, match=r"^params_by_name\['b'\].params.kr has shape"):
        studies.standard_conditions({"a": w.Gains(), "b": batched}, np.array([REF]), None)
    loop = studies.ClosedLoop("shim-sung", w.Gains(), w.studies.EKFParams(sigma_xy=[0.2, 0.9]))
    with pytest.raises(ValueError, match=r"^loop.estimator.sigma_xy has shape \(2,\)"):
        studies.evaluate_loop(loop, np.array([REF]))


@pytest.mark.parametrize(
    "value",
    ["abc", 1 + 2j, {"a": 1}, None, ["x", "y"], True, [True, False], [60.0, True], np.array([1j])],
)
def test_gain_values_that_are_not_numbers_name_the_field(value):
    with pytest.raises(ValueError, match=r"gains\.kr"):
        w.rollout(REF, w.Gains(kr=value), steps=3)


# ---------------------------------------------------------------- the smooth law's ties


def test_relaxed_law_drives_from_a_tie_as_the_hard_law_does():
    """Straight to the side (cos φ_e = 0): the relaxation used to stall there."""
    ref = [0.0, 30.0, 0.0]
    hard = np.asarray(w.rollout(ref, steps=STEPS).poses[-1])
    # Each temperature (a static option) compiles: the tuner's 0.05 and two small ones.
    runs = [w.rollout(ref, temperature=t, steps=STEPS) for t in (0.05, 1e-4, 1e-8)]
    errors = [float(np.abs(np.asarray(run.poses[-1]) - hard).max()) for run in runs]
    assert errors[0] < 1.0 and errors[1] < 1e-6 and errors[2] < 1e-6, errors
    assert float(runs[0].omega[0]) > 9.0  # the hard law commands k_θ = 10 rad/s


def test_relaxed_gradient_from_a_tie_is_finite_and_alive_in_float32():
    with jax.enable_x64(False):

        def final_y(kr):
            return w.rollout([0.0, 30.0, 0.0], w.Gains(kr=kr), temperature=0.05, steps=STEPS).poses[
                -1, 1
            ]

        grad = float(jax.grad(final_y)(60.0))
    assert math.isfinite(grad) and grad != 0.0


# ---------------------------------------------------------------- the baselines at their goal


@pytest.mark.parametrize("x64", [False, True])
@pytest.mark.parametrize("controller", ["aicardi", "astolfi-corke"])
def test_polar_baselines_stay_at_the_goal_over_long_horizons(controller, x64):
    dist, bearing, heading = np.meshgrid(
        [10.0, 75.0], np.arange(4) * math.pi / 2 + 0.3, [-math.pi / 2, 0.0, math.pi], indexing="ij"
    )
    refs = np.stack([dist * np.cos(bearing), dist * np.sin(bearing), heading], -1).reshape(-1, 3)
    refs = np.concatenate([refs, [[10.0, 0.0, math.pi / 2]]])
    with jax.enable_x64(x64):
        traj = w.batch_rollout(refs, controller=controller, steps=364)  # 12 s
        times = run_metrics(traj, refs)["arrival"]
    assert np.all(np.isfinite(times)), refs[~np.isfinite(times)]
    assert times.max() < 6.0  # arrived within the usual horizon and stayed for the rest


# ---------------------------------------------------------------- boundaries of the checks


def test_wheel_condition_holds_exactly_at_its_boundary():
    robot = w.Robot()
    k_theta = 10.0
    at = float(robot.v_max) - float(robot.half_track) * k_theta  # k_r + L k_θ = V_max
    assert bool(w.controllers.check_feasible(w.Gains(kr=at - 1e-6, k_theta=k_theta)))
    assert bool(w.controllers.check_feasible(w.Gains(kr=at, k_theta=k_theta)))
    assert not bool(w.controllers.check_feasible(w.Gains(kr=at + 1e-6, k_theta=k_theta)))


def test_the_tuners_box_reaches_the_wheel_limit():
    robot = w.Robot()
    top = tuning.gains_from_unit(np.ones(7))
    bound = float(top.kr) + float(robot.half_track) * float(top.k_theta)
    assert float(robot.v_max) * 0.999 <= bound <= float(robot.v_max)


def test_com_offset_is_allowed_up_to_the_body_edge():
    edge = float(w.Robot().body_diameter) / 2
    w.rollout(REF, robot=w.Robot(com_offset=edge - 1e-9), velocity="nonideal", steps=2)
    with pytest.raises(ValueError, match="robot.com_offset"):
        w.rollout(REF, robot=w.Robot(com_offset=edge), velocity="nonideal", steps=2)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: w.control([0.0, 0.0, 0.0], REF, w.Gains(), temperature=-1.0),
            "temperature = -1.0",
        ),
        (
            lambda: w.control([0.0, 0.0, 0.0], REF, w.Gains(), temperature=10.0),
            "temperature = 10.0",
        ),
        (
            lambda: w.control([0.0, 0.0, 0.0], REF, w.Gains(), temperature=np.nan),
            "temperature = nan",
        ),
        (
            lambda: w.control([0.0, 0.0, 0.0], REF, w.Gains(), temperature=True),
            "temperature = True",
        ),
        # A NaN pose is not "at the goal" (r_e = 0), and a (2,) ref is no pose.
        (lambda: w.control(jax.numpy.array([np.nan, 0.0, 0.0]), REF, w.Gains()), "not finite"),
        (lambda: w.control([0.0, 0.0, 0.0], [30.0, 30.0], w.Gains()), r"ref has shape \(2,\)"),
        (
            lambda: w.controllers.control_diagnostics([0.0, 0.0, 0.0], REF, w.Gains(kr=-1.0)),
            "gains.kr = -1",
        ),
        (
            lambda: w.controllers.control_diagnostics([0.0, 0.0, 0.0], REF, None),
            "gains = None is not allowed; allowed: a wmr_jax.Gains",
        ),
    ],
)
def test_the_law_functions_check_what_users_pass(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_a_frame_may_be_one_array_of_four_rows():
    # (x, y, cos θ, sin θ) of two poses as a (4, 2) array, as a tuple of rows would be.
    frame = np.array([[0.0, 1.0], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    np.testing.assert_allclose(
        w.controllers.polar_error(None, [10.0, 0.0, 0.0], frame=frame).r, [10.0, 9.0]
    )


def test_a_bool_among_numbers_is_refused_by_the_batch_and_reference_entry_points():
    with pytest.raises(ValueError, match=r"refs = \[\[30, 30, True\]\] is not allowed"):
        w.final_poses([[30, 30, True]], w.Gains(kr=60.0), steps=3)
    with pytest.raises(ValueError, match=r"ref = \[30, 30, True\] is not allowed"):
        w.reference_rollout([30, 30, True], w.Gains(kr=60.0), steps=3)
    with pytest.raises(ValueError, match=r"pose = \[0, 0, True\] is not allowed"):
        w.control([0, 0, True], REF, w.Gains(kr=60.0))


def test_the_entry_points_check_concrete_gains_beside_traced_poses():
    # Mapping over poses with concrete, bad gains still names the gains.
    bad = w.controllers.AstolfiGains(k_rho=-3.0)
    with pytest.raises(ValueError, match=r"gains\.k_rho = -3"):
        jax.vmap(lambda q: w.controllers.astolfi_control(q, [30.0, 30.0, 0.0], bad))(
            jax.numpy.zeros((4, 3))
        )
    with pytest.raises(ValueError, match=r"gains\.kr = -3"):
        jax.vmap(lambda q: w.control(q, [30.0, 30.0, 0.0], w.Gains(kr=-3.0)))(
            jax.numpy.zeros((4, 3))
        )


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


# ---------------------------------------------------------------- the laws' building blocks


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: w.controllers.aicardi_control(
                [0, 0, 0], REF, w.controllers.AicardiGains(gamma=-1.0)
            ),
            r"gains\.gamma = -1",
        ),
        (
            lambda: w.controllers.astolfi_control(
                [0, 0, 0], REF, w.controllers.AstolfiGains(k_rho=-3.0)
            ),
            r"gains\.k_rho = -3",
        ),
        (
            lambda: w.controllers.aicardi_control([0, 0, 0], REF, w.Gains()),
            r"allowed: a wmr_jax\.AicardiGains",
        ),
        (
            lambda: w.controllers.astolfi_control([0, 0], REF, w.controllers.AstolfiGains()),
            r"pose has shape \(2,\)",
        ),
        (lambda: w.controllers.knot_radii(1), r"knots = 1 is not allowed"),
    ],
)
def test_the_laws_called_by_hand_check_their_values(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_the_laws_building_blocks_take_plain_numbers_and_lists():
    np.testing.assert_allclose(
        np.asarray(w.controllers.wrap_angle([1.0, 7.0])), [1.0, 7.0 - 2 * np.pi]
    )
    cos_bar, sin_bar = w.controllers.fold(-0.6, 0.8)
    np.testing.assert_allclose([float(cos_bar), float(sin_bar)], [0.6, -0.8])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: w.studies.residual_bound(None), r"phi_m = None is not allowed"),
        (lambda: w.studies.residual_bound(True), r"phi_m = True is not allowed"),
        (
            lambda: w.studies.run_benchmark(w.studies.BenchConfig(sizes="10")),
            r"sizes = '10' is not allowed; allowed: a sequence",
        ),
        (
            lambda: w.studies.run_benchmark({"steps": 1}),
            r"config is a dict; allowed: a BenchConfig",
        ),
        (
            lambda: w.studies.run_benchmark(
                w.studies.BenchConfig(sizes=(10,), cases=("final_poses",)), log="x"
            ),
            r"log = 'x' is not allowed",
        ),
        (
            lambda: w.studies.evaluate_poses(np.array([REF]), w.Gains(), x64="no"),
            r"x64 = 'no' is not allowed; allowed: True or False",
        ),
        (
            lambda: w.tuning.tuning_loss(w.Gains(), np.array([REF]), temperature=0.1, remat="no"),
            r"remat = 'no' is not allowed; allowed: True or False",
        ),
        # A JAX bool among numbers is a bool too.
        (lambda: w.rollout([30.0, 30.0, jax.numpy.array(True)], steps=3), r"ref = .* not allowed"),
    ],
)
def test_options_of_the_studies_are_checked_before_work(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_a_parameter_below_the_smallest_normal_number_is_told_what_is_allowed():
    """It said "allowed: 0 or a larger magnitude", and 0 is then refused for r_e."""
    with jax.enable_x64(False):
        with pytest.raises(ValueError) as info:
            w.rollout(REF, w.Gains(r_e=1e-45), steps=3)
    message = str(info.value)
    assert message.startswith("gains.r_e = ") and "smallest normal number (1.18e-38)" in message
    assert message.endswith(
        "allowed: a magnitude of at least 1.18e-38 (or 0, where the field "
        "allows 0), or float64 (jax.config.update('jax_enable_x64', True))"
    )
    with pytest.raises(ValueError, match=r"^gains.r_e = 0.0 is not allowed"):
        w.rollout(REF, w.Gains(r_e=0.0), steps=3)


def test_wheel_speeds_take_lists():
    """A list raised "can't multiply sequence": lists are arrays, here as everywhere."""
    np.testing.assert_allclose(
        np.asarray(w.controllers.wheel_speeds([1.0, 2.0], [0.0, 1.0], w.Robot(half_track=2.0))),
        [[1.0, 1.0], [0.0, 4.0]],
    )


@pytest.mark.parametrize(
    ("name", "call"),
    [
        ("time_bounds", lambda x: w.studies.time_bounds(np.array([[30.0, 30.0, 0.0]]) * x)),
        ("check_feasible", lambda x: w.controllers.check_feasible(w.Gains(kr=x))),
        ("success_rate", lambda x: w.success_rate(x * np.ones(3))),
        ("sweep", lambda x: w.sweep(np.array([REF]), w.Gains(kr=x), steps=3)),
        ("tuning.evaluate", lambda x: tuning.evaluate(w.Gains(kr=x), np.array([REF]))),
    ],
)
def test_host_functions_say_they_need_values_inside_a_transformation(name, call):
    """They raised JAX's TracerArrayConversionError, several lines long."""
    for transform in (jax.jit, jax.grad):
        with pytest.raises(ValueError) as info:
            transform(call)(60.0)
        assert str(info.value).startswith(f"{name} is called with traced values (inside jax.jit")
        assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("name", "call"),
    [
        ("temperature", lambda t: tuning.tuning_loss(w.Gains(), np.array([REF]), temperature=t)),
        ("temperature", lambda t: w.rollout(REF, w.Gains(), steps=3, temperature=t).poses.sum()),
        ("steps", lambda n: w.rollout(REF, w.Gains(), steps=n).poses.sum()),
    ],
)
def test_a_traced_setting_is_named_as_one_the_program_is_compiled_for(name, call):
    """A temperature or a step count under jax.jit: they said 'temperature =
    JitTracer(...) is not allowed; allowed: a number', which hid the cause."""
    value = 3 if name == "steps" else 0.05
    with pytest.raises(ValueError) as info:
        jax.jit(call)(value)
    assert str(info.value).startswith(f"{name} is traced (inside jax.jit, vmap or grad)")
    assert "pass it as a static argument" in str(info.value)
    assert np.isfinite(jax.jit(call, static_argnums=0)(value))  # static: it runs


def test_a_traced_disturbance_is_named_as_checked_on_the_host():
    """It said 'disturbance.noise = DynamicJaxprTracer ... allowed: real numbers'."""
    refs = np.array([REF])
    drawn = w.studies.sample_disturbance(jax.random.key(0), refs, 4, noise_xy=0.5)

    def run(noise):
        return w.studies.disturbed_rollout(drawn._replace(noise=noise), w.Gains())["poses"]

    with pytest.raises(ValueError) as info:
        jax.jit(run)(drawn.noise)
    assert str(info.value).startswith("disturbance.noise is traced (inside jax.jit, vmap or")
    assert "call this outside the transformation" in str(info.value)
    assert np.all(np.isfinite(run(drawn.noise)))


def test_the_wheel_speed_bound_names_batches_of_two_sizes():
    with pytest.raises(ValueError, match=r"^batch sizes differ \(gains.kr: 2, robot.half_track: 3"):
        w.controllers.wheel_speed_bound(w.Gains(kr=[1.0, 2.0]), w.Robot(half_track=[1.0, 2.0, 3.0]))
    bound = w.controllers.wheel_speed_bound(w.Gains(kr=[1.0, 2.0]), w.Robot(half_track=[2.0]))
    np.testing.assert_allclose(np.asarray(bound), [1.0 + 2.0 * 10.0, 2.0 + 2.0 * 10.0])
    assert (
        float(jax.jit(lambda k: w.controllers.wheel_speed_bound(w.Gains(kr=k)))(60.0))
        == 60.0 + 18.5
    )


def test_a_trajectory_larger_than_the_memory_is_refused_before_it_runs(monkeypatch):
    """steps = 2**30 went on to allocate 13 GB at once (the system may stall, not fail)."""
    from wmr_jax._src.sim import rollout as module

    monkeypatch.setattr(module, "_memory_bytes", lambda inputs=None: 10**6)
    per_period = module.record_bytes(1, 0, module.TRAJECTORY_RECORD)  # one run, one period
    fits = 10**6 // per_period - 1  # steps + 1 periods of one run just fit
    assert w.rollout(REF, steps=fits).poses.shape == (fits + 1, 3)
    with pytest.raises(ValueError, match=rf"^steps = {fits + 1} for 1 run\(s\) is not allowed"):
        w.rollout(REF, steps=fits + 1)
    with pytest.raises(ValueError, match=r"for 4 run\(s\) .* more than the 0.001 GB of memory"):
        w.batch_rollout(np.array([REF] * 4), steps=fits // 2)
    # The other entry points that keep every period: the disturbed runs, the waypoints'.
    from wmr_jax import studies

    disturbance = studies.sample_disturbance(jax.random.key(0), np.array([REF]), 2 * fits)
    with pytest.raises(ValueError, match=r"^steps = \d+ for 1 run\(s\) is not allowed"):
        studies.disturbed_rollout(disturbance)
    with pytest.raises(ValueError, match=r"for 1 run\(s\) .* more than the 0.001 GB"):
        studies.chain_rollout(np.array([REF]), steps=fits)
    with pytest.raises(ValueError, match=r"for 2 run\(s\) .* more than the 0.001 GB"):
        studies.batch_track_rollout(np.broadcast_to(np.array(REF), (2, fits, 3)))
    monkeypatch.setattr(module, "_memory_bytes", lambda inputs=None: None)  # unknown: runs
    assert w.batch_rollout(np.array([REF] * 4), steps=fits // 2).poses.shape[0] == 4
    monkeypatch.undo()
    assert module._memory_bytes() > 10**8  # this machine's memory, in bytes


def test_the_memory_check_counts_what_each_record_holds(monkeypatch):
    """Its count is an upper bound of the arrays returned, within a period of each."""
    from wmr_jax import studies
    from wmr_jax._src.sim import rollout as module
    from wmr_jax._src.sim.sensing import loop
    from wmr_jax._src.studies import waypoints

    # Three runs of one shared reference (three gains), as the two tests above
    # run them: the same programs, compiled once for the file.
    steps, runs = 20, 3
    gains, one = w.Gains(kr=[40.0, 80.0, 120.0]), np.array([REF])
    disturbance = studies.sample_disturbance(jax.random.key(0), one, steps, noise_xy=0.5)
    chain = np.array([[[20.0, 0.0, 0.0], REF]])
    track = np.broadcast_to(np.array(REF), (1, steps, 3))
    for result, record in (
        (w.batch_rollout([REF], gains, steps=steps), module.TRAJECTORY_RECORD),
        (studies.disturbed_rollout(disturbance, gains), loop._DISTURBED_RECORD),
        (studies.batch_chain_rollout(chain, gains, steps=steps), waypoints._CHAIN_RECORD),
        (studies.batch_track_rollout(track, gains), waypoints._TRACK_RECORD),
    ):
        assert jax.tree.leaves(result)[0].shape[0] == runs  # one record per run
        held = sum(np.asarray(leaf).nbytes for leaf in jax.tree.leaves(result))
        counted = module.record_bytes(runs, steps, record)
        # The commands have steps rows, the poses steps + 1; a chain's arrivals are few:
        # over by at most one period of each run.
        period = module.record_bytes(runs, 0, record)
        assert held <= counted <= held + period, (record, held, counted, period)


def test_the_memory_check_comes_before_a_shared_run_is_repeated(monkeypatch):
    """A one-run disturbance or track repeated for each of a million gains was copied first."""
    from wmr_jax import studies
    from wmr_jax._src.sim import rollout as module
    from wmr_jax._src.sim.sensing import loop
    from wmr_jax._src.studies import waypoints

    def copied(*args, **kwargs):
        raise AssertionError("the shared run was copied before the memory was checked")

    many = w.Gains(kr=np.full(10**4, 60.0))
    one = studies.sample_disturbance(jax.random.key(0), np.array([REF]), 50)
    track = np.broadcast_to(np.array(REF), (1, 50, 3))
    monkeypatch.setattr(module, "_memory_bytes", lambda inputs=None: 10**6)
    monkeypatch.setattr(loop.np, "repeat", copied)  # NumPy's, for this test only
    monkeypatch.setattr(waypoints.jnp, "broadcast_to", copied)
    with pytest.raises(ValueError, match=r"^steps = 50 for 10000 run\(s\) is not allowed"):
        studies.disturbed_rollout(one, many)
    with pytest.raises(ValueError, match=r"^steps = 50 for 10000 run\(s\) is not allowed"):
        studies.batch_track_rollout(track, many)
