"""The sensed-loop studies and their commands on your own robot; their tables and figures."""

import json
import math

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.cli.main import main
from wmr_jax._src.model.robots import robot_json, same_robot
from wmr_jax._src.report.figures import plt
from wmr_jax._src.report.robustness import robustness_table, standard_figure
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.studies import conditions, robustness
from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
from wmr_jax._src.tuning.saved import tuned_json

# A robot slower than its paper counterpart: the paper's feasible gains (60 + 10 L =
# 100 cm/s) are scaled by 0.9 into its budget, and its horizon is 6 s / 0.9.
QUICK = w.Robot(half_track=4.0, v_max=90.0)
QUICK_HORIZON = 6.7  # s: 6 / 0.9 rounded up to 0.1 s
SLOW = w.Robot(half_track=8.0, v_max=22.0)
REFS = np.array([[30.0, 20.0, 0.3], [-20.0, 15.0, 1.0]])


def _file(tmp_path, name, values):
    path = tmp_path / name
    path.write_text(json.dumps(values))
    return str(path)


# ---------------------------------------------------------------- the studies take the robot


def test_the_horizon_scales_with_the_robots_paper_feasible_gains():
    assert robustness.study_horizon() == robustness.study_horizon(w.Robot()) == 6.0
    assert robustness.study_horizon(QUICK) == QUICK_HORIZON
    # 60 + 80 = 140 cm/s of budget for 22 cm/s of wheel: 6 s × 140 / 22 = 38.18 s.
    assert robustness.study_horizon(SLOW) == 38.2
    assert robustness.study_horizon(w.ROBOTS["turtlebot3-burger"]) == 37.0
    # The scaled gains are exactly that much slower (same shape, factor 0.9).
    assert paper_feasible_gains(QUICK).kr == pytest.approx(54.0)
    with pytest.raises(ValueError, match="robot.v_max"):
        robustness.study_horizon(w.Robot(v_max=-1.0))


def _recorded(monkeypatch):
    """Each run the studies ask for, as (robot, periods); nothing is drawn or run.

    The studies' plumbing only: the draws become zeros and every run arrives at 1 s.
    """
    seen = []

    def fake(spec, *args, robot=None, **kwargs):
        n, steps = np.shape(spec.noise)[:2]
        seen.append((robot, steps))
        ones = np.ones(n)
        return PoseMetrics(ones, ones, ones, ones, ones, ones)

    def unit_draws(key, refs, steps, mismatch):
        return np.zeros((len(refs), steps, 3)), np.ones((len(refs), 3))

    def draws(key, n, steps, **kwargs):
        return np.tile(REFS[:1], (n, 1)), np.zeros((n, steps, 3)), np.ones((n, 3))

    for module in (robustness, conditions):
        monkeypatch.setattr(module, "disturbed_metrics", fake)
    monkeypatch.setattr(conditions, "_unit_draws", unit_draws)
    monkeypatch.setattr(robustness, "draw_disturbances", draws)
    return seen


KEY = jax.random.PRNGKey(0)
STUDIES = {
    "monte_carlo": lambda **kw: studies.monte_carlo(
        KEY, n_runs=2, noise_xy=(0.5,), noise_deg=(1.0,), **kw
    ),
    "robustness_study": lambda **kw: studies.robustness_study(
        controller_names=["shim-sung"], n_runs=2, noise_xy=(0.5,), noise_deg=(1.0,), **kw
    ),
    "standard": lambda **kw: studies.standard_conditions({"a": w.Gains()}, REFS, KEY, **kw),
    "noise_curve": lambda **kw: studies.noise_curve(
        {"a": w.Gains()}, REFS, KEY, noise_xy=(0.5,), **kw
    ),
    "evaluate_loop": lambda **kw: [studies.evaluate_loop(w.Gains(), REFS, **kw)],
}


@pytest.mark.parametrize("study", list(STUDIES))
def test_every_study_runs_its_robot_for_its_horizon(monkeypatch, study):
    seen = _recorded(monkeypatch)
    rows = STUDIES[study](robot=QUICK)
    assert seen and all(same_robot(robot, QUICK) for robot, _ in seen)
    steps = math.ceil(QUICK_HORIZON / w.DEFAULT_DT)  # the robot's horizon by default
    assert {s for _, s in seen} == {steps}
    key_name = "horizon_s" if study == "evaluate_loop" else "horizon s"
    assert all(r[key_name] == pytest.approx(steps * w.DEFAULT_DT) for r in rows)
    seen.clear()
    STUDIES[study](robot=QUICK, horizon=1.0)  # a horizon given is run as it is
    assert {s for _, s in seen} == {math.ceil(1.0 / w.DEFAULT_DT)}
    seen.clear()
    STUDIES[study]()  # the paper robot by default, for the paper's 6 s
    assert {s for _, s in seen} == {182}
    assert all(robot is None or same_robot(robot, w.Robot()) for robot, _ in seen)


