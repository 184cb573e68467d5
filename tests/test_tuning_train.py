"""Gain tuning end to end: the trainer's callback, ``wmr-jax tune``, checkpoints and resume."""

import json
import logging
import os

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.tuning import run as tuning_run
from wmr_jax.cli import main

# One small setting shared by every run here, so that they compile once:
# 8 poses, a 1 s horizon (31 steps), 8 held-out poses, no random search.
SMALL = tuning.TuneConfig(
    iters=6,
    poses=8,
    horizon=1.0,
    checkpoint_every=2,
    eval_poses=8,
    random_search=False,
)
# The same settings as flags of `wmr-jax tune`.
SMALL_FLAGS = [
    "--iters=6",
    "--poses=8",
    "--horizon=1",
    "--checkpoint-every=2",
    "--eval-poses=8",
    "--no-random-search",
]


class _Stop(Exception):
    pass


def _stop_after(iterations: int):
    def progress_fn(state):
        if state.iteration == iterations:
            raise _Stop

    return progress_fn


def test_train_reports_every_feasible_iterate_and_annealing_does_not_recompile(caplog):
    first = tuning.train(SMALL)  # compiles, if nothing before did
    # It descends: six steps lower the loss on poses it never trained on
    # (1.289 -> 1.229 s measured; gradient ascent would raise it).
    refs = w.sample_poses(99, 64)
    loss = {
        name: float(tuning.tuning_loss(g, refs, temperature=SMALL.temperature_end, horizon=1.0))
        for name, g in (("start", tuning.PAPER_FEASIBLE_GAINS), ("tuned", first.gains))
    }
    assert loss["tuned"] < 0.98 * loss["start"], loss
    seen = []
    caplog.set_level(logging.WARNING)
    with jax.log_compiles(True):
        result = tuning.train(SMALL.replace(temperature_end=0.02), progress_fn=seen.append)
    # The temperature is traced, not static: another schedule compiles nothing.
    assert not [r.message for r in caplog.records if "Compiling" in r.message]
    assert [state.iteration for state in seen] == list(range(1, SMALL.iters + 1))
    for state in seen:
        assert np.all(w.controllers.check_feasible(tuning.gains_from_logits(state.z)))
    np.testing.assert_array_equal(result.history["gains"], np.asarray(seen[-1].gains))
    assert result.history["temperature"][-1] == pytest.approx(0.02)
    assert set(result.evaluation) == {"paper_feasible", "tuned"} and result.search is None
    # One result type for every problem: the robust problem's outputs are absent here.
    assert result.problem == "fixed" and result.loop is result.rows is result.searches is None
    assert np.all(np.isfinite(result.history["loss"]))


