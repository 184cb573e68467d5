"""The metrics of docs/model.md §6, each against a plain-Python reading of its definition.

Each reference below (``_arrived``, ``_arrival``, ``_zigzags``, ...) is written
from the text of §6 with ``math`` and loops, not from ``metrics.py``; the runs
are tiny and hand-made, so no test compiles a rollout.
"""

import math

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src.sim import metrics as m

REF = (10.0, -5.0, 0.7)


def _arrived(pose, ref, tol_r, tol_theta):
    """§6: r_e ≤ tol_r and |θ̄_e| ≤ tol_θ, θ̄_e the heading error folded into [−π/2, π/2]."""
    r = math.hypot(ref[0] - pose[0], ref[1] - pose[1])
    theta = (ref[2] - pose[2] + math.pi) % (2 * math.pi) - math.pi  # wrap to [−π, π)
    folded = min(abs(theta), math.pi - abs(theta))
    return r <= tol_r and folded <= tol_theta


def _arrival(ok, dt):
    """(k + 1) dt for the smallest k arrived at every sample from k to the end; inf if none."""
    k = len(ok)
    while k > 0 and ok[k - 1]:
        k -= 1
    return math.inf if k == len(ok) else (k + 1) * dt


def _zigzags(xs, band):
    """Sign changes, samples with |x| ≤ band carrying no sign (+, 0, − is one change)."""
    signs = [1 if x > band else -1 if x < -band else 0 for x in xs]
    nonzero = [s for s in signs if s != 0]
    return sum(a != b for a, b in zip(nonzero, nonzero[1:], strict=False))


def _near(rng, n, spread_r, spread_theta):
    """``n`` poses around REF: some arrived, some not, forwards and backwards."""
    angle = rng.uniform(-math.pi, math.pi, n)
    dist = rng.uniform(0.0, spread_r, n)
    heading = REF[2] + rng.uniform(-spread_theta, spread_theta, n) + math.pi * rng.integers(0, 2, n)
    return np.stack([REF[0] + dist * np.cos(angle), REF[1] + dist * np.sin(angle), heading], -1)


def _traj(poses, v=None, omega=None, region=None, distance=None, wheels=None):
    poses = np.asarray(poses, float)
    shape = poses.shape[:-2] + (poses.shape[-2] - 1,)
    zeros = np.zeros(shape)
    return w.Trajectory(
        poses,
        zeros if v is None else np.asarray(v, float),
        zeros if omega is None else np.asarray(omega, float),
        np.zeros(shape, np.int32) if region is None else np.asarray(region),
        np.zeros((*shape, 2)) if wheels is None else np.asarray(wheels, float),
        zeros if distance is None else np.asarray(distance, float),
    )


def test_the_defaults_are_those_of_the_text():
    assert m.DEFAULT_TOL_R == 1.0
    assert m.DEFAULT_TOL_THETA == math.pi / 36  # 5°
    assert m.DEFAULT_V_DEAD_BAND == 1.0
    assert m.DEFAULT_OMEGA_DEAD_BAND == 0.1
    assert m.Thresholds() == (1.0, math.pi / 36, 1.0, 0.1)


def test_arrived_is_distance_and_folded_heading_within_tolerance():
    rng = np.random.default_rng(0)
    poses = _near(rng, 64, 3.0, 0.4)
    got = np.asarray(m.arrived(poses, np.array(REF), tol_r=1.5, tol_theta=0.2))
    want = [_arrived(p, REF, 1.5, 0.2) for p in poses]
    assert 0 < sum(want) < len(want)
    np.testing.assert_array_equal(got, want)
    got = np.asarray(m.arrived(poses, np.array(REF)))  # the defaults: 1 cm, 5°
    np.testing.assert_array_equal(got, [_arrived(p, REF, 1.0, math.pi / 36) for p in poses])


def test_arrived_broadcasts_batches_of_poses_against_references():
    rng = np.random.default_rng(4)
    poses = _near(rng, 6, 2.0, 0.2).reshape(2, 3, 3)
    refs = np.stack([np.array(REF)] * 3)  # (3, 3): one reference per column of runs
    got = np.asarray(m.arrived(poses, refs))
    want = [[_arrived(p, REF, 1.0, math.pi / 36) for p in row] for row in poses]
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    "poses, refs, message",
    [
        (np.zeros(2), np.zeros(3), r"^poses "),
        (np.zeros(3), np.zeros((2, 4)), r"^refs "),
        (np.array([0.0, math.nan, 0.0]), np.zeros(3), r"^poses"),
    ],
)
def test_arrived_refuses_misshapen_poses_naming_them(poses, refs, message):
    with pytest.raises(ValueError, match=message):
        m.arrived(poses, refs)