def test_the_monte_carlo_scales_the_paper_gains_into_the_robots_budget(monkeypatch):
    # Its defaults ask 200 cm/s of a 90 cm/s robot's wheels; the study runs the
    # paper's feasible gains there, as the tuner's baseline (the baselines keep theirs).
    assert robustness.robot_defaults("shim-sung") is None
    assert robustness.robot_defaults("shim-sung", w.Robot()) is None
    assert robustness.robot_defaults("shim-sung", QUICK) == paper_feasible_gains(QUICK)
    schedule = robustness.robot_defaults("shim-sung-schedule", QUICK)
    assert schedule.v_max == 90.0 and schedule.half_track == 4.0
    assert schedule.kr == (pytest.approx(54.0),) * len(schedule.kr)
    assert robustness.robot_defaults("aicardi", QUICK) is None
    params = []

    def fake(spec, p, **kwargs):
        params.append(p)
        ones = np.ones(len(spec.ref))
        return PoseMetrics(ones, ones, ones, ones, ones, ones)

    _recorded(monkeypatch)
    monkeypatch.setattr(robustness, "disturbed_metrics", fake)
    studies.monte_carlo(KEY, n_runs=1, noise_xy=(0.0,), noise_deg=(0.0,), robot=QUICK)
    assert params == [paper_feasible_gains(QUICK)]


@pytest.fixture
def no_noise(monkeypatch):
    """The studies' draws replaced by no noise and exact wheels (drawing compiles for seconds)."""

    def unit_draws(key, refs, steps, mismatch):
        return np.zeros((len(refs), steps, 3)), np.ones((len(refs), 3))

    monkeypatch.setattr(conditions, "_unit_draws", unit_draws)


def test_a_robots_wheels_and_yardstick_are_its_own(no_noise):
    near = np.array([[8.0, 0.0, 0.0]])  # within reach of the slow robot in 6.7 s
    # One reference over the QUICK robot's horizon: the shape of the commands' tests.
    feasible = studies.evaluate_loop(paper_feasible_gains(SLOW), near, robot=SLOW,
                                     horizon=QUICK_HORIZON)  # fmt: skip
    assert feasible["v_max"] == 22.0 and feasible["robot"] == robot_json(SLOW)
    assert feasible["peak_wheel_speed"] <= 22.0 * 1.03 and feasible["peak_wheel_speed_ok"]
    # The paper's Fig. 7 gains ask far more of its wheels than 22 cm/s: said.
    with pytest.warns(w.WheelSpeedWarning, match="exceeds v_max = 22 cm/s"):
        fig7 = studies.evaluate_loop(w.Gains(), near, robot=SLOW, horizon=QUICK_HORIZON)
    assert fig7["peak_wheel_speed"] > 50.0 and not fig7["peak_wheel_speed_ok"]
    # The arrival is set against the robot's own turn-drive-turn time (docs/model.md §8).
    tdt = w.studies.time_bounds(near, robot=SLOW).turn_drive_turn.mean()
    assert feasible["turn_drive_turn_s"] == pytest.approx(tdt)
    assert feasible["vs_turn_drive_turn"] == pytest.approx(feasible["mean_arrival_s"] / tdt)
    # A loop tuned for one robot is judged on that one only.
    loop = studies.ClosedLoop("shim-sung", w.Gains(kr=60.0), None, w.Robot())
    with pytest.raises(ValueError, match=r"evaluate_loop\['loop'\] was tuned for paper"):
        studies.evaluate_loop(loop, REFS[:1], robot=SLOW, horizon=1.0)
    with pytest.raises(ValueError, match=r"params_by_name\['a'\] was tuned for paper"):
        studies.standard_conditions({"a": loop}, REFS[:1], KEY, robot=SLOW)


# ---------------------------------------------------------------- the commands take the robot


