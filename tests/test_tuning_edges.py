"""Bad input to the tuning layer: a named ValueError before any work, never a silent run."""

import math
import warnings

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import studies, tuning
from wmr_jax._src.tuning import compare as compare_module
from wmr_jax._src.tuning import search as search_module

KEY = jax.random.key(0)
REFS = np.array([[30.0, 10.0, 1.0], [-20.0, 15.0, -2.0]])
# The problem of tests/test_tuning_best.py: one compiled training step and evaluation for both.
TINY = tuning.TuneConfig(
    iters=6, poses=2, eval_poses=2, horizon=0.3, random_search=False, validate_every=2
)


def _trained_states(config):
    states = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tuning.train(config, progress_fn=states.append)
    return states


# ---------------------------------------------------------------- states and configs


def test_train_refuses_a_state_of_another_problem_or_run():
    schedule = tuning.TuneConfig.for_problem(
        "schedule", iters=2, poses=2, eval_poses=2, horizon=0.3, random_search=False
    )
    with pytest.raises(ValueError, match=r"state holds \(35,\) logits; allowed: \(7,\)"):
        tuning.train(TINY, state=tuning.init_state(schedule))
    with pytest.raises(ValueError, match=r"state holds \(7,\) logits; allowed: \(35,\)"):
        tuning.train(schedule, state=tuning.init_state(TINY))
    # A finished state of another config used to return that config's gains as this one's.
    last = _trained_states(TINY)[-1]
    with pytest.raises(ValueError, match=r"another run \(learning_rate = 0.1 there, 0.5 now\)"):
        tuning.train(TINY.replace(learning_rate=0.5), state=last)
    with pytest.raises(ValueError, match=r"state = \{\} is not allowed; allowed: a TrainState"):
        tuning.train(TINY, state={})
    with pytest.raises(ValueError, match=r"config = \{'iters': 2\} is not allowed"):
        tuning.train({"iters": 2})


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("iteration", np.asarray(1.7), r"iteration = array\(1.7\) is not a whole number"),
        ("iteration", np.asarray(True), r"iteration = array\(True\) is not a whole number"),
        ("elapsed_s", np.asarray(-5.0), r"elapsed time finite and >= 0 \(elapsed_s = -5.0\)"),
        ("temperatures", np.asarray([-1.0] + [0.1] * 5), r"temperatures must be > 0"),
        ("gains", np.ones((6, 2)), r"rows of 2 parameters; allowed: 7"),
        ("opt_0", np.asarray(-3, np.int32), r"optimiser step counts \[-3, 6\]"),
        ("lowest_z", np.full(7, np.nan), r"holds non-finite values"),
        ("lowest_z", np.zeros(6), r"incomplete \(TypeError: cannot reshape array of shape \(6,\)"),
    ],
)
def test_restore_state_refuses_a_corrupt_state(name, value, message):
    arrays = tuning.state_arrays(_trained_states(TINY)[-1])
    fresh = tuning.init_state(TINY)
    assert tuning.restore_state(arrays, fresh).iteration == 6
    with pytest.raises(ValueError, match=message):
        tuning.restore_state({**arrays, name: value}, fresh)


# ---------------------------------------------------------------- the feasible set


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: tuning.gains_from_logits(np.zeros(3)),
            r"z has shape \(3,\); allowed: \(\.\.\., 7\)",
        ),
        (lambda: tuning.FIXED.from_logits(np.zeros(35), w.Robot()), r"z has shape \(35,\)"),
        (lambda: tuning.robust_gains(np.zeros(3), w.Robot()), r"z has shape \(3,\)"),
        (lambda: tuning.gains_from_unit(np.full(7, 5.0)), r"u = .*5\.0.*numbers in \[0, 1\]"),
        (lambda: tuning.gains_from_unit(np.full(7, np.nan)), r"u = .*nan.*numbers in \[0, 1\]"),
        (lambda: tuning.gains_from_logits(np.full(7, np.nan)), r"z = .*nan.*not NaN"),
        (lambda: tuning.SCHEDULED.from_unit(np.zeros(7), w.Robot()), r"u has shape \(7,\)"),
    ],
)
def test_the_feasible_map_refuses_points_of_another_size_or_outside_the_cube(call, message):
    # Out-of-range indices were clamped: 3 or 35 logits gave 7 gains, and
    # u = 5 gave k_theta = -1347.
    with pytest.raises(ValueError, match=message):
        call()


