"""Budgets of the gradient-against-search comparisons: CPU time, and what the rows report."""

import json
import warnings

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src.tuning import robust, robust_run, trainer
from wmr_jax._src.tuning import search as search_module
from wmr_jax._src.tuning.estimation import concrete_loop
from wmr_jax._src.tuning.evaluation import poses_digest

KEY = jax.random.key(0)
REFS = np.array([[30.0, 10.0, 1.0], [-20.0, 15.0, -2.0]])


class FakeClock:
    """A CPU clock that moves only when ``tick`` is called: one second per scored generation."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now

    def tick(self, seconds=1.0):
        self.now += seconds


@pytest.fixture
def wall_races(monkeypatch):
    """Wall time that runs 1000 s per reading: a budget counted in it would end at once."""
    import time

    # A whole number of seconds: differences of the readings are exact.
    start, calls = float(int(time.perf_counter()) + 1), [0]

    def racing():
        calls[0] += 1
        return start + 1000.0 * calls[0]

    monkeypatch.setattr(time, "perf_counter", racing)


def test_search_loop_stops_once_the_cpu_clock_has_advanced_by_the_budget(monkeypatch, wall_races):
    clock = FakeClock()
    monkeypatch.setattr(search_module, "clock", clock)

    def score(xs):
        clock.tick()
        return np.zeros(len(xs))

    def propose(generation):
        return np.full((4, 2), float(generation))

    _, _, count = search_module.search_loop(
        propose, score, 3.0, began=clock(), best=(None, np.inf), at_least_once=False
    )
    # 0, 1, 2 s of CPU time used before generations 1, 2, 3; at 3 s it stops.
    assert count == 3 * 4
    clock.now = 100.0
    _, _, none = search_module.search_loop(
        propose, score, 0.0, began=clock(), best=(None, np.inf), at_least_once=False
    )
    assert none == 0


def test_search_loop_with_a_candidate_budget_stops_on_the_count_not_the_clock(monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(search_module, "clock", clock)

    def score(xs):
        clock.tick(1000.0)  # far past any time budget: the count alone must stop it
        return np.zeros(len(xs))

    def propose(generation):
        return np.full((4, 2), float(generation))

    _, _, count = search_module.search_loop(
        propose, score, 0.0, began=clock(), best=(None, np.inf), count=1,
        at_least_once=False, max_count=9,
    )  # fmt: skip
    assert count == 1 + 2 * 4  # 1 and 5 are short of 9; at 9 it stops


def test_random_search_spends_its_budget_in_cpu_time_and_reports_both(monkeypatch, wall_races):
    clock = FakeClock()
    monkeypatch.setattr(search_module, "clock", clock)

    def scored(problem, u, tiled, n, robot, run):
        clock.tick(0.5)
        return jax.numpy.arange(u.shape[0], dtype=float)

    monkeypatch.setattr(search_module, "population_scores", scored)
    result = tuning.random_search(KEY, REFS, budget_s=2.0, chunk=3, horizon=0.3)
    assert result.candidates == 4 * 3  # 0, 0.5, 1, 1.5 s before each chunk; 2 s ends it
    assert result.cpu_s == pytest.approx(2.0)
    assert result.wall_s >= 1000.0  # the wall clock ran on, and did not stop the search


def test_robust_black_box_counts_its_start_and_stops_on_the_cpu_clock(monkeypatch, wall_races):
    clock = FakeClock()
    monkeypatch.setattr(robust, "clock", clock)
    monkeypatch.setattr(search_module, "clock", clock)
    sizes = []

    def scores(loops, refs, key, **_):
        sizes.append(len(loops))
        clock.tick()
        return np.arange(len(loops), dtype=float)

    monkeypatch.setattr(robust, "robust_population_scores", scores)
    joint = robust.joint_problem(tuning.RobustConfig())
    loop, count, cpu, wall = robust.black_box(
        "random search", KEY, REFS, 3.0, w.Robot(), 0.01, joint, (0.5, 1.0)
    )
    # The start (1 s of the budget), then whole generations of 8 in one batch each.
    assert sizes == [1, 8, 8]
    assert count == 1 + 2 * 8 and cpu == pytest.approx(3.0) and wall >= 1000.0
    assert isinstance(loop, w.ClosedLoop)
    sizes.clear()
    _, count, *_ = robust.black_box(
        "random search", KEY, REFS, 0.0, w.Robot(), 0.01, joint, (0.5, 1.0), candidates=17
    )
    assert sizes == [1, 8, 8] and count == 17  # a candidate budget: no clock reading stops it


def test_an_iterations_price_is_its_cpu_time_over_a_candidates_timed_in_turn(monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(robust, "clock", clock)
    calls = []

    def step(z, opt_state, batch, temperature, consts, *, loss, hyper):
        calls.append("iteration")
        clock.tick(2.0)
        return z, opt_state, 0.0

    generation_times = iter([0.5, 0.5, 9.0, 0.5])  # compiled, then one slow round of three

    def scores(zs):
        calls.append(("generation", len(zs)))
        clock.tick(next(generation_times))
        return np.zeros(len(zs))

    monkeypatch.setattr(robust.trainer, "train_step", step)
    config = tuning.RobustConfig(iters=3, poses=2, nonideal_poses=0)
    problem = robust.robust_problem(config, w.Robot())
    state = robust.trainer.start_state(problem)
    price = robust.iteration_price(problem, state, scores, rounds=3)
    # The medians: 2 s an iteration, 0.5 s a generation of 8 (the slow round left out).
    assert price == pytest.approx(2.0 / (0.5 / 8))  # 32 candidates per iteration
    # One call of each to compile, then the two in turn, so that load falls on both.
    assert calls == ["iteration", ("generation", 8)] * 4


def test_the_trainer_counts_its_time_on_the_cpu_clock(monkeypatch, wall_races):
    calls = []

    def clock():
        calls.append(None)
        return 10.0 * len(calls)  # every reading 10 s after the one before

    monkeypatch.setattr(trainer, "clock", clock)
    config = tuning.TuneConfig(iters=2, poses=2, eval_poses=2, horizon=0.3, random_search=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = tuning.train(config)
    # The start's score and each of the 2 iterations: one span of 10 s each.
    assert result.tune_cpu_s == pytest.approx(30.0)


def test_batched_robust_scores_are_each_candidates_robust_score():
    robot = w.Robot()
    joint = robust.joint_problem(tuning.RobustConfig(law="fixed", estimator="ekf"))
    z0 = np.asarray(joint.start_logits(robot))
    loops = [concrete_loop(joint.from_logits(z0 + shift, robot)) for shift in (0.0, -1.0, 1.5)]
    key = jax.random.key(3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batched = search_module.robust_population_scores(
            loops, REFS, key, dt=0.05, robot=robot, noise=(0.5, 1.0)
        )
        alone = [
            tuning.robust_score(lp, REFS, key, dt=0.05, robot=robot, noise=(0.5, 1.0))
            for lp in loops
        ]
    assert batched.shape == (3,) and len(set(np.round(alone, 4))) == 3
    np.testing.assert_allclose(batched, alone, rtol=1e-5)


def _fake_tune(config, on_tuned=None, **_):
    """What tune_robust returns, made up: 4 CPU s of gradient, the searches' own CPU and wall."""
    on_tuned(None, [])
    rows = []
    for condition in ("model robot", "nominal", "latency", "noise", "both"):
        for gains in ("paper", "robust-tuned", "random search", "cma-es"):
            rows.append(
                {"condition": condition, "gains": gains, "feedback": "ekf", "success": 1.0,
                 "mean arrival s": 0.5, "median arrival s": 0.5, "horizon s": 6.0}
            )  # fmt: skip
    history = {"validated_at": np.array([0, config.iters]), "validation": np.array([2.0, 1.0])}
    searches = {"random search": (None, 17, 4.5, 3.0), "cma-es": (None, 9, 4.2, 5.0)}
    budget = {"price": 3.0, "measured_price": 3.0, "candidates": 25}
    return tuning.TuneResult(
        None, {}, history, 4.0, None, "robust", config.iters, None, None, rows, searches, budget
    )


