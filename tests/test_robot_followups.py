"""A robot's acceleration limits wherever its ideal loop runs (docs/model.md §4.2.2).

The rollouts and sweeps turn the speed limiter on for a robot that gives
acceleration limits (``loops.for_robot``); so do the tuning loss, the
disturbed loop (and the studies built on it) and the waypoint loops. A robot
whose turn may gain only ``SLOW_TURN`` rad/s per second arrives later on
each of them than the same robot without it, and the paper robot, which has
none, runs as before. Also: tuning checkpoints of robots without limits
keep the identity they had before limits existed.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.provenance import code_version
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.sensing import loop as sensed
from wmr_jax._src.sim.sensing.disturbances import Disturbance, draw_disturbances
from wmr_jax._src.studies import waypoints
from wmr_jax._src.studies.conditions import evaluate_loop
from wmr_jax._src.tuning import trainer, training

# The paper's feasible gains turn at up to 10 rad/s: at 30 rad/s² the turn
# takes a third of a second to build up, against one sample without a limit.
SLOW_TURN = 30.0
LIMITED = w.Robot(angular_accel_max=SLOW_TURN)
GAINS = tuning.PAPER_FEASIBLE_GAINS
REFS = np.array([[30.0, 20.0, 0.5], [-20.0, 25.0, 2.0], [40.0, -10.0, -1.0]])


def test_the_tuning_loss_runs_the_robots_speed_limiter():
    arrival = {}
    for name, robot in (("free", w.Robot()), ("limited", LIMITED)):
        terms = tuning.loss_terms(GAINS, REFS, temperature=None, robot=robot, horizon=2.0)
        arrival[name] = np.asarray(terms.arrival)
    assert np.all(arrival["limited"] > arrival["free"] + 0.03), arrival
    # The spec is fitted to the robot before tracing; the paper robot's is unchanged.
    spec = training.TuneConfig().spec()
    assert spec.for_robot(w.Robot(), 0.033) == spec and not spec.accel_limit
    assert spec.for_robot(LIMITED, 0.033).accel_limit


def test_the_tuner_iterates_on_the_limited_loop(monkeypatch):
    # What the training step is compiled with, without compiling it.
    seen = []

    def step(z, opt_state, refs, temperature, consts, *, loss, hyper):
        seen.append(loss.spec.accel_limit)
        return z, opt_state, jnp.zeros(())

    monkeypatch.setattr(trainer, "train_step", step)
    config = training.TuneConfig(iters=1, poses=2)
    for robot in (w.Robot(), LIMITED):
        problem = training.gain_problem(config, robot)
        trainer.iterate(problem, trainer.start_state(problem), None)
    assert seen == [False, True]


# 2 s: the runs of the studies' test below (one compiled loop serves both).
HORIZON_S = 2.0
STEPS = 61


def _disturbance(n=3, steps=STEPS, latency=0.0):
    refs, _, mismatch = draw_disturbances(jax.random.key(3), n, steps, radius_mismatch=0.03)
    return Disturbance(refs, np.zeros((n, steps, 3)), mismatch, np.float64(latency))


# Raw feedback, and the EKF under latency (its compensation rolls the estimate
# over the command in flight as the limiter will let it through).
@pytest.mark.parametrize(("estimator", "latency"), [(None, 0.0), ("ekf", 1.0)])
def test_the_disturbed_loop_runs_the_robots_speed_limiter(estimator, latency):
    spec = _disturbance(latency=latency)  # the wheels' radii off by up to 3 %
    arrival = {}
    for name, robot in (("free", w.Robot()), ("limited", LIMITED)):
        m = sensed.disturbed_metrics(spec, GAINS, robot=robot, estimator=estimator, x64=False)
        assert np.all(m.success), name
        arrival[name] = m.arrival
    assert np.mean(arrival["limited"]) > np.mean(arrival["free"]) + 0.05, arrival
    # Only the ideal loop of a robot with limits has the limiter.
    for robot, limited in ((w.Robot(), False), (LIMITED, True)):
        args = (spec, GAINS, w.controllers.SHIM_SUNG, estimator, (0.0, 0.0, 0.0), 0.033, robot)
        assert sensed.prepare_disturbed(*args, "ideal")[1].accel_limit is limited
        assert not sensed.prepare_disturbed(*args, "nonideal")[1].accel_limit


def test_an_undisturbed_run_is_the_limited_rollout():
    # With no noise, mismatch or latency the disturbed loop is the rollout,
    # its speed limiter included (the estimator predicts what it lets through).
    refs = REFS
    spec = Disturbance(refs, np.zeros((3, 60, 3)), np.ones((3, 3)), np.float64(0.0))
    with jax.enable_x64(True):
        rollout = np.asarray(w.batch_rollout(refs, GAINS, robot=LIMITED, steps=60).poses)
        for estimator in (None, "ekf"):
            run = sensed.disturbed_rollout(spec, GAINS, robot=LIMITED, estimator=estimator)
            np.testing.assert_array_equal(run["poses"], rollout)


def test_the_studies_run_the_robots_speed_limiter():
    arrival = {}
    for name, robot in (("free", w.Robot()), ("limited", LIMITED)):
        result = evaluate_loop(GAINS, REFS, robot=robot, horizon=HORIZON_S, mismatch=0.0, x64=False)
        assert result["success"] == 1.0, name
        arrival[name] = result["mean_arrival_s"]
    assert arrival["limited"] > arrival["free"] + 0.05, arrival


def test_the_waypoint_loops_run_the_robots_speed_limiter():
    chain = np.array([[30.0, 10.0, 0.0], [50.0, 40.0, 1.5]])
    arrival = {}
    for name, robot in (("free", w.Robot()), ("limited", LIMITED)):
        run = waypoints.chain_rollout(chain, GAINS, robot=robot, steps=120)
        arrival[name] = np.asarray(run.arrival)
        assert np.all(np.isfinite(arrival[name])), name
    assert np.all(arrival["limited"] > arrival["free"]), arrival
    # A moving reference too. The limiter's state is the state's velocity, from
    # rest: the first turn is cut to one period's worth.
    refs = np.tile(REFS[0], (60, 1))
    traj = waypoints.track_rollout(refs, GAINS, robot=LIMITED).trajectory
    assert abs(float(traj.omega[0])) > 2 * SLOW_TURN * 0.033  # what the law asked for
    rims = np.asarray(traj.wheel_speeds[0])
    turn = (rims[1] - rims[0]) / (2 * float(LIMITED.half_track))
    assert abs(turn) <= SLOW_TURN * 0.033 * (1 + 1e-5)
    assert loops.for_robot(loops.Options(), w.Robot(), 0.033).accel_limit is False


def test_a_checkpoints_identity_holds_every_robot_field():
    config = training.TuneConfig()
    now = tuning.run_identity(config, w.Robot())
    # Every robot field, the settings and the code that computes (provenance.code_version);
    # how often the run checkpoints is no setting of its result.
    fields = list(w.Robot.__dataclass_fields__)
    # The horizon it runs: the robot's (the paper robot's 6 s) where the settings leave it.
    run = config.for_robot(w.Robot()).as_dict()
    assert config.horizon is None and run["horizon"] == 6.0
    settings = {k: v for k, v in run.items() if k != "checkpoint_every"}
    assert len(settings) == len(config.as_dict()) - 1
    expected = {
        "config": settings,
        "robot": {f: float(getattr(w.Robot(), f)) for f in fields},
        "code": code_version(),
    }
    assert now == json.loads(json.dumps(expected))
    resolved = config.for_robot(w.Robot())
    assert trainer.run_text(resolved, w.Robot()) == json.dumps(expected, sort_keys=True)
    # A robot with a limit is another run; the limit it gives is in its identity.
    limited = tuning.run_identity(config, LIMITED)
    assert limited != now and limited["robot"]["angular_accel_max"] == SLOW_TURN
    state = training.init_state(config, w.Robot())
    with pytest.raises(ValueError, match="state is of another run"):
        run = trainer.run_text(config.for_robot(LIMITED), LIMITED)
        trainer.own_state(state, training.gain_problem(config, LIMITED), run)
    run = trainer.run_text(resolved, w.Robot())
    assert trainer.own_state(state, training.gain_problem(config, w.Robot()), run) is state


def test_tune_runs_a_slow_robot_for_the_horizon_its_wheels_need(tmp_path, capsys, monkeypatch):
    """Without --horizon, tune stretches the 6 s as the studies do, and says so."""
    from wmr_jax._src.tuning import run as tune_run
    from wmr_jax.cli import main

    seen = {}

    def fake_tune(out, config, *, robot=None, resume=False):
        seen["horizon"] = config.horizon
        raise KeyboardInterrupt  # stop before any work: the config is what is checked

    monkeypatch.setattr(tune_run, "tune", fake_tune)
    robot = tmp_path / "slow.json"
    robot.write_text('{"half_track": 8.0, "v_max": 22.0}')
    argv = ["tune", "--out", str(tmp_path / "t"), "--robot", str(robot), "--iters", "1"]
    main(argv)
    # (60 + 10 * 8) / 22 = 6.36 times the paper robot's 6 s, rounded up to 0.1 s.
    assert seen["horizon"] == pytest.approx(38.2)
    assert "horizon 38.2 s for this robot" in capsys.readouterr().out
    main([*argv, "--horizon", "12"])
    assert seen["horizon"] == 12.0


def test_tune_compare_runs_a_slow_robot_for_the_horizon_its_wheels_need(
    tmp_path, capsys, monkeypatch
):
    """--compare tunes each problem over the robot's horizon too, said once."""
    from wmr_jax._src.tuning import compare as compare_module
    from wmr_jax.cli import main

    seen = {}

    def fake_compare(*, seeds, problems, configs, progress, robot=None):
        seen.update({name: config.horizon for name, config in configs.items()})
        raise KeyboardInterrupt  # stop before any work: the configs are what is checked

    monkeypatch.setattr(compare_module, "compare", fake_compare)
    robot = tmp_path / "slow.json"
    robot.write_text('{"half_track": 8.0, "v_max": 22.0}')
    argv = ["tune", "--compare", "--out", str(tmp_path / "c"), "--robot", str(robot)]
    assert main(argv) == 130
    assert seen == {"fixed": pytest.approx(38.2)}  # the first problem, then stopped
    assert capsys.readouterr().out.count("horizon 38.2 s for this robot") == 1
    seen.clear()
    assert main([*argv, "--horizon", "12"]) == 130
    assert seen == {"fixed": 12.0}