def test_cli_writes_the_results_and_a_resumed_run_gives_the_same_gains(tmp_path, capsys):
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    # What judged other gains in this folder (here `tune --robust`'s) goes with them.
    whole.mkdir()
    for stale in ("robust_evaluation.md", "robust_evaluation.json", "robust_loss.json"):
        (whole / stale).write_text("{}")
    assert main(["tune", "--out", str(whole), *SMALL_FLAGS]) == 0
    assert not [p.name for p in whole.iterdir() if p.name.startswith("robust_")]
    printed = capsys.readouterr().out
    assert "| paper feasible | " in printed and "| tuned | " in printed
    saved = json.loads((whole / "tuned_gains.json").read_text())
    assert list(saved) == [
        "controller",
        "kind",
        *tuning.GAIN_FIELDS,
        "units",
        "tuning",
        "robot",
        "robot_units",
    ]
    assert tuning.tuning_of(whole / "tuned_gains.json") == saved["tuning"] == "nominal"
    controller, gains, *_ = tuning.load_tuned(whole / "tuned_gains.json")
    assert controller.name == saved["controller"] == "shim-sung"
    assert np.all(w.controllers.check_feasible(gains))
    # Every tuning report gives the ratio of each mean arrival to the §8 yardsticks.
    assert "vs turn–drive–turn" in printed and "| lower bound (§8) |" in printed
    report = json.loads((whole / "evaluation.json").read_text())
    assert set(report["rows"]) == {"paper_feasible", "tuned"}
    assert report["feasible"] is True and report["random_search_candidates"] is None
    assert (whole / "tuning_curve.png").stat().st_size > 0

    # A real interruption after 3 iterations: the checkpoint holds the first 2.
    with pytest.raises(_Stop):
        tuning.tune(cut, SMALL, progress=False, progress_fn=_stop_after(3))
    with np.load(cut / tuning.CHECKPOINT_NAME) as data:
        assert int(data["iteration"]) == 2
    assert not (cut / "tuned_gains.json").exists()
    capsys.readouterr()
    assert main(["tune", "--out", str(cut), *SMALL_FLAGS, "--resume"]) == 0
    said = f"--resume: continuing after iteration 2 of {cut / tuning.CHECKPOINT_NAME}\n"
    assert capsys.readouterr().out.startswith(said)
    # The same computation on the same inputs, restored bit for bit.
    assert (cut / "tuned_gains.json").read_bytes() == (whole / "tuned_gains.json").read_bytes()
    resumed = json.loads((cut / "evaluation.json").read_text())
    assert resumed["rows"] == report["rows"]
    # Its wall time counts a second session's compilation: the report says it was resumed.
    assert resumed["resumed_at_iteration"] == 2 and report["resumed_at_iteration"] is None
    # Resumed once more, the finished run is left as it is: nothing is tuned, searched or
    # judged again (a job resubmitted with --resume keeps its results).
    files = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in cut.iterdir()}
    capsys.readouterr()
    assert main(["tune", "--out", str(cut), *SMALL_FLAGS, "--resume"]) == 0
    assert capsys.readouterr().out == (
        f"--resume: {cut} holds this run finished (tuned_gains.json, evaluation.json); "
        "nothing to resume. Without --resume it tunes again from the start\n"
    )
    assert {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in cut.iterdir()} == files
    # One of its files judged by another run's settings: that run is resumed as before.
    (cut / "evaluation.json").write_text(json.dumps({**resumed, "config": {}}))
    assert not tuning_run.finished(cut, SMALL, None)
    assert tuning_run.finished(whole, SMALL, None)
    (whole / "tuned_gains.json").rename(whole / "kept.json")  # the gains gone: tuned again
    assert not tuning_run.finished(whole, SMALL, None)
    (whole / "kept.json").rename(whole / "tuned_gains.json")
    assert not tuning_run.finished(whole, SMALL.replace(iters=7), None)
    assert not tuning_run.finished(whole, SMALL, w.Robot(half_track=10.0))  # another robot's
    # An evaluation of another robot beside this run's checkpoint: not this run's result.
    report = (whole / "evaluation.json").read_text()
    other = {**json.loads(report), "robot": {**json.loads(report)["robot"], "half_track": 10.0}}
    (whole / "evaluation.json").write_text(json.dumps(other))
    assert not tuning_run.finished(whole, SMALL, None)
    (whole / "evaluation.json").write_text(report)
    assert tuning_run.finished(whole, SMALL, None)
    # A checkpoint of other code beside this run's evaluation: not finished either.
    from wmr_jax._src import io

    kept = (whole / tuning.CHECKPOINT_NAME).read_bytes()
    arrays, meta = io.load_arrays(whole / tuning.CHECKPOINT_NAME)
    meta["identity"]["code"] = "another version"
    io.save_arrays(whole / tuning.CHECKPOINT_NAME, arrays, meta)
    os.utime(whole / "evaluation.json")  # still written after the checkpoint
    assert not tuning_run.finished(whole, SMALL, None)
    (whole / tuning.CHECKPOINT_NAME).write_bytes(kept)
    os.utime(whole / "evaluation.json")
    assert tuning_run.finished(whole, SMALL, None)
    # A checkpoint newer than the evaluation: the run stopped after it, in its random
    # search or evaluation, so resuming it has work left.
    later = (whole / "evaluation.json").stat().st_mtime_ns + 10**9
    os.utime(whole / tuning.CHECKPOINT_NAME, ns=(later, later))
    assert not tuning_run.finished(whole, SMALL, None)


def test_resume_without_a_checkpoint_says_it_starts_over(tmp_path, capsys):
    # A mistyped --out: nothing to resume, and the user is told so.
    with pytest.raises(_Stop):
        tuning.tune(
            tmp_path / "typo", SMALL, resume=True, progress=False, progress_fn=_stop_after(1)
        )
    out = capsys.readouterr().out
    assert f"--resume: no checkpoint.npz in {tmp_path / 'typo'}; starting from the first" in out
    with pytest.raises(_Stop):  # without --resume a fresh start is what was asked
        tuning.tune(tmp_path / "new", SMALL, progress=False, progress_fn=_stop_after(1))
    assert "--resume" not in capsys.readouterr().out