def test_the_feasible_map_still_takes_batches_and_infinite_logits():
    gains = tuning.gains_from_logits(np.array([[-np.inf] * 7, [np.inf] * 7]))
    assert np.asarray(gains.kr).shape == (2,)
    assert np.all(np.isfinite(np.asarray(gains.kr)))


# ---------------------------------------------------------------- searches


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"budget_s": math.nan}, r"budget_s = nan is not allowed"),
        ({"budget_s": math.inf}, r"budget_s = inf is not allowed"),
        ({"budget_s": True}, r"budget_s = True is not allowed"),
        ({"budget_s": "0.5"}, r"budget_s = '0.5' is not allowed"),
        ({"budget_s": None}, r"budget_s = None is not allowed"),
        ({"key": 0}, r"key = 0 is not allowed; allowed: a jax.random key"),
        ({"progress": 5}, r"progress = 5 is not allowed; allowed: a function or None"),
        ({"velocity": "fast"}, r"velocity = 'fast' is not allowed"),
    ],
)
@pytest.mark.parametrize("search", [tuning.random_search, tuning.cma_es_search])
def test_searches_check_their_options_before_they_start(search, kwargs, message):
    if search is tuning.cma_es_search:
        pytest.importorskip("evosax")
    args = {"key": KEY, "budget_s": 0.1, "horizon": 0.3, **kwargs}
    key = args.pop("key")
    with pytest.raises(ValueError, match=message):
        search(key, REFS, **args)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"population": True}, r"population = True is not allowed"),
        ({"population": 1}, r"population = 1 is not allowed"),
        ({"std_init": -1.0}, r"std_init = -1.0 is not allowed"),
        ({"std_init": math.nan}, r"std_init = nan is not allowed"),
        ({"horizn": 0.3}, r"unknown option 'horizn'; allowed: robot, dt, horizon"),
    ],
)
def test_cma_es_checks_its_own_options(kwargs, message):
    pytest.importorskip("evosax")
    with pytest.raises(ValueError, match=message):
        tuning.cma_es_search(KEY, REFS, budget_s=0.1, horizon=0.3, **kwargs)


def test_random_search_refuses_a_start_the_schedule_would_ignore():
    with pytest.raises(ValueError, match=r"start is for the fixed problem"):
        tuning.random_search(KEY, REFS, budget_s=0.0, problem="schedule", start=w.Gains())


@pytest.mark.parametrize("generation", [0, 1, 2**31 - 2])
def test_cma_es_asks_and_tells_with_the_keys_of_its_generation(generation):
    # Each generation's keys are split(fold_in(key, generation + 1)), as the
    # docs' comparison tables were drawn: computed in one compiled call.
    key = jax.random.fold_in(KEY, 2)
    want = jax.random.split(jax.random.fold_in(key, generation + 1))
    got = search_module._generation_keys(key, generation)
    np.testing.assert_array_equal(jax.random.key_data(got), jax.random.key_data(want))


def test_cma_es_keeps_its_best_when_a_flat_landscape_breaks_it(monkeypatch):
    # Every candidate scored alike: evosax's step size overflows after some
    # 300 generations and it asks for NaN candidates, which used to end the
    # whole budget in a "gains.kr = nan" error.
    pytest.importorskip("evosax")
    scored = []

    def flat(problem, u, tiled, n, robot, run):
        scored.append(np.asarray(u))
        return jax.numpy.full((u.shape[0],), 0.66)

    monkeypatch.setattr(search_module, "population_scores", flat)
    result = tuning.cma_es_search(KEY, REFS, budget_s=600.0, horizon=0.3)
    assert result.wall_s < 600.0  # stopped by the breakdown, not by the budget
    assert all(np.all(np.isfinite(u)) for u in scored)
    assert result.score == pytest.approx(0.66)
    assert np.isfinite(result.gains.kr)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seeds": ()}, r"seeds = \(\) is not allowed; allowed: a non-empty tuple"),
        ({"problems": ()}, r"problems = \(\) is not allowed"),
        ({"problems": "fixed"}, r"problems = 'fixed' is not allowed"),
        ({"seeds": (0, -1)}, r"seeds\[1\] = -1 is not allowed"),
        ({"problems": ("fixed", "bogus")}, r"problem = 'bogus' is not allowed"),
        (
            {"configs": {"schedule": TINY}, "problems": ("fixed",)},
            r"configs\['schedule'\] is for no",
        ),
        (
            {"configs": {"fixed": tuning.TuneConfig.for_problem("schedule")}},
            r"of the 'fixed' problem",
        ),
        ({"progress": "x"}, r"progress = 'x' is not allowed"),
    ],
)
def test_compare_checks_every_problem_and_seed_before_the_first_run(kwargs, message):
    # A bad second problem or seed used to fail only after the first one's runs.
    with pytest.raises(ValueError, match=message):
        tuning.compare(**kwargs)


