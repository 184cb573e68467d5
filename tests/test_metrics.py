"""The metrics of docs/model.md §6, pinned on hand-made runs whose answers are known."""

import math

import jax
import numpy as np
import pytest
from conftest import random_refs, run_metrics

import wmr_jax as w
from wmr_jax import studies

DT = 0.1
REF = np.array([10.0, 0.0, 0.0])


def run_through(poses, v=None, omega=None, regions=None):
    """A ``Trajectory`` that visits ``poses`` (the first is the initial pose)."""
    poses = np.asarray(poses, dtype=float)
    steps = len(poses) - 1
    v = np.zeros(steps) if v is None else np.asarray(v, dtype=float)
    omega = np.zeros(steps) if omega is None else np.asarray(omega, dtype=float)
    regions = np.zeros(steps, np.int32) if regions is None else np.asarray(regions, np.int32)
    distance = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    wheels = np.stack([v - 1.85 * omega, v + 1.85 * omega], axis=-1)
    return w.Trajectory(poses, v, omega, regions, wheels, distance)


def at(dx=0.0, heading_deg=0.0):
    """A pose ``dx`` cm beyond the reference with the given heading error."""
    return [REF[0] + dx, REF[1], math.radians(heading_deg)]


# The single runs whose arrival is measured below are all 5 periods long: the
# metrics run op by op, and each new trajectory shape compiles their operations again.
def start_then(*poses):
    """From the origin through ``poses``, holding the last one to the end of 5 periods."""
    poses = list(poses)
    return [[0.0, 0.0, 0.0]] + poses + poses[-1:] * (5 - len(poses))


def test_heading_tolerance_is_in_radians_and_five_degrees_by_default():
    # 4° off arrives, 6° off does not: the default tolerance is 5° given in rad.
    for heading, arrives in ((4.0, True), (6.0, False), (-4.0, True), (184.0, True)):
        traj = run_through(start_then(at(0.5, heading)))
        time = float(w.arrival_time(traj, REF, dt=DT))
        assert math.isfinite(time) == arrives, heading
    assert w.studies.DEFAULT_TOL_THETA == pytest.approx(math.radians(5.0))


def test_distance_tolerance_is_one_cm_by_default():
    for dx, arrives in ((0.99, True), (1.01, False), (-0.99, True)):
        traj = run_through(start_then(at(dx)))
        assert math.isfinite(float(w.arrival_time(traj, REF, dt=DT))) == arrives, dx


def test_arrival_is_the_settled_one_not_the_first():
    # Samples are the poses after each period: arrived after period 1, away
    # after period 2, arrived again from period 3 on. The first arrival
    # would be 1 dt; the settled one is 3 dt.
    traj = run_through([[0, 0, 0], at(), at(3.0), at(), at(), at()])
    assert float(w.arrival_time(traj, REF, dt=DT)) == pytest.approx(3 * DT)
    # Leaving at the very end means it never arrived.
    traj = run_through([[0, 0, 0], at(), at(), at(), at(), at(3.0)])
    assert math.isinf(float(w.arrival_time(traj, REF, dt=DT)))
    # The initial pose is not a sample: starting on the goal arrives at dt.
    traj = run_through([at()] * 6)
    assert float(w.arrival_time(traj, REF, dt=DT)) == pytest.approx(DT)


def test_arrived_and_success_rate():
    poses = np.array([at(), at(2.0), at(0.0, 10.0), at(-0.5), at(0.0, -4.0)])
    np.testing.assert_array_equal(
        np.asarray(w.studies.arrived(poses, REF)), [True, False, False, True, True]
    )
    assert w.success_rate([1.0, np.inf, 2.0, 3.0]) == pytest.approx(0.75)


def test_path_length_sums_the_distance_travelled():
    traj = run_through([[0, 0, 0], [3, 4, 0], [3, 4, 0], [6, 8, 0]])
    assert float(w.studies.path_length(traj)) == pytest.approx(10.0)


def test_zigzag_counts_sign_changes_beyond_the_dead_bands():
    v = [5.0, 0.5, -5.0, -0.5, 5.0, 5.0]  # 0.5 is inside the 1 cm/s band: 2 changes
    omega = [0.2, -0.05, 0.3, -0.2, -0.2, 0.2]  # -0.05 inside the band: 2 changes
    traj = run_through(np.zeros((7, 3)), v=v, omega=omega)
    assert int(w.studies.zigzag_count(traj)) == 4
    assert int(w.studies.zigzag_count(traj, v_dead_band=10.0, omega_dead_band=10.0)) == 0