def test_how_often_a_run_checkpoints_is_not_part_of_the_run(tmp_path):
    every = SMALL.replace(checkpoint_every=1)
    with pytest.raises(_Stop):
        tuning.tune(tmp_path, every, progress=False, progress_fn=_stop_after(2))
    tuning.tune(tmp_path, SMALL, progress=False, resume=True)  # every 2 iterations now
    assert tuning_run.finished(tmp_path, every.replace(checkpoint_every=5), None)
    assert not tuning_run.finished(tmp_path, every.replace(seed=1), None)


def test_resume_refuses_other_settings_and_damaged_checkpoints(tmp_path, capsys):
    every = SMALL.replace(checkpoint_every=1)
    with pytest.raises(_Stop):
        tuning.tune(tmp_path, every, progress=False, progress_fn=_stop_after(1))
    checkpoint = tmp_path / tuning.CHECKPOINT_NAME
    with pytest.raises(ValueError, match=r"\(poses = 8 there, 9 now\); allowed: the same"):
        tuning.tune(tmp_path, every.replace(poses=9), resume=True)
    # More iterations: another run, and why (the first iterations of a longer run differ).
    longer = r"\(iters = 6 there, 9 now\) \(the step size and the temperature anneal over all"
    with pytest.raises(ValueError, match=longer):
        tuning.tune(tmp_path, every.replace(iters=9), resume=True)

    # Truncated (a disk full, a copy cut short): one clean line, never a traceback.
    checkpoint.write_bytes(checkpoint.read_bytes()[:-100])
    stale = tmp_path / ".checkpoint.npz.x1y2.tmp"  # what a killed write leaves
    stale.write_bytes(b"partial")
    with pytest.raises(ValueError, match="damaged") as info:
        tuning.tune(tmp_path, every, resume=True)
    assert "\n" not in str(info.value) and "remove it" in str(info.value)
    assert not stale.exists()
    assert main(["tune", "--out", str(tmp_path), *SMALL_FLAGS, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("wmr-jax: error: --resume: checkpoint") and err.count("\n") == 1


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["--iters", "0"], "--iters"),
        (["--iters", "many"], "--iters"),
        (["--poses", "1.5"], "--poses"),
        (["--seed", "-3"], "--seed"),
        (["--velocity", "warp"], "--velocity"),
        (["--horizon", "0"], "--horizon"),
        (["--eval-poses", "0"], "--eval-poses"),
        (["--checkpoint-every", "x"], "--checkpoint-every"),
    ],
)
def test_bad_flags_give_one_line_errors(tmp_path, capsys, argv, flag):
    assert main(["tune", "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"wmr-jax: error: {flag} ") and "allowed" in err
    assert err.count("\n") == 1


def test_out_must_be_a_folder_and_help_shows_the_defaults(tmp_path, capsys):
    afile = tmp_path / "file"
    afile.write_text("")
    assert main(["tune", "--out", str(afile)]) == 2
    assert "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["tune", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    defaults = tuning.TuneConfig()
    for flag, value in [
        ("--iters", defaults.iters),
        ("--poses", defaults.poses),
        ("--seed", defaults.seed),
        ("--velocity", defaults.velocity),
        ("--horizon", "the robot's study horizon, 6 on the paper robot"),
        ("--eval-poses", defaults.eval_poses),
    ]:
        shown = f"(default: {value})"
        if flag in ("--iters", "--poses"):  # the other modes' own defaults beside
            name = flag.lstrip("-")
            scheduled = getattr(tuning.TuneConfig.for_problem("schedule"), name)
            robust = getattr(tuning.RobustConfig(), name)
            shown = f"(default: {value}, {scheduled} with --schedule, {robust} with --robust)"
        assert flag in text and shown in text, flag


def test_each_problem_has_its_own_recommended_settings():
    fixed, schedule = tuning.TuneConfig.for_problem(), tuning.TuneConfig.for_problem("schedule")
    assert fixed == tuning.TuneConfig() and fixed.problem == "fixed"
    assert schedule.problem == "schedule" and schedule.space.name == "schedule"
    # More, longer steps and a colder end for 35 parameters than for 7.
    assert schedule.iters > fixed.iters and schedule.learning_rate > fixed.learning_rate
    assert schedule.temperature_end < fixed.temperature_end
    schedule.validate()
    assert tuning.TuneConfig.for_problem("schedule", iters=5, seed=3).iters == 5
    with pytest.raises(ValueError, match=r"problem = 'sched'.*'fixed', 'schedule'"):
        tuning.TuneConfig.for_problem("sched")


def test_a_schedule_of_any_size_is_a_problem_of_its_own():
    """knots sizes the tables: 3K + 5 parameters, and a file of K knots that loads back."""
    for knots in (2, 4, 30):
        problem = tuning.schedule_problem(knots)
        assert problem is tuning.schedule_problem(knots)  # one static value per size
        assert problem.dim == 3 * knots + 5 and len(problem.columns) == 3 * knots + 7
        params = problem.from_unit(np.full(problem.dim, 0.3), w.Robot())
        assert len(params.kr) == len(params.k_turn) == knots
        again = problem.from_row(problem.row(params))
        assert problem.row(again) == problem.row(params)
        start = problem.start(w.Robot())
        assert start.shape == (problem.dim,) and np.all((start > 0) & (start < 1))
    assert tuning.schedule_problem() is tuning.SCHEDULED and tuning.SCHEDULED.dim == 35
    for knots in (1, 61, True, 2.5):
        with pytest.raises(ValueError, match=f"knots = {knots!r} is not allowed"):
            tuning.schedule_problem(knots)


def test_tuning_a_schedule_of_four_knots(tmp_path):
    config = tuning.TuneConfig.for_problem("schedule", knots=4, **_small_settings())
    assert config.space is tuning.schedule_problem(4)
    result = tuning.tune(tmp_path, config, progress=False)
    assert len(result.gains.kr) == 4 and result.history["gains"].shape == (SMALL.iters, 19)
    controller, params, *_ = w.load_tuned(tmp_path / "tuned_gains.json")
    assert controller.name == "shim-sung-schedule" and len(params.k_theta) == 4
    assert (tmp_path / "tuning_curve.png").stat().st_size > 1000
    # Its size is part of the run: a checkpoint of 4 knots does not resume 5.
    with pytest.raises(ValueError, match="knots = 4 there, 5 now"):
        tuning.tune(tmp_path, config.replace(knots=5), resume=True)
    # Knots are the schedule's; every size, the default's too, is in the saved settings.
    with pytest.raises(ValueError, match="knots = 4 is not allowed with problem = 'fixed'"):
        tuning.TuneConfig(knots=4).validate()
    assert tuning.TuneConfig.for_problem("schedule").as_dict()["knots"] == 10
    assert config.as_dict()["knots"] == 4
    with pytest.raises(ValueError, match=r"another run \(knots = 4 there, 10 now\)"):
        tuning.tune(tmp_path, config.replace(knots=10), resume=True)


def _small_settings():
    names = ("iters", "poses", "horizon", "checkpoint_every", "eval_poses", "random_search")
    return {name: getattr(SMALL, name) for name in names}


def test_a_robust_resume_leaves_its_finished_run_and_refuses_another(tmp_path, capsys):
    import dataclasses
    from types import SimpleNamespace

    from wmr_jax._src.cli.tune_robust import config_from
    from wmr_jax._src.model.robots import robot_json

    # A finished `tune --robust --iters 3 --poses 4` (its files, as the run writes them).
    config = config_from(SimpleNamespace(iters=3, poses=4))
    record = {"config": dataclasses.asdict(config), "robot": robot_json(w.Robot()), "rows": []}
    (tmp_path / "robust_evaluation.json").write_text(json.dumps(record))
    (tmp_path / "tuned_gains.json").write_text("{}")
    files = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in tmp_path.iterdir()}
    flags = ["tune", "--robust", "--out", str(tmp_path), "--poses", "4", "--resume"]
    assert main([*flags, "--iters", "3"]) == 0
    assert capsys.readouterr().out == (
        f"--resume: {tmp_path} holds this run finished (tuned_gains.json, "
        "robust_evaluation.json); nothing to resume. Without --resume it tunes again\n"
    )
    # Other settings are refused, naming the difference, before anything is tuned.
    assert main([*flags, "--iters", "5"]) == 2
    err = capsys.readouterr().err
    assert "robust_evaluation.json' is of another run (iters = 3 there, 5 now)" in err
    assert main([*flags, "--iters", "3", "--robot", "turtlebot3-burger"]) == 2
    assert "(the robot differs)" in capsys.readouterr().err
    assert {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in tmp_path.iterdir()} == files