def test_evaluate_runs_a_tuned_file_on_its_robot(tmp_path, capsys, monkeypatch, no_noise):
    gains = _file(tmp_path, "g.json", tuned_json(paper_feasible_gains(QUICK), robot=QUICK))
    refs = str(tmp_path / "refs.npy")
    np.save(refs, REFS[:1])
    out = tmp_path / "e.json"
    argv = ["evaluate", "--gains", gains, "--refs", refs, "--condition", "nominal"]
    assert main([*argv, "--json", str(out), "--mismatch", "0"]) == 0
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["robot"] == robot_json(QUICK) and result["v_max"] == 90.0
    # The robot's horizon by default: 6 s / 0.9 for its scaled paper gains.
    assert result["horizon_s"] == pytest.approx(204 * 0.033)
    assert result["success"] == 1.0 and result["peak_wheel_speed"] <= 90.0
    assert "| V_max | 90 cm/s, every wheel command within it |" in printed
    assert "| robot | custom (L = 4 cm" in printed
    assert f"| vs turn–drive–turn time | {result['vs_turn_drive_turn']:.3f}× " in printed
    # Another robot than the file's is refused in one line, before any run.
    assert main([*argv, "--robot", "turtlebot3-burger"]) == 2
    err = capsys.readouterr().err
    assert "--robot 'turtlebot3-burger' is not allowed with --gains" in err
    assert err.count("\n") == 1
    # A file that records no robot runs on --robot's.
    plain = _file(tmp_path, "plain.json", tuned_json(w.Gains(kr=10.0, k_theta=1.0)))
    slow = _file(tmp_path, "slow.json", {"half_track": 8.0, "v_max": 22.0})
    argv = ["evaluate", "--gains", plain, "--refs", refs, "--condition", "latency"]
    assert main([*argv, "--robot", slow, "--horizon", "6.7", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["robot"] == robot_json(SLOW)

    # Without --horizon, the slow robot's 38.2 s.
    class Ran(Exception):
        pass

    def stand_in(*args, **kwargs):
        raise Ran(kwargs)

    monkeypatch.setattr(conditions, "evaluate_loop", stand_in)
    with pytest.raises(Ran) as ran:
        main([*argv, "--robot", slow])
    (called,) = ran.value.args
    assert called["horizon"] == 38.2 and same_robot(called["robot"], SLOW)


def test_robustness_runs_the_files_robot_and_prints_percentages(tmp_path, capsys, monkeypatch):
    from wmr_jax._src.report import figures as report
    from wmr_jax._src.tuning import evaluation

    # The studies' rows, as they return them (their robot and horizon are tested above).
    runs = {}
    mc_row = {"condition": "noise", "controller": "aicardi", "noise xy cm": 0.5,
              "noise theta deg": 1.0, "success": 0.998, "mean arrival s": 1.0,
              "median arrival s": 1.0, "reached": 1.0, "median first arrival s": 1.0,
              "mean final distance cm": 0.1, "mean zigzag": 1.0, "settled at horizon": 0.5,
              "median arrival, not at horizon s": 1.0, "horizon s": 6.732}  # fmt: skip

    def monte_carlo(**kwargs):
        runs["monte carlo"] = kwargs
        return [mc_row]

    def standard(sets, refs, key, **kwargs):
        runs["standard"] = (sets, kwargs)
        labels = ("model robot", "nominal", "latency", "noise", "both")
        return [
            {"condition": c, "gains": name, "feedback": "raw", "success": 1.0,
             "mean arrival s": 1.0, "median arrival s": 1.0, "mean final distance cm": 0.1,
             "peak wheel cm/s": 80.0, "mismatch": 0.03, "runs": 400, "horizon s": 6.732,
             "settled at horizon": 0.0, "mean arrival, not at horizon s": 1.0}
            for c in labels for name in sets
        ]  # fmt: skip

    monkeypatch.setattr(robustness, "robustness_study", monte_carlo)
    monkeypatch.setattr(conditions, "standard_conditions", standard)
    # Neither the held-out poses drawn nor the figures saved (the figures are tested below).
    monkeypatch.setattr(evaluation, "held_out_poses", lambda *args: REFS)
    monkeypatch.setattr(report, "save_figure", lambda fig, path, **kw: path)
    loop = studies.ClosedLoop("shim-sung", w.Gains(kr=50.0, k_theta=2.0), None)
    gains = _file(tmp_path, "g.json", tuned_json(loop, robot=QUICK))
    out = tmp_path / "rob"
    # An earlier run's noise curve (not asked for now) does not stay beside this run's files.
    out.mkdir()
    for stale in ("noise_curve.md", "noise_curve.json", "standard_conditions.png"):
        (out / stale).write_text("an earlier run")
    argv = ["robustness", "--out", str(out), "--runs", "2", "--controller", "aicardi"]
    assert main([*argv, "--robust-gains", gains]) == 0
    printed = capsys.readouterr().out
    assert not (out / "noise_curve.md").exists() and not (out / "noise_curve.json").exists()
    assert not (out / "standard_conditions.png").exists()  # removed; figures not saved here
    # Each record says which gains, from which file, in which dtype.
    record = json.loads((out / "standard_conditions.json").read_text())
    assert record["gain_files"] == {"--robust-gains": gains} and record["dtype"] == "float64"
    assert record["gains"]["robust-tuned"] == tuned_json(loop.params)
    assert record["gains"]["paper (k_r = 54)"] == tuned_json(paper_feasible_gains(QUICK))
    assert json.loads((out / "robustness.json").read_text())["dtype"] == "float64"
    # Both studies run the file's robot; the paper's gains are scaled into its budget.
    assert same_robot(runs["monte carlo"]["robot"], QUICK)
    sets, kwargs = runs["standard"]
    assert same_robot(kwargs["robot"], QUICK)
    assert sets["paper (k_r = 54)"] == paper_feasible_gains(QUICK)
    assert same_robot(sets["robust-tuned"].robot, QUICK)
    assert "robot custom (L = 4 cm, V_max = 90 cm/s" in printed
    assert f"horizon {QUICK_HORIZON:g} s" in printed
    # Success as percentages, as the README prints them, in the printed tables.
    assert "| noise | aicardi | 0.5 | 99.8 % | 1 | 50 % |" in printed
    assert "| model robot | paper (k_r = 54) | raw | 100 % | 1 | 1 | 0 % |" in printed
    assert "| 100 % |" in (out / "standard_conditions.md").read_text()
    for name in ("standard_conditions.json", "robustness.json"):
        assert json.loads((out / name).read_text())["robot"] == robot_json(QUICK)
    # Another dtype reads as such.
    assert main([*argv, "--robust-gains", gains, "--float32"]) == 0
    for name in ("standard_conditions.json", "robustness.json"):
        assert json.loads((out / name).read_text())["dtype"] == "float32"
    capsys.readouterr()
    # A --robot other than the file's is refused in one line.
    assert main([*argv, "--robust-gains", gains, "--robot", "paper"]) == 2
    err = capsys.readouterr().err
    assert "--robot 'paper' is not allowed with --robust-gains" in err and err.count("\n") == 1


def test_a_file_is_labelled_by_the_problem_that_tuned_it_not_by_the_flag(tmp_path, capsys):
    # Refused before any run: a nominal file given as --robust-gains would be
    # labelled "robust-tuned" in every table.
    gains = w.Gains(kr=50.0, k_theta=2.0)
    argv = ["robustness", "--out", str(tmp_path / "rob"), "--runs", "2"]
    for tuned_by, flag, other in (
        ("nominal", "--robust-gains", "--nominal-gains"),
        ("robust", "--nominal-gains", "--robust-gains"),
    ):
        path = _file(tmp_path, f"{tuned_by}.json", tuned_json(gains, tuning=tuned_by))
        assert main([*argv, flag, path]) == 2
        err = capsys.readouterr().err
        assert f"{flag} {path!r} is not allowed: its gains were tuned by `wmr-jax tune" in err
        assert f"(give this one as {other})" in err and err.count("\n") == 1
    assert not (tmp_path / "rob").exists()


def test_a_gain_file_is_read_once(tmp_path, monkeypatch, capsys):
    """Its gains and the problem that tuned it come from one reading: a pipe is read once."""
    import pathlib

    path = _file(tmp_path, "g.json", tuned_json(w.Gains(kr=50.0), tuning="nominal"))
    reads = []
    read_text = pathlib.Path.read_text

    def counted(self, *args, **kwargs):
        reads.append(str(self))
        return read_text(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "read_text", counted)
    argv = ["robustness", "--out", str(tmp_path / "rob"), "--robust-gains", path]
    assert main(argv) == 2  # refused (tuned nominally) before any run
    assert reads.count(path) == 1, reads
    assert "its gains were tuned by `wmr-jax tune`" in capsys.readouterr().err


# ---------------------------------------------------------------- runs that only settle late


def _metrics(arrival, first):
    arrival, first = np.array(arrival), np.array(first)
    ones = np.ones_like(arrival)
    return PoseMetrics(arrival, ones, ones, ones, ones, first)


def test_a_run_that_left_the_goal_and_is_back_only_at_the_end_has_not_arrived():
    horizon = 6.0
    m = _metrics(
        # arrived early; hovering, back at 5.9 s; slow but straight in; never
        [1.0, 5.9, 5.9, math.inf],
        [1.0, 0.8, 5.9, math.inf],
    )
    late = robustness.settled_at_horizon(m, horizon)
    assert late.tolist() == [False, True, False, False]
    row = robustness.summary_row(m, horizon)
    assert row["success"] == 0.75 and row["settled at horizon"] == 0.25
    assert row["mean arrival s"] == pytest.approx((1.0 + 5.9 + 5.9) / 3)
    assert row["mean arrival, not at horizon s"] == pytest.approx((1.0 + 5.9) / 2)
    assert "settled at horizon" not in robustness.summary_row(m)  # without a horizon: as before


def test_late_arrivals_need_first_arrivals_and_a_horizon():
    """evaluate_poses records no first arrivals: a one-line refusal, not a TypeError."""
    swept = studies.evaluate_poses(np.array([[30.0, 30.0, 0.0]]), w.Gains(), steps=20)
    assert swept.first_arrival is None
    for call in (robustness.settled_at_horizon, robustness.summary_row):
        with pytest.raises(ValueError, match=r"^m.first_arrival is None \(evaluate_poses"):
            call(swept, 6.0)
    with pytest.raises(ValueError, match=r"^m is a NoneType; allowed: a PoseMetrics"):
        robustness.settled_at_horizon(None, 6.0)
    m = _metrics([1.0], [1.0])
    for horizon in (None, -1.0, math.nan, "6"):
        with pytest.raises(ValueError, match=r"^horizon = .* is not allowed"):
            robustness.settled_at_horizon(m, horizon)


def _standard_rows():
    base = {"mean final distance cm": 0.5, "mismatch": 0.03, "runs": 400, "feedback": "raw"}
    return [
        {**base, "condition": "nominal", "gains": "a", "success": 1.0, "mean arrival s": 0.5,
         "median arrival s": 0.5, "settled at horizon": 0.0,
         "mean arrival, not at horizon s": 0.5},
        # Every success only settles at the horizon: no arrival time to draw.
        {**base, "condition": "noise", "gains": "a", "success": 0.678, "mean arrival s": 5.72,
         "median arrival s": 5.8, "settled at horizon": 0.678,
         "mean arrival, not at horizon s": math.inf},
    ]  # fmt: skip


def test_the_standard_figure_draws_no_arrival_bar_at_the_horizon():
    fig = standard_figure(_standard_rows())
    try:
        success, arrival = fig.axes[:2]
        heights = [p.get_height() for p in arrival.patches]
        assert max(heights) == pytest.approx(0.5)  # no bar at 5.72 s
        hatched = [p for p in success.patches if p.get_hatch()]
        assert [p.get_height() for p in hatched] == pytest.approx([0.0, 0.678])
        assert any("horizon" in t.get_text() for t in arrival.texts)
    finally:
        plt.close(fig)


def test_tables_print_success_as_percentages():
    table = robustness_table(_standard_rows(), ["condition", "success", "mean arrival s"])
    assert "| nominal | 100 % | 0.5 | 0 % |" in table
    assert "| noise | 67.8 % | 5.72 | 67.8 % |" in table
    assert table.splitlines()[0] == "| condition | success | mean arrival s | settled at horizon |"
    # No run arrived: said in words, not as inf.
    failed = {**_standard_rows()[1], "condition": "latency", "success": 0.0}
    failed.update({"mean arrival s": math.inf, "median arrival s": math.inf})
    failed.update({"settled at horizon": 0.0, "median first arrival s": math.inf})
    columns = ["condition", "mean arrival s", "median arrival s", "mean arrival, not at horizon s"]
    rows = [{**_standard_rows()[0], "median first arrival s": 0.4}, failed]
    table = robustness_table(rows, [*columns, "median first arrival s"])
    failed_row = "| latency | none arrived | none arrived | 0 % | none before the horizon |"
    assert f"{failed_row} none arrived |" in table
    assert "| nominal | 0.5 | 0.5 | 0 % | 0.5 | 0.4 |" in table
    assert "inf" not in table
