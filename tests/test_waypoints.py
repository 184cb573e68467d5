"""Consecutive motions: waypoint chains and moving references."""

import json
import math

import numpy as np
import pytest
from conftest import run_metrics

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.studies import waypoints
from wmr_jax.cli import main

DT = 0.033
# Every run here lasts STEPS periods (the command's default), so that the
# compiled chains, tracks and rollouts are shared between the tests.
STEPS = 450
WP = studies.soccer_waypoints()


def chain(controller="shim-sung", **kwargs):
    return studies.chain_rollout(WP, controller=controller, steps=STEPS, **kwargs)


def switch_samples(run):
    """The sample at which each waypoint counted as reached (its arrival, in periods)."""
    return [round(t / DT) for t in np.asarray(run.arrival)]


@pytest.mark.parametrize("controller", ["shim-sung", "astolfi-corke"])
def test_chain_visits_the_waypoints_in_order(controller):
    run = chain(controller)
    arrival = np.asarray(run.arrival)
    assert np.isfinite(arrival).all() and np.all(np.diff(arrival) > 0)
    leg = np.asarray(run.leg)
    assert leg[0] == 0 and np.all(np.diff(leg) >= 0) and set(leg) == set(range(len(WP)))
    poses = np.asarray(run.trajectory.poses)
    for i, k in enumerate(switch_samples(run)):
        if i < len(WP) - 1:
            assert np.all(leg[k:] >= i + 1)
        assert bool(w.studies.arrived(poses[k], WP[i]))
        # Before it, the robot was still heading for this or an earlier waypoint.
        assert leg[k - 1] <= i


def test_each_leg_is_a_rollout_from_where_the_last_one_ended():
    run = chain()
    poses = np.asarray(run.trajectory.poses)
    start = 0
    for i, k in enumerate(switch_samples(run)[:-1]):
        traj = w.rollout(WP[i], init=poses[start], steps=STEPS)
        # The same closed loop by two arrangements of the same arithmetic.
        leg = np.asarray(traj.poses[: k - start + 1])
        np.testing.assert_allclose(poses[start : k + 1], leg, atol=1e-9)
        start = k
    last = w.rollout(WP[-1], init=poses[start], steps=STEPS)
    settled = float(run_metrics(last, WP[-1], DT)["arrival"])
    assert float(run.arrival[-1]) == pytest.approx(start * DT + settled, abs=1e-9)


def test_pass_through_is_faster_than_stopping():
    stop = chain()
    through = chain(pass_tol_r=5.0, pass_tol_theta=math.pi / 2)
    assert np.isfinite(np.asarray(through.arrival)).all()
    assert float(through.arrival[-1]) < float(stop.arrival[-1])
    assert np.all(np.asarray(through.arrival[:-1]) <= np.asarray(stop.arrival[:-1]))


def test_batched_chain_rows_equal_single_chains():
    inits = np.array([[0.0, 0.0, 0.0], [-10.0, 5.0, 1.0], [10.0, -5.0, -2.0]])
    batch = studies.batch_chain_rollout(WP, init=inits, steps=STEPS)
    assert batch.arrival.shape == (3, len(WP)) and batch.trajectory.poses.shape == (3, 451, 3)
    for i in (0, 2):
        one = chain(init=inits[i])
        # vmap may fuse differently from the unbatched program: a few ulps.
        np.testing.assert_allclose(
            np.asarray(batch.trajectory.poses[i]), np.asarray(one.trajectory.poses), atol=1e-9
        )
        np.testing.assert_array_equal(np.asarray(batch.arrival[i]), np.asarray(one.arrival))


def test_constant_moving_reference_is_a_rollout():
    ref = WP[1]
    run = studies.track_rollout(np.tile(ref, (STEPS, 1)))
    traj = w.rollout(ref, init=np.zeros(3), steps=STEPS)
    np.testing.assert_allclose(np.asarray(run.trajectory.poses), np.asarray(traj.poses), atol=1e-9)
    assert float(run.arrival) == float(run_metrics(traj, ref, DT)["arrival"])
    assert run.error.shape == (STEPS,)


def test_moving_reference_batched():
    t = np.arange(STEPS) * DT
    # A reference gliding along x at 10 cm/s, and one standing still.
    gliding = np.stack([20 + 10 * t, np.full_like(t, 10.0), np.zeros_like(t)], axis=-1)
    still = np.tile([30.0, -10.0, 0.5], (STEPS, 1))
    refs = np.stack([gliding, still])
    batch = studies.batch_track_rollout(refs)
    assert batch.error.shape == (2, STEPS) and batch.arrival.shape == (2,)
    for i in range(2):
        one = studies.track_rollout(refs[i])
        np.testing.assert_allclose(np.asarray(batch.error[i]), np.asarray(one.error), atol=1e-9)
    # The robot catches the gliding reference and follows it closely.
    assert float(np.max(batch.error[0, -30:])) < 3.0
    assert np.isfinite(float(batch.arrival[1]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"waypoints": np.zeros((3, 2))}, "waypoints has shape (3, 2)"),
        ({"waypoints": [[1.0, np.inf, 0.0]]}, "waypoints[0] = [1.0, inf, 0.0] is not finite"),
        ({"pass_tol_theta": 2.0}, "pass_tol_theta = 2.0"),
        ({"tol_theta": math.pi / 2}, "tol_theta"),
        ({"tol_r": 0.0}, "tol_r = 0.0"),
        ({"controller": "nope"}, "controller = 'nope'"),
        ({"params": w.controllers.AicardiGains(k=0.0), "controller": "aicardi"}, "gains.k = 0.0"),
    ],
)
def test_bad_chain_inputs_raise_before_tracing(kwargs, message):
    kwargs = {"waypoints": WP, **kwargs}
    with pytest.raises(ValueError, match="allowed") as info:
        studies.chain_rollout(kwargs.pop("waypoints"), steps=5, **kwargs)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        pytest.param(
            lambda: studies.track_rollout(np.zeros((5, 3, 3))),
            "refs has shape (5, 3, 3)",
            id="track",
        ),
        pytest.param(
            lambda: studies.batch_track_rollout(np.zeros((5, 3))),
            "refs has shape (5, 3)",
            id="batch",
        ),
        pytest.param(
            lambda: studies.batch_chain_rollout(WP), "allowed: waypoints (N, K, 3)", id="no-batch"
        ),
        pytest.param(
            lambda: studies.batch_chain_rollout(WP, init=np.zeros((2, 4))),
            "init has shape",
            id="init",
        ),
        pytest.param(
            lambda: studies.batch_chain_rollout(np.zeros((2, 4, 3)), init=np.zeros((3, 3))),
            "init has 3 rows; allowed: 2",
            id="rows",
        ),
    ],
)
def test_bad_batch_and_track_inputs_raise(call, message):
    with pytest.raises(ValueError, match="allowed") as info:
        call()
    assert message in str(info.value)