def test_robust_comparison_rows_report_cpu_wall_rates_and_what_each_minimises(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(robust, "tune_robust", _fake_tune)
    config = tuning.RobustConfig(iters=8, search_poses=5, eval_poses=6)
    rows = robust_run.run_comparison(tmp_path, config, progress=None)
    assert len(rows) == 3 * 3 * 5  # seeds, methods, conditions
    by = {(r["seed"], r["method"]): r for r in rows if r["condition"] == "nominal"}
    gradient, search = by[(0, "gradient")], by[(0, "random search")]
    assert gradient["budget_s"] == search["budget_s"] == 4.0  # the gradient's CPU time
    assert gradient["price"] == search["price"] == 3.0  # candidates per iteration
    assert gradient["budget_candidates"] == search["budget_candidates"] == 25
    assert (gradient["cpu_s"], gradient["candidates"]) == (4.0, 8)
    assert gradient["per_cpu_s"] == pytest.approx(8 / 4.0)  # iterations per CPU-second
    assert (search["cpu_s"], search["wall_s"], search["candidates"]) == (4.5, 3.0, 17)
    assert search["per_cpu_s"] == pytest.approx(17 / 4.5)
    assert by[(2, "cma-es")]["per_cpu_s"] == pytest.approx(9 / 4.2)
    assert "relaxed surrogate" in gradient["minimises"]
    assert "hard law" in search["minimises"] and "5 fixed search poses" in search["minimises"]
    # Every row judged on the same held-out poses: the 6 of the evaluation seed.
    held = poses_digest(tuning.held_out_poses(6, tuning.EVAL_SEED))
    assert {r["held_out"] for r in rows} == {held}
    table = (tmp_path / "robust_compare.md").read_text()
    header = table.splitlines()[0]
    for column in ("gradient CPU (s)", "price", "budget", "CPU (s)", "wall (s)", "per CPU-s"):
        assert f"| {column} |" in header, header
    assert "| 4 | 3 | 25 | 17 | 4 | 3 | 3.78 |" in table, table  # random search: 4.5 CPU s
    assert "- gradient minimises: relaxed surrogate" in table


def test_a_given_price_sets_every_searchs_budget_and_the_measured_one_is_reported(
    tmp_path, monkeypatch
):
    pytest.importorskip("evosax")
    budgets = {}

    def fake_black_box(method, key, refs, budget_s, robot, dt, joint, noise=None, **kwargs):
        budgets[method] = kwargs["candidates"]
        loop = concrete_loop(joint.from_logits(joint.start_logits(robot), robot))
        return loop, kwargs["candidates"], 1.0, 1.0

    monkeypatch.setattr(robust, "black_box", fake_black_box)
    monkeypatch.setattr(robust, "iteration_price", lambda *args, **kwargs: 2.5)
    base = dict(
        iters=3, poses=3, nonideal_poses=0, eval_poses=3, law="fixed", estimator=None,
        validation_poses=3, search_poses=2, compare=True,
    )  # fmt: skip
    for price, used in ((None, 2.5), (4.0, 4.0)):
        config = tuning.RobustConfig(**base, price=price)
        result = tuning.tune_robust(config)
        validations = len(result.history["validated_at"])  # each 1.5 candidates
        expected = round(3 * used + validations * 1.5)
        assert budgets == {"random search": expected, "cma-es": expected}
        assert result.budget == {"price": used, "measured_price": 2.5, "candidates": expected}
    # The table says which price set the budget when it was given.
    rows = [
        {**row, "method": row["gains"], "seed": 0, "budget_s": 1.0, "candidates": 3,
         "price": 4.0, "measured_price": 2.5, "budget_candidates": 13, "cpu_s": 1.0,
         "wall_s": 1.0, "per_cpu_s": 3.0}
        for row in result.rows if row["gains"] != "paper"
    ]  # fmt: skip
    from wmr_jax._src.report.tuning import robust_comparison_table

    assert "| 4 (measured 2.5) | 13 |" in robust_comparison_table(rows)


def test_the_price_flag_reaches_the_robust_comparison_and_only_it(monkeypatch, tmp_path, capsys):
    from wmr_jax._src.cli import tune_robust as cli_robust
    from wmr_jax.cli import main

    seen = []
    monkeypatch.setattr(search_module, "one_core", lambda: True)
    monkeypatch.setattr(
        cli_robust, "_compare", lambda out, config, *a, **k: seen.append(config) or 0
    )
    assert main(["tune", "--robust", "--compare", "--price", "4.5", "--out", str(tmp_path)]) == 0
    assert seen[0].price == 4.5
    for argv, message in (
        (["--robust", "--compare", "--price", "0"], "--price '0' is not allowed; allowed: a"),
        (["--robust", "--price", "4"], "--price is not allowed without --robust --compare"),
        (["--compare", "--price", "4"], "--price is not allowed without --robust --compare"),
        (["--robust", "--compare", "--seed", "5"], "--seed is not allowed with --robust --compare"),
    ):
        assert main(["tune", *argv, "--out", str(tmp_path)]) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"price = -1.0 is not allowed; allowed: a number > 0"):
        tuning.RobustConfig(price=-1.0).validate()