def test_arrival_time_is_the_start_of_the_settled_run_of_samples():
    rng = np.random.default_rng(1)
    dt, tol_r, tol_theta = 0.05, 2.0, 0.3
    start = np.broadcast_to([0.0, 0.0, 0.0], (8, 1, 3))
    poses = np.concatenate([start, _near(rng, 8 * 6, 3.0, 0.5).reshape(8, 6, 3)], axis=1)
    poses[0, 1:] = [REF[0], REF[1], REF[2] + math.pi]  # arrived backwards all along
    poses[1, -1] = [0.0, 0.0, 0.0]  # leaves at the last sample
    got = np.asarray(
        m.arrival_time(_traj(poses), np.array(REF), dt=dt, tol_r=tol_r, tol_theta=tol_theta)
    )
    want = [_arrival([_arrived(p, REF, tol_r, tol_theta) for p in run[1:]], dt) for run in poses]
    assert want[0] == dt and want[1] == math.inf
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert math.isinf(_arrival([], dt)) and math.isinf(_arrival([True, False], dt))


def test_success_rate_is_the_fraction_of_finite_times():
    assert m.success_rate([0.1, math.inf, 0.0, math.inf, 2.0]) == 3 / 5  # exactly, not float32
    assert m.success_rate(np.array([[math.inf]])) == 0.0


_TIMES = r"one or more arrival times, s \(from arrival_time; inf where a run never settles\)$"


@pytest.mark.parametrize(
    "times, message",
    [
        ([], r"^times has shape \(0,\) \(no runs\); allowed: one or more arrival times"),
        ([1.0, -0.5], r"^times.* is not allowed; allowed: " + _TIMES),
        ([1.0, math.nan], r"^times.* is not allowed; allowed: " + _TIMES),
        ("0.5", r"^times = str is not allowed; allowed: one or more arrival times, s "),
        (b"1", r"^times = bytes is not allowed"),
        ([True, False], r"^times.* is not allowed; allowed: " + _TIMES),
    ],
)
def test_success_rate_refuses_what_is_no_arrival_time(times, message):
    with pytest.raises(ValueError, match=message):
        m.success_rate(times)


def test_success_rate_refuses_a_trajectory():
    with pytest.raises(ValueError, match=r"^times = Trajectory is not allowed"):
        m.success_rate(_traj(np.zeros((2, 3))))
    assert m.success_rate([0.0]) == 1.0  # zero is a time (started on the goal)


def test_path_length_is_the_sum_of_the_distances_per_period():
    distance = np.array([[0.5, 0.0, 2.25], [1.0, 1.0, 1.0]])
    got = np.asarray(m.path_length(_traj(np.zeros((2, 4, 3)), distance=distance)))
    np.testing.assert_allclose(got, [2.75, 3.0])


def test_zigzag_count_skips_the_dead_band_including_its_edge():
    rng = np.random.default_rng(2)
    # Values on a grid of 0.5 cm/s and 0.05 rad/s, so that some equal the band exactly.
    v = rng.integers(-6, 7, (5, 12)) * 0.5
    omega = rng.integers(-6, 7, (5, 12)) * 0.05
    v[0] = [1.0, -1.0, 1.0, -1.0, 3, 0, -3, 0, 0, 3, -1.0, 1.0]  # |v| = 1 carries no sign
    traj = _traj(np.zeros((5, 13, 3)), v=v, omega=omega)
    got = np.asarray(m.zigzag_count(traj))
    want = [_zigzags(a, 1.0) + _zigzags(b, 0.1) for a, b in zip(v, omega, strict=True)]
    np.testing.assert_array_equal(got, want)
    assert got.dtype.kind == "i"  # a count
    assert _zigzags(v[0], 1.0) == 2
    got = np.asarray(m.zigzag_count(traj, v_dead_band=0.0, omega_dead_band=0.15))
    want = [_zigzags(a, 0.0) + _zigzags(b, 0.15) for a, b in zip(v, omega, strict=True)]
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            {"v_dead_band": -0.1},
            r"^v_dead_band = -0.1 is not allowed; allowed: a number >= 0 cm/s$",
        ),
        (
            {"omega_dead_band": math.nan},
            r"^omega_dead_band = nan is not allowed; allowed: a number >= 0 rad/s$",
        ),
    ],
)
def test_zigzag_dead_bands_are_non_negative(kwargs, message):
    with pytest.raises(ValueError, match=message):
        m.zigzag_count(_traj(np.zeros((3, 3))), **kwargs)