def test_command_writes_the_soccer_tables(tmp_path, capsys):
    argv = ["waypoints", "--out", str(tmp_path), "--controller", "shim-sung", "astolfi-corke"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "| astolfi-corke | pass |" in printed and "hint" not in printed  # each chain finished
    for name in ("soccer.png", "soccer.md", "soccer.json"):
        assert (tmp_path / name).stat().st_size > 100
    assert not list(tmp_path.glob(".*tmp"))  # no temporary files left behind
    saved = json.loads((tmp_path / "soccer.json").read_text())
    rows, runs, *_ = studies.soccer_study(controller_names=["shim-sung", "astolfi-corke"])
    assert saved["rows"] == rows and [r.mode for r in runs] == ["stop", "pass"] * 2
    assert all(f"leg {i + 1} s" in rows[0] for i in range(len(WP)))
    assert rows[0]["leg 6 s"] == float(runs[0].run.arrival[-1])
    # Too few periods for the chain: its times are inf, and the command says what to change.
    argv = ["waypoints", "--out", str(tmp_path), "--controller", "shim-sung", "--steps", "5"]
    assert main(argv) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "hint: shim-sung (stop), shim-sung (pass) did not finish the chain within 5 control "
        "periods (0.165 s); more --steps give it time"
    )


# Values the command refuses, each with a one-line error and exit status 2.
REFUSED = [("--controller", "nope"), ("--velocity", "warp"), ("--pass-tol-deg", "120")]
REFUSED += [("--pass-tol", "-1"), ("--steps", "0"), ("--steps", "1.5")]


@pytest.mark.parametrize(("flag", "value"), REFUSED)
def test_command_rejects_bad_values_in_one_line(tmp_path, capsys, flag, value):
    assert main(["waypoints", "--out", str(tmp_path), flag, value]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"wmr-jax: error: {flag} '{value}' is not ")


def test_waypoints_never_reached_make_the_slowest_leg_infinite():
    # Ten periods reach no waypoint: every leg, and the slowest, is inf (not NaN).
    rows, *_ = studies.soccer_study(controller_names=["shim-sung"], steps=10)
    for row in rows:
        assert row["slowest leg s"] == math.inf and row[f"leg {len(WP)} s"] == math.inf


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"pass_tol_r": -1.0}, "pass_tol_r = -1.0 is not allowed"),
        ({"pass_tol_theta": 2.0}, "pass_tol_theta = 2.0 is not allowed"),
        ({"velocity": "warp"}, "velocity = 'warp' is not allowed"),
        ({"steps": 0}, "steps = 0 is not allowed"),
    ],
)
def test_the_soccer_study_checks_its_settings_before_running_anything(monkeypatch, kwargs, message):
    # Before, a bad pass tolerance surfaced only after the first controller's
    # whole "stop" run had compiled and run.
    def no_run(*args, **kwargs):
        raise AssertionError("a run started before the settings were checked")

    monkeypatch.setattr(waypoints, "chain_rollout", no_run)
    with pytest.raises(ValueError, match=message):
        studies.soccer_study(controller_names=["shim-sung"], **kwargs)


def test_batched_parameters_in_a_single_chain_point_to_the_batched_entry_point():
    with pytest.raises(ValueError, match=r"in chain_rollout \(one run\); use batch_chain_rollout"):
        studies.chain_rollout(WP[:2], w.Gains(kr=[60.0, 70.0]), steps=3)
    with pytest.raises(ValueError, match=r"robot.v_max .* use batch_track_rollout for a batch"):
        studies.track_rollout(np.zeros((3, 3)), robot=w.Robot(v_max=[125.0, 100.0]))


def test_chains_and_tracks_run_inside_a_callers_jit_and_grad():
    """Waypoints and references traced by a caller's jit (or grad) run as given."""
    import jax

    wp = np.array([[20.0, 0.0, 0.0], [30.0, 10.0, 1.0]])
    refs = np.stack([np.linspace(5.0, 20.0, 30), np.zeros(30), np.zeros(30)], axis=-1)
    eager = studies.chain_rollout(wp, steps=50).arrival
    traced = jax.jit(lambda x: studies.chain_rollout(x, steps=50).arrival)(wp)
    np.testing.assert_array_equal(traced, eager)
    error = studies.track_rollout(refs).error
    np.testing.assert_array_equal(jax.jit(lambda r: studies.track_rollout(r).error)(refs), error)
    grad = jax.grad(lambda r: studies.track_rollout(r).error.sum())(refs)
    assert grad.shape == refs.shape and np.isfinite(np.asarray(grad)).all()
