"""Consecutive motions: waypoint chains and moving references."""

import argparse
import math

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import baselines, metrics, waypoints
from wmr_jax.waypoints import (
    batch_chain_rollout,
    batch_track_rollout,
    chain_rollout,
    soccer_waypoints,
    track_rollout,
)

DT = 0.033


@pytest.mark.parametrize("controller", ["shim-sung", "astolfi-corke"])
def test_chain_visits_the_waypoints_in_order(controller):
    wp = soccer_waypoints()
    run = chain_rollout(wp, controller=controller, steps=450)
    arrival = np.asarray(run.arrival)
    assert np.isfinite(arrival).all() and np.all(np.diff(arrival) > 0)
    leg = np.asarray(run.leg)
    assert leg[0] == 0 and np.all(np.diff(leg) >= 0) and set(leg) == set(range(len(wp)))
    poses = np.asarray(run.trajectory.poses)
    for i, t in enumerate(arrival):
        k = round(t / DT)  # the sample at which waypoint i counted as reached
        assert np.all(leg[k:] >= i + 1) if i < len(wp) - 1 else True
        assert bool(metrics.arrived(poses[k], wp[i]))
        # Before it, the robot was still heading for this or an earlier waypoint.
        assert leg[k - 1] <= i


def test_single_waypoint_chain_is_a_rollout():
    ref = np.array([30.0, -20.0, 2.0])
    run = chain_rollout(ref[None], steps=150)
    traj = w.rollout(ref, steps=150)
    # The same closed loop by two arrangements of the same arithmetic.
    np.testing.assert_allclose(np.asarray(run.trajectory.poses), np.asarray(traj.poses), atol=1e-9)
    assert float(run.arrival[0]) == float(metrics.arrival_time(traj, ref, dt=DT))


def test_pass_through_is_faster_than_stopping():
    wp = soccer_waypoints()
    stop = chain_rollout(wp, controller="aicardi", steps=450)
    through = chain_rollout(
        wp, controller="aicardi", steps=450, pass_tol_r=5.0, pass_tol_theta=math.pi / 2
    )
    assert np.isfinite(np.asarray(through.arrival)).all()
    assert float(through.arrival[-1]) < float(stop.arrival[-1])
    assert np.all(np.asarray(through.arrival[:-1]) <= np.asarray(stop.arrival[:-1]))


def test_batched_chain_rows_equal_single_chains():
    wp = soccer_waypoints()[:3]
    inits = np.array([[0.0, 0.0, 0.0], [-10.0, 5.0, 1.0], [10.0, -5.0, -2.0]])
    batch = batch_chain_rollout(wp, init=inits, controller="aicardi", steps=300)
    assert batch.arrival.shape == (3, 3) and batch.trajectory.poses.shape == (3, 301, 3)
    for i in (0, 2):
        one = chain_rollout(wp, init=inits[i], controller="aicardi", steps=300)
        # vmap may fuse differently from the unbatched program: a few ulps.
        np.testing.assert_allclose(
            np.asarray(batch.trajectory.poses[i]), np.asarray(one.trajectory.poses), atol=1e-9
        )
        np.testing.assert_array_equal(np.asarray(batch.arrival[i]), np.asarray(one.arrival))


def test_constant_moving_reference_is_a_rollout():
    ref = np.array([-25.0, 35.0, -1.0])
    run = track_rollout(np.tile(ref, (120, 1)), controller="astolfi-corke")
    traj = w.rollout(ref, steps=120, controller="astolfi-corke")
    np.testing.assert_allclose(np.asarray(run.trajectory.poses), np.asarray(traj.poses), atol=1e-9)
    assert float(run.arrival) == float(metrics.arrival_time(traj, ref, dt=DT))
    assert run.error.shape == (120,)


def test_moving_reference_batched():
    t = np.arange(150) * DT
    # A reference gliding along x at 10 cm/s, and one standing still.
    gliding = np.stack([20 + 10 * t, np.full_like(t, 10.0), np.zeros_like(t)], axis=-1)
    still = np.tile([30.0, -10.0, 0.5], (150, 1))
    refs = np.stack([gliding, still])
    batch = batch_track_rollout(refs, controller="shim-sung")
    assert batch.error.shape == (2, 150) and batch.arrival.shape == (2,)
    for i in range(2):
        one = track_rollout(refs[i], controller="shim-sung")
        np.testing.assert_allclose(np.asarray(batch.error[i]), np.asarray(one.error), atol=1e-9)
    # The robot catches the gliding reference and follows it closely.
    assert float(np.max(batch.error[0, -30:])) < 3.0
    assert np.isfinite(float(batch.arrival[1]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"waypoints": np.zeros((3, 2))}, "waypoints has shape (3, 2)"),
        ({"waypoints": [[1.0, np.inf, 0.0]]}, "waypoints has a non-finite value"),
        ({"pass_tol_theta": 2.0}, "pass_tol_theta = 2.0"),
        ({"tol_theta": math.pi / 2}, "tol_theta"),
        ({"tol_r": 0.0}, "tol_r = 0.0"),
        ({"controller": "nope"}, "controller = 'nope'"),
        ({"params": baselines.AicardiGains(k=0.0), "controller": "aicardi"}, "gains.k = 0.0"),
    ],
)
def test_bad_inputs_raise_before_tracing(kwargs, message):
    kwargs = {"waypoints": soccer_waypoints(), **kwargs}
    with pytest.raises(ValueError) as info:
        chain_rollout(kwargs.pop("waypoints"), steps=5, **kwargs)
    assert message in str(info.value)


def test_demo_writes_figure_and_tables(tmp_path):
    rows = waypoints.soccer_demo(tmp_path, controller_names=["shim-sung", "aicardi"], steps=400)
    assert len(rows) == 4 and {r["mode"] for r in rows} == {"stop", "pass"}
    assert all(f"leg {i + 1} s" in rows[0] for i in range(len(soccer_waypoints())))
    for name in ("soccer.png", "soccer.md", "soccer.json"):
        assert (tmp_path / name).stat().st_size > 100
    assert not list(tmp_path.glob(".*tmp"))  # no temporary files left behind


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--controller", "nope"], "--controller = 'nope'"),
        (["--velocity", "warp"], "--velocity = 'warp'"),
        (["--pass-tol-deg", "120"], "--pass-tol-deg = 120.0"),
        (["--steps", "0"], "--steps = 0"),
    ],
)
def test_cli_bad_values(tmp_path, argv, message):
    parser = argparse.ArgumentParser()
    waypoints.configure_parser(parser)
    args = parser.parse_args(["--out", str(tmp_path), *argv])
    with pytest.raises(ValueError) as info:
        args.func(args)
    assert message in str(info.value) and "allowed" in str(info.value)
    assert "\n" not in str(info.value)