def test_region_time_counts_the_periods_in_each_region():
    region = np.array([[0, 3, 3, -1, 1, 3], [-1, -1, -1, -1, -1, -1]], np.int32)
    got = np.asarray(m.region_time(_traj(np.zeros((2, 7, 3)), region=region), dt=0.25))
    want = [[sum(r == k for r in row) * 0.25 for k in range(4)] for row in region]
    np.testing.assert_allclose(got, want)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("region", [0, 4], r"^traj\.region"),
        ("region", [-2, 0], r"^traj\.region"),
        (
            "region",
            np.array([0.0, 1.0]),
            r"^traj\.region = an array of float64 \(2,\) is not allowed; "
            r"allowed: integer region labels 0 to 3 \(-1 for a controller without regions\)$",
        ),
        ("distance", [1.0, -0.5], r"^traj\.distance.*allowed: finite numbers, cm, >= 0"),
        ("distance", [1.0, math.inf], r"^traj\.distance.*allowed: finite numbers, cm, >= 0"),
        (
            "distance",
            None,
            r"^traj\.distance = None is not allowed; allowed: finite numbers, cm, >= 0$",
        ),
        (
            "distance",
            [1.0, 2.0, 3.0],
            r"^traj\.distance has shape \(3,\); allowed: \(2,\), one "
            r"value per control period of traj\.poses \(3, 3\)$",
        ),
        ("v", [0.0, math.nan], r"^traj\.v.*allowed: finite numbers, cm/s$"),
        ("v", "fast", r"^traj\.v = 'fast' is not allowed; allowed: finite numbers, cm/s$"),
        ("omega", [math.inf, 0.0], r"^traj\.omega.*allowed: finite numbers, rad/s$"),
    ],
)
def test_trajectory_fields_are_checked_naming_field_unit_and_range(field, value, message):
    traj = _traj(np.zeros((3, 3)))._replace(**{field: value})
    call = {
        "region": lambda t: m.region_time(t, dt=0.1),
        "distance": m.path_length,
        "v": m.zigzag_count,
        "omega": m.zigzag_count,
    }[field]
    with pytest.raises(ValueError, match=message):
        call(traj)


def test_a_run_without_a_field_is_refused_naming_it():
    class PosesOnly:
        poses = np.zeros((3, 3))

    with pytest.raises(ValueError, match=r"^traj\.distance = None is not allowed"):
        m.path_length(PosesOnly())


def test_zigzag_count_takes_traced_dead_bands():
    """Dead bands may be traced (Thresholds: changing them does not recompile)."""
    v = np.array([[2.0, -2.0, 0.5, -3.0]])
    omega = np.array([[0.3, 0.3, -0.3, 0.3]])
    traj = _traj(np.zeros((1, 5, 3)), v=v, omega=omega)
    count = jax.jit(lambda t, a, b: m.zigzag_count(t, v_dead_band=a, omega_dead_band=b))
    got = np.asarray(count(traj, 1.0, 0.1))
    np.testing.assert_array_equal(got, [_zigzags(v[0], 1.0) + _zigzags(omega[0], 0.1)])
    np.testing.assert_array_equal(np.asarray(count(traj, 2.5, 0.1)), [0 + 2])


def test_a_distance_of_zero_and_integer_fields_are_allowed():
    traj = _traj(np.zeros((3, 3)))._replace(distance=np.array([0, 2]), v=np.array([2, -2]))
    assert float(m.path_length(traj)) == 2.0
    assert int(m.zigzag_count(traj)) == 1