def test_region_time_counts_samples_per_region():
    traj = run_through(np.zeros((6, 3)), regions=[2, 2, 1, 3, 0])
    np.testing.assert_allclose(np.asarray(w.studies.region_time(traj, dt=DT)), [0.1, 0.1, 0.2, 0.1])


def test_batched_trajectories():
    a = run_through([[0, 0, 0], at(), at()])
    b = run_through([[0, 0, 0], at(5.0), at()])
    batch = w.Trajectory(*(np.stack(pair) for pair in zip(a, b, strict=True)))
    np.testing.assert_allclose(np.asarray(w.arrival_time(batch, REF, dt=DT)), [DT, 2 * DT])


def test_streamed_metrics_equal_the_trajectory_metrics():
    refs = random_refs(11, 24)
    gains = w.Gains(kr=60.0)
    traj = w.batch_rollout(refs, gains, steps=120)
    streamed = w.sweep(refs, gains, steps=120)
    want = run_metrics(traj, refs, 0.033)  # the trajectory metrics, compiled as one program
    np.testing.assert_array_equal(streamed["arrival_time"], want["arrival"])
    np.testing.assert_allclose(streamed["path_length"], want["path"], rtol=1e-12)
    np.testing.assert_array_equal(streamed["zigzags"], want["zigzag"])
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(1, 2))
    np.testing.assert_allclose(streamed["peak_wheel_speed"], peak, rtol=1e-12)


def test_run_table_rows_are_each_runs_metrics():
    a = run_through([[0, 0, 0], at(), at()], v=[200.0, 0.0])
    b = run_through([[0, 0, 0], at(5.0), at(0.5)], omega=[0.0, 100.0])
    batch = w.Trajectory(*(np.stack(pair) for pair in zip(a, b, strict=True)))
    refs = np.stack([REF, REF])
    rows = studies.run_table(batch, refs, dt=DT, robot=w.Robot(half_track=1.85))
    assert [r["arrival_s"] for r in rows] == [DT, 2 * DT]
    assert [r["path_cm"] for r in rows] == [10.0, 19.5]  # 15 cm out, 4.5 cm back
    assert [r["peak_wheel_cm_s"] for r in rows] == [200.0, 185.0]
    assert [r["saturated_fraction"] for r in rows] == [0.5, 0.5]  # one period of two > 125 cm/s
    assert [r["final_distance_cm"] for r in rows] == [0.0, 0.5]
    # The references are reported as given, in a float32 session too (not 40.099998).
    odd = np.array([[40.1, 0.0, -math.pi / 4], [0.0, 40.0, math.pi / 2]])
    with jax.enable_x64(False):
        rows = studies.run_table(batch, odd, dt=DT)
    assert [r["ref"] for r in rows] == [[40.1, 0.0, -45.0], [0.0, 40.0, 90.0]]
    # A reference per run, one robot: a shorter list of references is no longer broadcast.
    for args, kwargs, message in (
        ((batch, refs[:1]), {}, r"refs has shape \(1, 3\); allowed: \(2, 3\), one per run"),
        ((batch, refs), {"robot": w.Robot(v_max=-1.0)}, r"robot.v_max = -1.0"),
        (
            (batch, refs),
            {"robot": "x"},
            r"robot = 'x' is not allowed; allowed: a Robot \(wmr_jax.load_robot",
        ),
        ((a, REF), {}, r"poses of shape \(3, 3\) is not allowed; allowed: a Trajectory of"),
    ):
        with pytest.raises(ValueError, match=message):
            studies.run_table(*args, dt=DT, **kwargs)


def test_the_distance_tolerance_holds_at_its_boundary():
    # docs/model.md §6: arrived when r_e <= tol_r; exactly 1 cm away counts.
    assert math.isfinite(float(w.arrival_time(run_through(start_then(at(1.0))), REF, dt=DT)))
    beyond = [float(np.nextafter(REF[0] + 1.0, 20.0)), 0.0, 0.0]  # the next float: 1 + 2e-15 cm
    assert math.isinf(float(w.arrival_time(run_through(start_then(beyond)), REF, dt=DT)))


def test_a_non_finite_pose_is_named_by_its_index_in_traj_poses():
    # Run 1, sample 2: named as the user indexes it, not by a flattened row.
    traj = run_through(start_then(at()))
    poses = np.stack([traj.poses, traj.poses])
    poses[1, 2, 0] = np.nan
    batch = traj._replace(poses=poses)
    with pytest.raises(
        ValueError, match=r"traj\.poses\[1, 2\] = \[nan, 0\.0, 0\.0\] is not finite"
    ):
        w.arrival_time(batch, REF, dt=DT)
