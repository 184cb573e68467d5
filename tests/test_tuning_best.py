"""The tuner keeps its best iterate by a held-out hard-law score, and says when it beat nothing."""

import json
import warnings

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.tuning import trainer, training
from wmr_jax._src.tuning.evaluation import Evaluation
from wmr_jax.cli import main

# The command's test below runs the same problem (its flags leave the
# validation poses at their default; how often they are scored compiles
# nothing), so the file compiles one training step, score and evaluation.
TINY = tuning.TuneConfig(
    iters=6, poses=2, eval_poses=2, horizon=0.3, random_search=False, validate_every=2
)


def _train(config, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tuning.train(config, **kwargs)


@pytest.mark.parametrize(
    ("validated", "best"),
    [
        ([(0, 5.0), (2, 3.0), (4, 4.0), (6, 4.5)], 2),
        ([(0, 5.0), (2, 3.0), (4, 3.0), (6, 4.0)], 4),  # a tie goes to the later iterate
        ([(0, 5.0), (2, 3.0), (6, 3.0)], 6),  # so the last one stays where it is as good
        ([(0, 5.0), (2, 3.0), (6, 3.03)], 6),  # or within 1 %: the validation set is a sample
        ([(0, 5.0), (2, 3.0), (6, 3.031)], 2),  # beyond 1 %, the earlier one
        ([(0, 1.0), (2, 3.0), (6, 3.0)], 0),  # the start, if nothing beats it
    ],
)
def test_the_best_iterate_is_the_last_unless_an_earlier_one_is_clearly_better(validated, best):
    assert trainer.best_iteration(validated) == best
    assert trainer.BEST_MARGIN == 0.01


def test_train_scores_the_start_every_few_iterations_and_the_last(monkeypatch):
    result = _train(TINY)
    assert result.history["validated_at"].tolist() == [0, 2, 4, 6]
    assert np.all(np.isfinite(result.history["validation"]))
    # 6 is not a multiple of 4: the last iteration is scored all the same.
    assert _train(TINY.replace(validate_every=4)).history["validated_at"].tolist() == [0, 4, 6]


def test_train_returns_the_iterate_of_the_best_validation_score(monkeypatch):
    scores = iter([9.0, 4.0, 1.0, 7.0])  # iterations 0, 2, 4, 6: 4 is the best
    monkeypatch.setattr(training, "validation_score", lambda *args: next(scores))
    result = _train(TINY)
    assert result.best_iteration == 4
    row = result.history["gains"][3]  # the parameters after iteration 4
    expected = dict(zip(tuning.GAIN_FIELDS, row.tolist(), strict=True))
    assert tuning.gains_as_dict(result.gains) == expected
    assert result.history["validation"].tolist() == [9.0, 4.0, 1.0, 7.0]


def test_train_returns_the_start_when_no_iterate_beats_it(monkeypatch):
    scores = iter([1.0, 4.0, 3.0, 2.0])
    monkeypatch.setattr(training, "validation_score", lambda *args: next(scores))
    result = _train(TINY)
    assert result.best_iteration == 0
    start = tuning.FIXED.from_logits(tuning.FIXED.start_logits(w.Robot()), w.Robot())
    expected = tuning.gains_as_dict(jax_floats(start))
    assert tuning.gains_as_dict(result.gains) == pytest.approx(expected, rel=1e-6)


def jax_floats(gains):
    return gains.replace(**{f: float(getattr(gains, f)) for f in tuning.GAIN_FIELDS})


def test_a_resumed_run_keeps_the_scores_it_had(monkeypatch):
    states = []
    whole = _train(TINY, progress_fn=states.append)
    arrays = tuning.state_arrays(states[2])  # after iteration 3: scores at 0 and 2
    resumed_state = tuning.restore_state(arrays, tuning.init_state(TINY))
    assert [i for i, _ in resumed_state.validated] == [0, 2]
    # The logits of the lower of the two scores (the later of equal ones) come back.
    lowest = min(v for _, v in resumed_state.validated)
    at = max(i for i, v in resumed_state.validated if v == lowest)
    want = tuning.init_state(TINY).z if at == 0 else states[at - 1].z
    np.testing.assert_array_equal(np.asarray(resumed_state.lowest_z), np.asarray(want))
    resumed = _train(TINY, state=resumed_state)
    assert resumed.best_iteration == whole.best_iteration
    assert resumed.history["validation"].tolist() == whole.history["validation"].tolist()
    assert tuning.gains_as_dict(resumed.gains) == tuning.gains_as_dict(whole.gains)
    # A state saved before its first score (init_state's) holds none, and runs as a fresh one.
    fresh = tuning.init_state(TINY)
    unscored = tuning.restore_state(tuning.state_arrays(fresh), fresh)
    assert unscored.lowest_z is None and not unscored.validated
    again = _train(TINY, state=unscored)
    assert again.history["validation"].tolist() == whole.history["validation"].tolist()


def _evaluation(mean, success=1.0):
    return Evaluation(mean, success, 10.0, 4)


@pytest.mark.parametrize(
    ("tuned", "paper", "said"),
    [
        (_evaluation(1.0), _evaluation(2.0), False),
        (_evaluation(2.0), _evaluation(2.0), True),  # no better is not better
        (_evaluation(3.0), _evaluation(2.0), True),
        (_evaluation(1.0, 0.9), _evaluation(2.0), True),  # sooner, but arrives less often
        (_evaluation(3.0), _evaluation(2.0, 0.9), False),  # arrives more often
    ],
)
def test_a_result_no_better_than_the_baseline_is_said_in_one_line(tuned, paper, said):
    note = training.baseline_note(
        {"tuned": tuned, "paper_feasible": paper}, "paper_feasible", "tuned"
    )
    assert (note is not None) == said
    if said:
        assert "\n" not in note
        assert note.startswith("warning: the tuned parameters are no better than the baseline")
        assert f"{tuned.mean_arrival:.3f} s" in note and f"{paper.mean_arrival:.3f} s" in note


def test_the_command_prints_the_note_once_and_records_it(tmp_path, monkeypatch, capsys):
    line = "warning: the tuned parameters are no better than the baseline (paper_feasible): x"
    monkeypatch.setattr(training, "baseline_note", lambda *args: line)
    flags = ["--iters", "6", "--poses", "2", "--eval-poses", "2", "--horizon", "0.3"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["tune", "--out", str(tmp_path), *flags, "--no-random-search"]) == 0
    out = capsys.readouterr().out
    assert out.count(line) == 1
    assert "kept iteration" in out
    report = json.loads((tmp_path / "evaluation.json").read_text())
    assert report["no_better_than_baseline"] is True
    assert report["note"] == line
    assert report["best_iteration"] in report["validation"]["scored_at"]


def test_a_slow_robot_tuned_briefly_never_returns_worse_than_its_start_unsaid():
    """The robot of a wide, slow base: its loss can climb; the result is the best iterate."""
    robot = w.Robot(half_track=8.0, v_max=22.0)
    config = tuning.TuneConfig(
        iters=12, poses=8, horizon=38.2, eval_poses=16, validation_poses=16,
        validate_every=4, random_search=False,
    )  # fmt: skip
    result = _train(config, robot=robot)
    scores = result.history["validation"]
    assert scores[result.history["validated_at"].tolist().index(result.best_iteration)] <= scores[0]
    evaluation = result.evaluation
    better = evaluation["tuned"].mean_arrival < evaluation["paper_feasible"].mean_arrival
    assert better or result.note is not None