@pytest.mark.parametrize(
    "poses, message",
    [
        (
            np.zeros(3),
            r"^traj\.poses has shape \(3,\); allowed: \(\.\.\., steps \+ 1, 3\) with "
            r"steps >= 1 \(the initial pose, then one per control period\)$",
        ),
        (np.zeros((4, 2)), r"^traj\.poses has shape \(4, 2\)"),
        (np.zeros((1, 3)), r"^traj\.poses has shape \(1, 3\)"),
        (
            np.array([[0, 0, 0], [0, math.inf, 0]]),
            r"^traj\.poses\[1\] = \[0\.0, inf, 0\.0\] is "
            r"not finite; allowed: finite numbers \(a run that left the range has no metrics\)$",
        ),
    ],
)
def test_arrival_time_refuses_what_is_no_run(poses, message):
    traj = _traj(np.zeros((2, 3)))._replace(poses=poses)
    with pytest.raises(ValueError, match=message):
        m.arrival_time(traj, np.array(REF), dt=0.1)


def test_arrival_time_refuses_no_trajectory_and_references_of_another_batch():
    with pytest.raises(
        ValueError,
        match=r"^traj is a ndarray; allowed: a Trajectory \(from "
        r"rollout or batch_rollout\), whose poses have shape \(\.\.\., steps \+ 1, 3\)$",
    ):
        m.arrival_time(np.zeros((2, 3)), np.array(REF), dt=0.1)
    traj = _traj(np.zeros((2, 3, 3)))
    with pytest.raises(
        ValueError,
        match=r"^refs has batch shape \(3,\) and traj \(2,\); allowed: "
        r"shapes that broadcast \(one reference per run, or one for all\)$",
    ):
        m.arrival_time(traj, np.zeros((3, 3)), dt=0.1)
    with pytest.raises(ValueError, match=r"^refs has batch shape \(3,\) and poses \(2,\)"):
        m.arrived(np.zeros((2, 3)), np.zeros((3, 3)))
    # The references themselves are checked under their own name.
    for bad, message in (
        ([0.0, math.nan, 0.0], r"^refs = \[0\.0, nan, 0\.0\] is not finite; allowed: finite"),
        ("abc", r"^refs = 'abc' is not allowed; allowed: real numbers"),
        ([0.0, 1.0], r"^refs has shape \(2,\); allowed: \(\.\.\., 3\)"),
    ):
        with pytest.raises(ValueError, match=message):
            m.arrival_time(_traj(np.zeros((2, 3))), bad, dt=0.1)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"tol_r": 0.0}, r"^tol_r = 0.0 is not allowed; allowed: a number > 0 cm$"),
        (
            {"tol_theta": math.pi / 2},
            r"^tol_theta = 1.57.* is not allowed; allowed: a number > 0 "
            r"and < 1.5708 rad$",
        ),
        ({"tol_theta": 0.0}, r"^tol_theta = 0.0 is not allowed"),
    ],
)
def test_tolerances_are_checked(kwargs, message):
    with pytest.raises(ValueError, match=message):
        m.arrived(np.zeros(3), np.zeros(3), **kwargs)
    with pytest.raises(ValueError, match=message):
        m.arrival_time(_traj(np.zeros((2, 3))), np.zeros(3), dt=0.1, **kwargs)


def test_pose_metrics_success_is_a_finite_arrival():
    pm = m.PoseMetrics(np.array([0.1, math.inf]), *([np.zeros(2)] * 4))
    np.testing.assert_array_equal(pm.success, [True, False])
    assert pm.first_arrival is None


class _Out:
    def __init__(self, v, omega, wheels, distance):
        self.v, self.omega, self.wheel_speeds, self.distance = (
            v,
            omega,
            np.asarray(wheels),
            distance,
        )