@pytest.mark.filterwarnings("ignore::wmr_jax.SamplingWarning")  # a candidate may not settle
def test_compare_runs_all_three_methods_on_a_schedule_of_its_size():
    """A schedule config's knots size what the gradient, CMA-ES and random search all search."""
    # The 4-knot problem and settings of test_tuning_train.py's schedule test:
    # the gradient's compiled step and evaluation are that test's.
    small = dict(iters=6, poses=8, horizon=1.0, checkpoint_every=2, eval_poses=8)
    config = tuning.TuneConfig.for_problem("schedule", knots=4, random_search=False, **small)
    searched = []

    def watched(search):
        def run(*args, problem, budget_s, **kwargs):
            searched.append((search.__name__, problem.dim, budget_s > 0))
            # One round each: what is searched is under test here, not for how long.
            return search(*args, problem=problem, budget_s=0.0, **kwargs)

        return run

    def warning(evaluate):
        def run(*args, **kwargs):
            warnings.warn("k_theta*dt = 2.5 >= 2", w.SamplingWarning, stacklevel=2)
            return evaluate(*args, **kwargs)

        return run

    with pytest.MonkeyPatch.context() as patch, pytest.warns(w.SamplingWarning) as said:
        for name in ("cma_es_search", "random_search"):
            patch.setattr(compare_module, name, watched(getattr(compare_module, name)))
        patch.setattr(compare_module, "evaluate", warning(compare_module.evaluate))
        rows = tuning.compare(seeds=(0,), problems=("schedule",), configs={"schedule": config})
    assert [r["method"] for r in rows] == ["gradient", "cma-es", "random search"]
    # A warning about a method's gains names the method, the problem and the seed.
    named = [str(r.message) for r in said if issubclass(r.category, w.SamplingWarning)]
    for method in ("gradient", "cma-es", "random search"):
        assert f"gains 'schedule, seed 0, {method}': k_theta*dt = 2.5 >= 2" in named
    assert all(text.startswith("gains 'schedule, seed 0, ") for text in named), named
    # Each given the gradient's CPU time (positive), searching the 17 logits.
    assert searched == [("cma_es_search", 17, True), ("random_search", 17, True)]
    assert all(r["parameters"] == 17 for r in rows)
    for row in rows:
        assert row["wall_s"] > 0 and row["mean_arrival"] > 0, row  # inf where none arrives
    # The budget is the gradient's CPU time; every method judged on the same held-out poses.
    gradient = rows[0]
    assert gradient["cpu_s"] == gradient["budget_s"] > 0
    assert gradient["per_cpu_s"] == pytest.approx(config.iters / gradient["cpu_s"])
    held = tuning.held_out_poses(config.eval_poses, config.eval_seed)
    from wmr_jax._src.tuning.evaluation import poses_digest

    assert {r["held_out"] for r in rows} == {poses_digest(held)}
    assert {r["budget_s"] for r in rows} == {gradient["budget_s"]}
    assert "relaxed surrogate" in gradient["minimises"]
    assert all("hard law" in r["minimises"] for r in rows[1:])


