"""tuned_gains.json of either kind: load_tuned, simulate --gains, refused checkpoints."""

import json

import jax
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax.cli import main


def _schedule() -> tuning.ScheduleParams:
    k = len(tuning.knot_radii())
    return tuning.ScheduleParams(
        kr=tuple(np.linspace(70.0, 125.0, k)),
        k_theta=tuple(np.linspace(30.0, 12.0, k)),
        k_turn=(40.0,) * k,
        phi_m=1.3,
        r_m=2.5,
        r_a=2.3,
        r_e=0.3,
        alpha=0.4,
    )


def test_a_schedule_round_trips_through_tuned_gains_json(tmp_path, capsys):
    params = _schedule()
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps(tuning.tuned_json(params)))
    controller, loaded, *_ = tuning.load_tuned(path)
    assert controller is tuning.SCHEDULE and loaded == params
    refs = random_refs(1, 16)
    np.testing.assert_array_equal(
        np.asarray(w.final_poses(refs, loaded, controller=controller)),
        np.asarray(w.batch_rollout(refs, params, controller=tuning.SCHEDULE).poses[:, -1]),
    )
    assert main(["simulate", "--ref", "30", "20", "45", "--gains", str(path)]) == 0
    assert "arrival time" in capsys.readouterr().out


def test_fixed_gains_old_and_new_files_load(tmp_path):
    gains = w.Gains(kr=80.0, k_theta=15.0, alpha=0.4)
    new, old = tmp_path / "new.json", tmp_path / "old.json"
    new.write_text(json.dumps(tuning.tuned_json(gains)))
    old.write_text(json.dumps({"kr": 80.0, "k_theta": 15.0, "alpha": 0.4}))
    assert json.loads(new.read_text())["kind"] == "fixed"
    for path in (new, old):
        controller, loaded, *_ = tuning.load_tuned(path)
        assert controller.name == "shim-sung" and loaded == gains
        w.rollout([20.0, 5.0, 0.0], loaded, controller=controller)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"kind": "schedule", "kr": [1, 2]}', "missing"),
        ('{"kind": "warp"}', "kind 'warp' is not allowed"),
        ('{"kr": [60, 60]}', "kr = \\[60, 60\\] is not allowed"),
        ('{"kr": 60, "speed": 3}', "key 'speed' is not allowed"),
        ("[1, 2]", "a JSON object"),
        ("{", "cannot be read"),
        ('{"kr": 1' + "0" * 400 + "}", "kr = 10* is not allowed; allowed: a number"),
        ('{"kind": [1]}', "kind = \\[1\\] is not allowed; allowed: a string"),
        ('{"kr": true}', "kr = True is not allowed"),
        # The last of a repeated key won without a word.
        ('{"kr": 60, "kr": 70}', "cannot be read: the key 'kr' is given twice"),
        ("[" * 100_000 + "]" * 100_000, "cannot be read: maximum recursion depth"),
        # The problem that tuned them, if said, is one the commands know.
        ('{"kr": 60, "tuning": "fast"}', "tuning = 'fast' is not allowed; allowed: 'nominal' or"),
        ('{"kr": 60, "tuning": ["robust"]}', "tuning = \\['robust'\\] is not allowed"),
        # Not the law's defaults (k_r = 120) from a file with no gains in it.
        ("{}", "holds no gains \\(its keys: none\\); allowed: a tuned_gains.json"),
        ('{"kind": "fixed", "controller": "shim-sung"}', "holds no gains \\(its keys: 'kind', "),
        # Another of the tuner's files, named as such.
        (
            '{"config": {}, "rows": {}, "feasible": true, "poses": 3}',
            "holds no gains \\(its keys: 'config', 'rows', 'feasible', ...\\); allowed: a "
            "tuned_gains.json, as wmr-jax tune writes beside evaluation.json",
        ),
    ],
)
def test_bad_files_are_refused_in_one_line(tmp_path, content, message):
    path = tmp_path / "tuned_gains.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as err:
        tuning.load_tuned(path)
    assert "\n" not in str(err.value)
    assert str(err.value).startswith(f"{str(path)!r}"), "the message names the file first"