def test_streamed_metrics_follow_the_definitions_period_by_period():
    """stream_start / stream_update / stream_result against the §6 definitions."""
    rng = np.random.default_rng(3)
    th = m.Thresholds(tol_r=2.0, tol_theta=0.3, v_dead_band=0.5, omega_dead_band=0.05)
    dt, n = 0.04, 9
    poses = _near(rng, n, 3.2, 0.5)
    poses[2] = REF  # arrived at sample 2 at least
    poses[-3:] = REF  # and settled over the last three
    poses[-4] = [0.0, 0.0, 0.0]  # after leaving once
    v = rng.integers(-3, 4, n) * 0.5
    omega = rng.integers(-3, 4, n) * 0.05
    wheels = rng.normal(0.0, 50.0, (n, 2))
    dist = rng.uniform(0.0, 2.0, n)
    acc = m.stream_start(np.float64)
    assert acc.step == 0 and acc.settled_from == -1 and acc.first == -1
    assert acc.path == 0.0 and acc.peak_wheel == 0.0 and acc.zigzag == 0
    ref = np.array(REF)
    for k in range(n):
        acc = m.stream_update(acc, poses[k], ref, _Out(v[k], omega[k], wheels[k], dist[k]), th)
    got = {key: np.asarray(val) for key, val in m.stream_result(acc, dt).items()}
    ok = [_arrived(p, REF, 2.0, 0.3) for p in poses]
    first = next(k for k, a in enumerate(ok) if a)
    assert got["arrival_time"] == pytest.approx(_arrival(ok, dt)) == (n - 3 + 1) * dt
    assert got["first_arrival"] == pytest.approx((first + 1) * dt)
    assert got["success"]
    assert got["path_length"] == pytest.approx(sum(dist))
    assert got["peak_wheel_speed"] == np.abs(wheels).max()
    assert got["zigzags"] == _zigzags(v, 0.5) + _zigzags(omega, 0.05)
    assert int(acc.step) == n
    # RunMetrics.v_sign / omega_sign: the last sign (±1) beyond the dead band.
    assert int(acc.v_sign) == next(int(math.copysign(1, x)) for x in v[::-1] if abs(x) > 0.5)
    assert int(acc.omega_sign) == next(
        int(math.copysign(1, x)) for x in omega[::-1] if abs(x) > 0.05
    )


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_streamed_metrics_keep_lengths_in_the_dtype_asked_and_counts_in_int32(dtype):
    acc = m.stream_start(dtype)
    assert acc.path.dtype == dtype and acc.peak_wheel.dtype == dtype
    for count in (acc.step, acc.settled_from, acc.first, acc.v_sign, acc.omega_sign, acc.zigzag):
        assert count.dtype == np.int32 and count.shape == ()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_streamed_metrics_of_a_run_arrived_from_its_first_sample(dtype):
    """§6: arrived at every sample from k = 0 on: arrival (0 + 1) dt, a success."""
    acc = m.stream_start(dtype)
    ref = np.array(REF, dtype)
    for _ in range(3):
        acc = m.stream_update(acc, ref, ref, _Out(0.0, 0.0, [0.0, 0.0], 0.0), m.Thresholds())
    got = m.stream_result(acc, 0.25)
    assert float(got["arrival_time"]) == 0.25 and float(got["first_arrival"]) == 0.25
    assert bool(got["success"])
    assert got["arrival_time"].dtype == dtype and got["first_arrival"].dtype == dtype


def test_streamed_metrics_of_a_run_that_never_arrives():
    acc = m.stream_start(np.float64)
    far = np.array([50.0, 0.0, 0.0])
    for x in (1.0, -1.0):
        acc = m.stream_update(acc, far, np.array(REF), _Out(x, x, [x, -2 * x], 0.0), m.Thresholds())
    got = m.stream_result(acc, 0.1)
    assert math.isinf(float(got["arrival_time"])) and math.isinf(float(got["first_arrival"]))
    assert not bool(got["success"])
    assert float(got["peak_wheel_speed"]) == 2.0
    assert int(got["zigzags"]) == 1  # |v| = 1 cm/s has no sign; ω flips once
    assert (int(acc.v_sign), int(acc.omega_sign)) == (0, -1)  # v never had a sign
    assert (int(acc.settled_from), int(acc.first)) == (-1, -1)  # RunMetrics: −1, never arrived
    acc = m.stream_update(acc, far, np.array(REF), _Out(7.0, 0.0, [0, 0], 0.0), m.Thresholds())
    assert (int(acc.v_sign), int(acc.omega_sign)) == (1, -1)  # ω in its band keeps its sign


def test_arrival_time_runs_traced_with_the_values_it_gives_untraced():
    # Inside jit the trajectory and the tolerances are tracers: not checked
    # (they cannot be), and the same arrival time as outside.
    poses = np.array(
        [[0.0, 0.0, 0.0], [REF[0] + 0.9, REF[1], REF[2]], [REF[0], REF[1], REF[2] + 0.05]]
    )
    traj = _traj(poses)
    eager = float(m.arrival_time(traj, np.array(REF), dt=0.1, tol_r=1.0, tol_theta=0.06))
    traced = jax.jit(
        lambda t, tol_r, tol_theta: m.arrival_time(
            t, np.array(REF), dt=0.1, tol_r=tol_r, tol_theta=tol_theta
        )
    )(traj, 1.0, 0.06)
    assert eager == pytest.approx(0.1) and float(traced) == eager