# ---------------------------------------------------------------- smaller entry points


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: tuning.train(TINY, progress_fn=5), r"progress_fn = 5 is not allowed"),
        (lambda: tuning.train(TINY, eval_progress=5), r"eval_progress = 5 is not allowed"),
        (lambda: tuning.tune_robust(TINY), r"allowed: a wmr_jax.tuning.RobustConfig or None"),
        (
            lambda: tuning.tune_robust(tuning.RobustConfig(iters=1), progress_fn="x"),
            r"progress_fn = 'x' is not allowed",
        ),
        (lambda: tuning.RobustConfig(compare="no").validate(), r"compare = 'no' is not allowed"),
        (lambda: tuning.bound_ratios(math.nan, tuning.time_bounds(REFS)), r"mean_arrival = nan"),
        (lambda: tuning.bound_ratios(True, tuning.time_bounds(REFS)), r"mean_arrival = True"),
        (lambda: tuning.bound_ratios(-1.0, tuning.time_bounds(REFS)), r"mean_arrival = -1.0"),
        (lambda: tuning.evaluate(None, REFS), r"gains = None is not allowed"),
        (lambda: tuning.robust_score(None, REFS, KEY), r"gains = None is not allowed"),
        (
            lambda: tuning.robust_score(w.Gains(kr=[60.0, 90.0]), REFS, KEY),
            r"^gains.kr has shape \(2,\); allowed: scalars: one set of gains",
        ),
        (lambda: tuning.robust_score(w.Gains(), "ab", KEY), r"refs = 'ab' is not allowed"),
        (lambda: tuning.robust_score(w.Gains(), REFS, 0), r"key = 0 is not allowed"),
        (lambda: tuning.held_out_poses(2, -1), r"eval_seed = -1 is not allowed"),
        (lambda: tuning.training_poses(0, -1, 2), r"iteration = -1 is not allowed"),
        (lambda: tuning.training_poses(1.5, 0, 2), r"seed = 1.5 is not allowed"),
        (lambda: tuning.load_tuned(5), r"path = 5 is not allowed; allowed: a path"),
        (lambda: studies.pose_grid(4, "90"), r"headings_deg = '90' is not allowed"),
        (lambda: studies.map_study(4, cache=5), r"cache = 5 is not allowed"),
        (lambda: studies.monte_carlo(KEY, n_runs=2, x64="no"), r"x64 = 'no' is not allowed"),
        (lambda: w.sweep(REFS, steps=3, resume="no"), r"resume = 'no' is not allowed"),
        (lambda: w.sweep(REFS, steps=3, progress="no"), r"progress = 'no' is not allowed"),
        (lambda: w.unpad(np.float32(1.0), 1), r"allowed: arrays .* with a leading batch axis"),
        (lambda: w.shard(REFS, devices="cpu"), r"devices = 'cpu' is not allowed"),
    ],
)
def test_tuning_and_study_entry_points_name_bad_values(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_tune_checks_its_folder_flags_and_config_before_writing(tmp_path):
    afile = tmp_path / "a.txt"
    afile.write_text("x")
    for kwargs, message in (
        ({"out_dir": afile}, r"out_dir = '.*a.txt' is not allowed; allowed: a folder"),
        ({"out_dir": 5}, r"out_dir = 5 is not allowed"),
        ({"resume": "no"}, r"resume = 'no' is not allowed"),
        ({"progress_fn": 5}, r"progress_fn = 5 is not allowed"),
        ({"config": {"iters": 1}}, r"config = \{'iters': 1\} is not allowed"),
    ):
        args = {"out_dir": tmp_path / "out", "config": TINY, **kwargs}
        with pytest.raises(ValueError, match=message):
            tuning.tune(args.pop("out_dir"), **args)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_compare_rows_saved_before_sizes_group_with_new_ones():
    """A resumed comparison mixes rows without "parameters" (the default size) and rows with."""
    from wmr_jax._src.report.tuning import comparison_table

    row = {"problem": "schedule", "method": "gradient", "mean_arrival": 0.4, "wall_s": 1.0}
    row.update(success_rate=1.0, lower_bound_s=0.34, turn_drive_turn_s=0.37)
    rows = [row, {**row, "parameters": 35}, {**row, "parameters": 35}]
    table = comparison_table(rows)
    assert "| schedule (35) | gradient | 0.400 / 0.400 / 0.400 |" in table, table
    assert table.count("| schedule") == 1


def test_compare_without_evosax_is_refused_before_any_run(monkeypatch, tmp_path, capsys):
    import sys

    from wmr_jax._src.cli.main import main
    from wmr_jax._src.tuning import compare

    trained = []
    monkeypatch.setattr(compare, "train", lambda *a, **k: trained.append(1))
    monkeypatch.setitem(sys.modules, "evosax.algorithms", None)  # import evosax... fails
    with pytest.raises(ValueError, match=r"CMA-ES needs evosax; allowed: pip install"):
        compare.compare(seeds=(0,), problems=("fixed",))
    argv = ["tune", "--compare", "--out", str(tmp_path), "--iters", "2"]
    assert main(argv) == 2
    assert "CMA-ES needs evosax" in capsys.readouterr().err
    assert trained == [] and not (tmp_path / "compare.json").exists()