def test_the_python_tuner_and_pose_maps_run_a_slow_robot_over_its_horizon(monkeypatch):
    """train and evaluate_poses default to the robot's study horizon, as the commands,
    tune_robust and tuning.evaluate do: 6 s left a 22 cm/s robot's runs unfinished."""
    from wmr_jax._src.studies import maps
    from wmr_jax._src.studies.robustness import study_horizon

    slow = w.Robot(half_track=8.0, v_max=22.0)
    assert study_horizon(slow) == 38.2 and study_horizon(w.Robot()) == 6.0
    config = training.TuneConfig(iters=1, poses=2)
    assert config.horizon is None
    assert training._checked(config, slow)[0].horizon == 38.2
    assert training._checked(config, None)[0].horizon == 6.0
    assert training._checked(config.replace(horizon=10.0), slow)[0].horizon == 10.0
    assert training.gain_problem(config, slow).loss.spec == config.replace(
        horizon=38.2
    ).spec().for_robot(slow, 0.033)
    # The searches take the same run options, a horizon of None included.
    from wmr_jax._src.tuning.evaluation import check_run

    assert check_run({**config.hard_run, "robot": slow})["horizon"] == 38.2
    searched = tuning.random_search(
        jax.random.key(1), np.array([[30.0, 0.0, 0.0]]), budget_s=0.0, chunk=2, **config.hard_run
    )
    assert searched.candidates == 2 and np.isfinite(searched.score)
    seen = []
    monkeypatch.setattr(maps, "sweep", lambda *a, steps, **k: seen.append(steps) or 1 / 0)
    for robot, steps in ((slow, math.ceil(38.2 / 0.033)), (None, math.ceil(6.0 / 0.033))):
        with pytest.raises(ZeroDivisionError):
            maps.evaluate_poses(np.zeros((1, 3)) + [30.0, 0.0, 0.0], robot=robot)
        assert seen.pop() == steps