def test_a_robust_comparison_of_the_wall_time_format_is_not_resumed(tmp_path, monkeypatch):
    monkeypatch.setattr(robust, "tune_robust", _fake_tune)
    config = tuning.RobustConfig(iters=8)
    robust_run.run_comparison(tmp_path, config, progress=None)
    path = tmp_path / "robust_compare.json"
    saved = json.loads(path.read_text())
    saved["settings"]["format"] = 2  # rows whose budgets were wall time
    path.write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"is of another comparison \(format = 2 there, 3 now\)"):
        robust_run.run_comparison(tmp_path, config, resume=True, progress=None)


def test_one_core_confines_the_process_only_before_jax_starts(monkeypatch):
    confined = []
    monkeypatch.setattr(search_module.os, "sched_getaffinity", lambda pid: {5, 3, 7})
    pin = lambda pid, cpus: confined.append(cpus)  # noqa: E731
    monkeypatch.setattr(search_module.os, "sched_setaffinity", pin)
    # This process's JAX has run already: its thread pool is sized, so nothing changes.
    assert search_module.one_core() is False and confined == []
    from jax._src import xla_bridge

    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    assert search_module.one_core() is True
    assert confined == [{3}]  # one core of those allowed, the process's own threads to come
    monkeypatch.delattr(search_module.os, "sched_setaffinity")
    assert search_module.one_core() is False  # a platform without affinity: run as it is