def test_a_missing_file_or_a_folder_is_said_in_words(tmp_path):
    missing = r"'[^']*nope\.json' cannot be read: there is no such file$"
    with pytest.raises(ValueError, match=missing):
        tuning.load_tuned(tmp_path / "nope.json")
    with pytest.raises(ValueError, match=r"cannot be read: it is a folder$"):
        tuning.load_tuned(tmp_path)


def test_non_finite_parameters_are_never_written():
    with pytest.raises(ValueError, match="gains.kr = nan is not allowed; allowed: a finite"):
        tuning.tuned_json(w.Gains(kr=float("nan")))
    with pytest.raises(ValueError, match=r"params.k_turn\[3\] = inf is not allowed"):
        tuning.tuned_json(tuning.ScheduleParams(k_turn=(10.0,) * 3 + (np.inf,) + (10.0,) * 6))


def test_a_checkpoint_with_nan_or_wrong_lengths_is_refused():
    config = tuning.TuneConfig(iters=3, poses=4)
    fresh = tuning.init_state(config)
    good = tuning.state_arrays(fresh)
    assert tuning.restore_state(good, fresh).iteration == 0
    with pytest.raises(ValueError, match="non-finite"):
        tuning.restore_state({**good, "z": np.full_like(good["z"], np.nan)}, fresh)
    with pytest.raises(ValueError, match="inconsistent"):
        tuning.restore_state({**good, "iteration": np.asarray(2)}, fresh)
    # Arguments swapped or missing: named, not an AttributeError.
    allowed = "is not allowed; allowed: a TrainState (init_state, or one handed to progress_fn)"
    for call, named in (
        (lambda: tuning.state_arrays(None), "state = None"),
        (lambda: tuning.state_arrays(good), "state = {'iteration'"),
        (lambda: tuning.restore_state(good, config), "fresh = TuneConfig("),
    ):
        with pytest.raises(ValueError) as info:
            call()
        assert str(info.value).startswith(named) and str(info.value).endswith(allowed)


def test_a_fixed_gain_file_written_by_tune_must_be_whole(tmp_path):
    """Without its k_r it loaded the paper's 120 cm/s, beyond the wheels, without a word."""
    path = tmp_path / "tuned_gains.json"
    for recorded in ({"tuning": "nominal"}, {}):  # with or without the tuning it records
        values = tuning.tuned_json(w.Gains(kr=80.0, k_theta=15.0), **recorded)
        assert "units" in values
        del values["kr"]
        path.write_text(json.dumps(values))
        with pytest.raises(ValueError, match=r"the field 'kr' is missing \(a file that records"):
            tuning.load_tuned(path)
    # Its estimator too (without its σ_xy, the default 0.5 cm was tuned with).
    loop = w.studies.ObserverParams(position=0.3, heading=0.4)
    values = tuning.tuned_json(tuning.ScheduleParams(), estimator=w.studies.EKFParams(sigma_xy=0.2))
    del values["estimator"]["sigma_xy"]
    path.write_text(json.dumps(values))
    with pytest.raises(ValueError, match=r"the estimator field 'sigma_xy' is missing"):
        tuning.load_tuned(path)
    values = tuning.tuned_json(tuning.ScheduleParams(), estimator=loop)
    del values["estimator"]["compensate"]  # as written before it existed: it was on
    path.write_text(json.dumps(values))
    assert tuning.load_tuned(path).estimator == loop
    # The tuning it records says as much as its units.
    values = tuning.tuned_json(w.Gains(kr=80.0), tuning="robust")
    del values["units"], values["phi_m"]
    path.write_text(json.dumps(values))
    with pytest.raises(ValueError, match=r"the field 'phi_m' is missing \(a file that records"):
        tuning.load_tuned(path)
    # A hand-written file of Gains fields only may leave fields out, its estimator's too.
    path.write_text('{"k_theta": 15.0, "estimator": {"kind": "ekf", "sigma_xy": 0.2}}')
    loop = tuning.load_tuned(path)
    assert loop.params == w.Gains(k_theta=15.0) and loop.estimator == w.studies.EKFParams(
        sigma_xy=0.2
    )


def test_an_estimator_number_no_float_holds_is_refused_in_one_line(tmp_path):
    path = tmp_path / "tuned_gains.json"
    path.write_text('{"kr": 60, "estimator": {"kind": "ekf", "sigma_xy": 1' + "0" * 400 + "}}")
    with pytest.raises(ValueError, match=r"estimator sigma_xy = 10+ is not allowed; allowed: a "):
        tuning.load_tuned(path)


def test_a_schedule_file_must_be_whole_and_integers_load_as_floats(tmp_path):
    schedule = tuning.tuned_json(tuning.ScheduleParams())
    del schedule["phi_m"]
    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps(schedule))
    with pytest.raises(ValueError, match="the field 'phi_m' is missing$"):
        tuning.load_tuned(path)
    # JSON integers become floats, so the loaded gains can be differentiated.
    path.write_text('{"kr": 60, "k_theta": 10}')
    controller, gains, *_ = tuning.load_tuned(path)
    grad = jax.grad(lambda g: w.rollout([30.0, 30.0, 0.0], g, steps=5).poses[-1, 0])(gains)
    assert np.isfinite(float(grad.kr)) and float(grad.kr) != 0.0


def test_only_what_load_tuned_reads_back_is_written():
    """tuned_json refuses what load_tuned would refuse, by name, before writing."""
    schedule = tuning.ScheduleParams
    for params, message in (
        (schedule(kr=(60.0, 60.0)), r"the tables have \[2, 10\] knots"),
        (w.Gains(kr=-1.0), r"gains.kr = -1.0 is not allowed"),
        (w.Gains(kr=np.array([60.0, 70.0])), r"params.kr has shape \(2,\); allowed: one"),
        ("gains.json", "params is a str; allowed: a wmr_jax.Gains or"),
        (None, "params is a NoneType"),
    ):
        with pytest.raises(ValueError, match=message):
            tuning.tuned_json(params)


def test_a_file_says_which_problem_tuned_it(tmp_path):
    """The commands record it; a file of a user's own says nothing unless asked to."""
    gains, robot = w.Gains(kr=80.0, k_theta=15.0), w.Robot(half_track=4.0, v_max=90.0)
    for tuning_name in ("nominal", "robust", None):
        path = tmp_path / f"{tuning_name}.json"
        path.write_text(json.dumps(tuning.tuned_json(gains, robot=robot, tuning=tuning_name)))
        assert tuning.tuning_of(path) == tuning_name
        assert ("tuning" in json.loads(path.read_text())) == (tuning_name is not None)
        assert tuning.load_tuned(path).params == gains
    with pytest.raises(ValueError, match="tuning = 'Robust' is not allowed; allowed: 'nominal'"):
        tuning.tuned_json(gains, tuning="Robust")
    # The commands' files: tests/test_tuning_train.py and test_tuning_robust.py.


def test_a_null_or_missing_kind_is_named(tmp_path):
    path = tmp_path / "tuned_gains.json"
    path.write_text('{"kind": null, "controller": null, "kr": 50}')
    with pytest.raises(ValueError, match="kind = None is not allowed; allowed: a string"):
        tuning.load_tuned(path)
    values = tuning.tuned_json(tuning.ScheduleParams())
    del values["kind"], values["controller"]
    path.write_text(json.dumps(values))
    with pytest.raises(ValueError, match="is a schedule's, but the file names no kind"):
        tuning.load_tuned(path)