@pytest.mark.parametrize("robust_flag", [[], ["--robust"]])
def test_the_comparisons_and_only_they_run_on_one_core(monkeypatch, tmp_path, robust_flag):
    from wmr_jax._src.cli import tune as cli_tune
    from wmr_jax._src.cli import tune_robust as cli_robust
    from wmr_jax.cli import main

    calls = []
    monkeypatch.setattr(search_module, "one_core", lambda: calls.append("one core") or True)
    compare = cli_robust if robust_flag else cli_tune
    monkeypatch.setattr(compare, "_compare", lambda *a, **k: calls.append("compare") or 0)
    assert main(["tune", *robust_flag, "--compare", "--out", str(tmp_path / "c")]) == 0
    assert calls == ["one core", "compare"]  # before the comparison's first computation
    calls.clear()
    monkeypatch.setattr(cli_robust, "run", lambda args: calls.append("tune") or 0)
    assert main(["tune", "--robust", "--out", str(tmp_path / "t")]) == 0
    assert calls == ["tune"]  # a tuning run keeps every core


def test_every_cma_es_search_of_a_shape_runs_the_programs_the_first_compiled():
    """A search's budget buys candidates, not compiling: the gradient's seeds after the
    first reuse its compiled step, and CMA-ES's reuse its compiled init, ask and tell."""
    evosax = pytest.importorskip("evosax.algorithms")
    start = np.zeros(7)

    def generations(seed):
        propose, tell = search_module.cma_es_proposals(jax.random.key(seed), start, 4)
        asked = []
        for g in range(3):
            z = propose(g)
            tell(g, z, np.sum(np.asarray(z) ** 2, axis=1))
            asked.append(np.asarray(z))
        return np.stack(asked)

    first = generations(0)
    jitted = (evosax.CMA_ES.init, evosax.CMA_ES.ask, evosax.CMA_ES.tell)
    compiled = [f._cache_size() for f in jitted]
    other = generations(1)
    assert [f._cache_size() for f in jitted] == compiled
    # The shared strategy keeps no state between searches: a seed asks the same again.
    np.testing.assert_array_equal(generations(0), first)
    assert not np.array_equal(other, first)
    # Each search asks for the strategy of its class, population and shape.
    asked = []
    cached = search_module._strategy

    def recorded(*key):
        asked.append(key)
        return cached(*key)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(search_module, "_strategy", recorded)
        search_module.cma_es_proposals(KEY, start, 6)
    used = search_module._evosax_cma_es()  # evosax's, with the eigenbasis of tuning/cma.py
    assert issubclass(used, evosax.CMA_ES) and used is search_module._evosax_cma_es()
    assert asked == [(used, 6, (7,), "float64")]
    # One strategy per population and shape.
    strategy = cached
    assert strategy(evosax.CMA_ES, 4, (7,), "float64") is strategy(
        evosax.CMA_ES, 4, (7,), "float64"
    )
    assert strategy(evosax.CMA_ES, 6, (7,), "float64") is not strategy(
        evosax.CMA_ES, 4, (7,), "float64"
    )
    assert strategy(evosax.CMA_ES, 4, (8,), "float64") is not strategy(
        evosax.CMA_ES, 4, (7,), "float64"
    )
