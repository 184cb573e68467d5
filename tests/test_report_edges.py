"""Bad input to the reporting layer and its files: a named ValueError, nothing half-written."""

from __future__ import annotations

import gc
import json
import math
from types import SimpleNamespace

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import pytest

from wmr_jax._src.report import animation
from wmr_jax.report import (
    ROBUSTNESS_COLUMNS as _ROBUSTNESS_COLUMNS,
)
from wmr_jax.report import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    bench_table,
    comparison_table,
    evaluation_table,
    frame_timing,
    load_arrays,
    map_figure,
    markdown_table,
    paper_summary_table,
    path_figure,
    plot_paths,
    plot_wheel_speeds,
    save_arrays,
    save_comparison,
    save_figure,
    save_map_study,
    standard_figure,
    tuning_curve,
    winner_figure,
    write_gif,
    write_robustness,
    write_standard_conditions,
)
from wmr_jax.studies import MapStudy, PoseMetrics, pose_grid

INF = math.inf
# A GIF whose encoding is made to fail leaves an animation never rendered.
pytestmark = pytest.mark.filterwarnings("ignore:Animation was deleted")


# ---------------------------------------------------------------- save_arrays


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"a": None}, "arrays['a'] = None is not allowed"),
        ({"a": {"x": 1}}, "arrays['a'] = {'x': 1} is not allowed"),
        ({"a": np.array([object()])}, "arrays['a']"),
        ({"a": [[1.0], [1.0, 2.0]]}, "arrays['a']"),
        ({"__meta__": np.ones(2)}, "arrays name = '__meta__' is not allowed"),
        ({"__sha256__": np.ones(2)}, "arrays name = '__sha256__' is not allowed"),
        ({1: np.ones(2)}, "arrays name = 1 is not allowed"),
        ([np.ones(2)], "arrays = [array"),
    ],
)
def test_save_arrays_refuses_what_load_arrays_cannot_read(tmp_path, arrays, message):
    path = tmp_path / "a.npz"
    with pytest.raises(ValueError, match="allowed") as err:
        save_arrays(path, arrays, {})
    assert message in str(err.value)
    assert not list(tmp_path.iterdir())  # nothing written


def test_save_arrays_refuses_a_meta_json_cannot_store(tmp_path):
    with pytest.raises(ValueError, match="meta = "):
        save_arrays(tmp_path / "a.npz", {"a": np.ones(2)}, {"x": {1, 2}})
    assert not list(tmp_path.iterdir())


def test_save_arrays_still_round_trips(tmp_path):
    arrays = {"a": np.arange(3.0), "s": np.asarray("text"), "b": np.array([True, False])}
    save_arrays(tmp_path / "a.npz", arrays, {"inf": INF})
    got, meta = load_arrays(tmp_path / "a.npz")
    assert set(got) == set(arrays) and meta == {"inf": "inf"}
    for k, v in arrays.items():
        np.testing.assert_array_equal(got[k], v)


# ---------------------------------------------------------------- own JSON read back


def _summary_row(name, **changes):
    row = {
        "controller": name,
        "poses": 4,
        "success": 0.5,
        "mean arrival s": 2.0,
        "median arrival s": INF,
        "p90 arrival s": math.nan,
        "mean path cm": 40.0,
        "mean peak wheel cm/s": 100.0,
        "max peak wheel cm/s": INF,
        "over V_max": 0.25,
        "mean zigzag": -INF,
        "any zigzag": 0.0,
        "faster than shim_sung": 0.5,
    }
    return {**row, **changes}


def _through_json(tmp_path, obj):
    atomic_write_json(tmp_path / "x.json", obj)
    with open(tmp_path / "x.json") as f:
        return json.load(f)


def test_comparison_table_accepts_its_own_json(tmp_path):
    rows = [_summary_row("a"), _summary_row("b", success=1.0)]
    loaded = _through_json(tmp_path, rows)
    assert loaded[0]["median arrival s"] == "inf" and loaded[0]["p90 arrival s"] == "nan"
    table = comparison_table(loaded)
    assert table == comparison_table(rows)
    assert "2 / inf / nan" in table and "100 / inf" in table and "-inf" in table


def test_comparison_table_names_a_bad_number():
    with pytest.raises(ValueError, match=r"rows\[0\]\['success'\] = 'many' is not allowed"):
        comparison_table([_summary_row("a", success="many")])
    with pytest.raises(ValueError, match=r"rows\[0\] has no 'mean path cm'"):
        comparison_table([{k: v for k, v in _summary_row("a").items() if k != "mean path cm"}])


def _paper_summary():
    case = {
        "k_r + L k_theta": 180.0,
        "condition": "violated",
        "max_deviation_cm": INF,
        "mean_deviation_cm": math.nan,
        "ideal_arrival_s": 1.5,
        "nonideal_arrival_s": INF,
        "ideal_zigzag": 0.0,
        "nonideal_zigzag": 2.0,
        "ideal_saturated_fraction": 0.1,
        "nonideal_saturated_fraction": 0.0,
    }
    return {"fig6": {"phi_m_deg": 70.0, "bound_cm": 1.6}, "kr=120": case}


def test_paper_summary_table_accepts_its_own_json(tmp_path):
    summary = _paper_summary()
    loaded = _through_json(tmp_path, {"summary": summary})["summary"]
    assert loaded["kr=120"]["max_deviation_cm"] == "inf"
    table = paper_summary_table(loaded, 125.0)
    assert table == paper_summary_table(summary, 125.0)
    assert "inf / nan" in table and "1.5 / inf" in table


# ---------------------------------------------------------------- empty inputs


def _grid_and_metrics(n=None):
    grid = pose_grid(40, (0.0,))
    n = len(grid.refs) if n is None else n
    arrival = np.where(np.arange(n) % 3 == 0, INF, 1.0 + np.arange(n) / n)
    m = PoseMetrics(arrival, np.full(n, 30.0), np.linspace(50, 150, n), np.zeros(n), np.zeros(n))
    return grid, m


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda d: write_robustness(d, [], seed=0, velocity="ideal", n_runs=1), "rows = []"),
        (lambda d: write_standard_conditions(d, [], meta={}), "rows = []"),
        (lambda d: comparison_table([]), "rows = []"),
        (lambda d: markdown_table([]), "rows = []"),
        (lambda d: evaluation_table({}), "evaluation = {}"),
        (lambda d: bench_table({}), "result = {}"),
        (lambda d: paper_summary_table({}, 125), "summary has no gain"),
        (lambda d: standard_figure([]), "rows = []"),
        (lambda d: winner_figure(d / "w.png", _grid_and_metrics()[0], {}), "results = {}"),
    ],
)
def test_empty_inputs_are_named(tmp_path, call, message):
    with pytest.raises(ValueError, match="allowed") as err:
        call(tmp_path)
    assert message in str(err.value)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- no half-written sets


def _robustness_row(**changes):
    row = dict.fromkeys(_ROBUSTNESS_COLUMNS, 1.0)
    row.update(condition="nominal", controller="shim_sung", **changes)
    return row


def test_write_robustness_checks_everything_before_writing(tmp_path):
    with pytest.raises(ValueError, match="rows = "):
        write_robustness(
            tmp_path, [_robustness_row(extra={1, 2})], seed=0, velocity="ideal", n_runs=1
        )
    assert not list(tmp_path.iterdir())
    written = write_robustness(tmp_path, [_robustness_row()], seed=0, velocity="ideal", n_runs=1)
    assert sorted(p.name for p in written) == ["robustness.json", "robustness.md", "robustness.png"]
    # A dtype is recorded when the caller says it, never guessed.
    assert "dtype" not in json.loads((tmp_path / "robustness.json").read_text())
    for x64, dtype in ((False, "float32"), (True, "float64")):
        write_robustness(tmp_path, [_robustness_row()], seed=0, velocity="ideal", n_runs=1, x64=x64)
        assert json.loads((tmp_path / "robustness.json").read_text())["dtype"] == dtype
    # The controllers' feedback, as the rows give it, heads the table.
    head = (tmp_path / "robustness.md").read_text().splitlines()[0]
    assert head.startswith("Robustness Monte Carlo (ideal loop, seed 0, 1 runs")  # rows say none
    for feedback, said in (("raw", "raw feedback, "), ("ekf", "the ekf, ")):
        rows = [_robustness_row(feedback=feedback)]
        write_robustness(tmp_path, rows, seed=0, velocity="ideal", n_runs=1)
        head = (tmp_path / "robustness.md").read_text().splitlines()[0]
        assert head.startswith(f"Robustness Monte Carlo (ideal loop, {said}seed 0")


def test_write_standard_conditions_checks_everything_before_writing(tmp_path):
    row = {
        "condition": "latency",
        "gains": "paper",
        "feedback": "raw",
        "success": 1.0,
        "mean arrival s": 2.0,
        "median arrival s": 2.0,
        "mean final distance cm": 0.1,
        "mismatch": 0.03,
        "runs": 4,
    }
    with pytest.raises(ValueError, match="rows = "):
        write_standard_conditions(tmp_path, [{**row, "bad": object()}], meta={})
    with pytest.raises(ValueError, match=r"rows\[0\] has no column 'runs'"):
        write_standard_conditions(
            tmp_path, [{k: v for k, v in row.items() if k != "runs"}], meta={}
        )
    assert not list(tmp_path.iterdir())
    assert len(write_standard_conditions(tmp_path, [row], meta={"seed": 0})) == 3


def test_save_comparison_checks_the_rows_before_writing(tmp_path):
    comparison = {
        "poses": 4,
        "seed": 0,
        "velocity": "ideal",
        "horizon_s": 6.0,
        "dtype": "float64",
        "rows": [{"controller": "a"}],
    }
    with pytest.raises(ValueError, match=r"rows\[0\] has no 'success'"):
        save_comparison(tmp_path, comparison)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="comparison = "):
        save_comparison(tmp_path, {"rows": []})
    comparison["rows"] = [_summary_row("a")]
    paths = save_comparison(tmp_path, comparison)
    assert {p.name for p in paths} == {"comparison.json", "comparison.md"}


# ---------------------------------------------------------------- markdown_table


def test_markdown_table_keeps_sign_escapes_and_formats_numpy_and_jax():
    text = markdown_table(
        [
            {
                "a|b": -INF,
                "text": "x|y\nz",
                "f32": np.float32(0.1),
                "jax": jnp.float32(1 / 3),
                "big": np.float32(123456.0),
            }
        ]
    )
    header, _, row = text.splitlines()
    assert header == r"| a\|b | text | f32 | jax | big |"
    assert row == r"| -inf | x\|y z | 0.1 | 0.333 | 1.235e+05 |"


def test_markdown_table_names_a_missing_column():
    with pytest.raises(ValueError, match=r"rows\[1\] has no column 'b'"):
        markdown_table([{"a": 1, "b": 2}, {"a": 3}])
    with pytest.raises(ValueError, match=r"rows\[0\] = 3 is not allowed"):
        markdown_table([3])


# ---------------------------------------------------------------- maps


def test_map_figures_refuse_metrics_of_another_grid(tmp_path):
    grid, _ = _grid_and_metrics()
    n = len(grid.refs)
    _, m = _grid_and_metrics(n + 5)
    with pytest.raises(ValueError, match=rf"m.arrival has {n + 5} values; allowed: .*{n}"):
        map_figure(tmp_path / "m.png", grid, m)
    with pytest.raises(ValueError, match=rf"results\['b'\].arrival has {n + 5} values"):
        winner_figure(tmp_path / "w.png", grid, {"a": _grid_and_metrics()[1], "b": m})
    assert not list(tmp_path.iterdir())


def test_save_map_study_checks_every_controller_before_writing(tmp_path):
    grid, good = _grid_and_metrics()
    _, bad = _grid_and_metrics(len(grid.refs) - 1)
    summary = {"poses": len(grid.refs), "velocity": "ideal", "horizon_s": 6.0, "dtype": "float64"}
    study = MapStudy(grid, {"a": good, "b": bad}, {**summary, "rows": [_summary_row("a")]})
    with pytest.raises(ValueError, match=r"study.results\['b'\].arrival has"):
        save_map_study(tmp_path, study)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- figures closed on error


def _history():
    return {"loss": np.ones(3), "temperature": np.ones(3), "gains": np.ones((3, 7))}


@pytest.mark.parametrize(
    "call",
    [
        lambda p: path_figure(
            p / "x.nosuchformat", SimpleNamespace(poses=np.zeros((4, 3))), (1, 1, 0), title=""
        ),
        lambda p: tuning_curve(p / "x.nosuchformat", _history()),
        lambda p: map_figure(p / "x.nosuchformat", *_grid_and_metrics()),
        lambda p: winner_figure(
            p / "x.nosuchformat", _grid_and_metrics()[0], {"a": _grid_and_metrics()[1]}
        ),
    ],
)
def test_a_failing_figure_is_closed(tmp_path, call):
    # Each fails when saving, after its figure was drawn.
    before = plt.get_fignums()
    with pytest.raises(ValueError, match=r"nosuchformat"):
        call(tmp_path)
    assert plt.get_fignums() == before


def test_a_failing_gif_closes_its_figure(tmp_path, monkeypatch):
    def fail(*args):
        raise RuntimeError("encoding failed")

    monkeypatch.setattr(animation, "_save", fail)
    before = plt.get_fignums()
    with pytest.raises(RuntimeError):
        write_gif(tmp_path / "x.gif", np.zeros((1, 3, 3)), np.ones((1, 3)))
    assert plt.get_fignums() == before
    gc.collect()  # the unrendered animation warns here (ignored), not in a later test


@pytest.mark.parametrize(
    "kwargs, message",
    [({"trail": "a"}, "trail = 'a'"), ({"body_radius": -1.0}, "body_radius = -1.0")],
)
def test_write_gif_names_bad_drawing_options(tmp_path, kwargs, message):
    with pytest.raises(ValueError, match="allowed") as err:
        write_gif(tmp_path / "x.gif", np.zeros((1, 3, 3)), np.ones((1, 3)), **kwargs)
    assert message in str(err.value)


# ---------------------------------------------------------------- GIF delays


def test_gif_delays_beyond_a_gif_are_named(tmp_path):
    with pytest.raises(ValueError, match=r"dt = 1e\+30 s .*at most 655.35 s per frame"):
        frame_timing(1e30)
    with pytest.raises(ValueError, match="speed = 1e-300"):
        frame_timing(0.033, 1, 1e-300)
    assert frame_timing(655.35, 1) == (1, 655_350)
    with pytest.raises(ValueError, match=r"dt = 1000000.0 s"):
        write_gif(tmp_path / "x.gif", np.zeros((1, 3, 3)), np.ones((1, 3)), dt=1e6)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- text and JSON writers


@pytest.mark.parametrize("text", [b"bytes", None])
def test_atomic_write_text_refuses_what_is_not_text(tmp_path, text):
    with pytest.raises(ValueError, match=r"text = .* is not allowed; allowed: a str"):
        atomic_write_text(tmp_path / "x.txt", text)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="data is a str; allowed: bytes"):
        atomic_write_bytes(tmp_path / "a.bin", "abc")


def test_atomic_write_json_names_a_value_json_cannot_store(tmp_path):
    with pytest.raises(ValueError, match=r"obj = \{'a': \{1, 2\}\} is not allowed .*set"):
        atomic_write_json(tmp_path / "x.json", {"a": {1, 2}})
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda ax: plot_paths(ax, [np.zeros((5, 3)), np.zeros((5, 3))], np.zeros((1, 3))),
            r"refs has shape \(1, 3\); allowed: \(M, 3\) with M >= 2",
        ),
        (lambda ax: plot_paths(ax, [np.zeros((5, 2))], np.zeros((1, 3))), r"paths\[0\] has shape"),
        (
            lambda ax: plot_paths(ax, [np.zeros((5, 3))], np.zeros((1, 3)), heading_spacing=0),
            r"heading_spacing = 0 is not allowed",
        ),
        (
            lambda ax: plot_wheel_speeds(ax, np.zeros((5, 3)), dt=0.1),
            r"wheel_speeds has shape \(5, 3\)",
        ),
        (
            lambda ax: plot_wheel_speeds(ax, np.zeros((5, 2)), dt=0.1, labels=("a",)),
            r"labels = \('a',\) is not allowed",
        ),
        (lambda ax: plot_wheel_speeds(ax, np.zeros((5, 2)), dt=-0.1), r"dt = -0.1"),
        (
            lambda ax: plot_wheel_speeds(ax, np.zeros((5, 2)), dt=0.1, v_max="125"),
            r"v_max = '125' is not allowed",
        ),
        # matplotlib leaves a gap at NaN: a run that left the range would look merely short.
        (
            lambda ax: plot_paths(ax, [np.array([[0.0, 0, 0], [np.nan, 0, 0]])], np.zeros((1, 3))),
            r"paths\[0\] = .*\[1, 0\] = nan\) is not allowed; allowed: finite poses",
        ),
        (lambda ax: save_figure("fig", "a.png"), r"fig is a str; allowed: a matplotlib Figure"),
        (lambda ax: save_figure(ax.figure, 3), r"path = 3 is not allowed"),
        (lambda ax: path_figure("a.png", 3, [1.0, 2.0, 0.0], title=""), r"traj is a int"),
    ],
)
def test_drawing_helpers_name_what_they_cannot_draw(call, message):
    fig, ax = plt.subplots()
    try:
        with pytest.raises(ValueError, match=message):
            call(ax)
    finally:
        plt.close(fig)


def test_tuning_curve_names_an_unknown_problem_and_gains_of_another(tmp_path):
    history = {"loss": np.ones(3), "temperature": np.ones(3), "gains": np.ones((3, 7))}
    with pytest.raises(ValueError, match=r"problem = 'schedul' is not allowed"):
        tuning_curve(tmp_path / "c.png", history, problem="schedul")
    from wmr_jax._src.tuning.problems import get_problem

    columns = len(get_problem("schedule").columns)
    with pytest.raises(
        ValueError, match=rf"history\['gains'\] has shape \(3, 7\); allowed: \(3, {columns}\)"
    ):
        tuning_curve(tmp_path / "c.png", history, problem="schedule")
    assert not (tmp_path / "c.png").exists()


def test_animation_title_names_the_start_it_was_given():
    from wmr_jax._src.report.animation import _start, run_title

    assert run_title("aicardi", "ideal", 2) == "aicardi, ideal loop: 2 robots from (0, 0, 0°)"
    assert _start((0.0, 0.0, 0.0)) == "(0, 0, 0°)"
    assert _start((50.0, -5.0, math.pi / 2)) == "(50, -5, 90°)"
    assert _start([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]) == "their initial poses"


def test_json_writer_refuses_keys_that_collide_and_objects_that_contain_themselves(tmp_path):
    with pytest.raises(ValueError, match=r"keys '1', 1 collide as JSON names"):
        atomic_write_json(tmp_path / "a.json", {1: "a", "1": "b"})
    loop: dict = {}
    loop["self"] = loop
    with pytest.raises(ValueError, match=r"obj is not allowed: it contains itself"):
        atomic_write_json(tmp_path / "b.json", loop)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dtype", [complex, bool])
def test_gif_poses_must_be_real_numbers(tmp_path, dtype):
    with pytest.raises(ValueError, match=r"poses holds (bools|complex numbers); allowed: real"):
        write_gif(tmp_path / "a.gif", np.zeros((1, 3, 3), dtype), np.zeros((1, 3)))
    assert not (tmp_path / "a.gif").exists()


def test_bench_table_names_a_missing_entry_of_the_environment():
    result = {
        "environment": {"device": "cpu"},
        "config": {"dtype": "float32", "steps": 10, "repeats": 1},
        "rows": [{"case": "final_poses", "n": 10}],
    }
    with pytest.raises(ValueError, match=r"result\['environment'\] has no 'backend'"):
        bench_table(result)


def test_writers_refuse_a_folder_or_no_path_and_tables_impossible_rates(tmp_path):
    with pytest.raises(ValueError, match=r"path = '' is not allowed; allowed: a file path"):
        atomic_write_text("", "x")
    with pytest.raises(ValueError, match=r"is a folder; allowed: a file path"):
        atomic_write_text(tmp_path, "x")
    from wmr_jax.tuning import Evaluation

    table = {"paper_feasible": Evaluation(2.0, 5.0, 100.0, 10)}
    with pytest.raises(ValueError, match=r"success_rate = 5.0 is not allowed; allowed: a fraction"):
        evaluation_table(table)


@pytest.mark.parametrize("name", ["run", "run.xyz", "run.gif.txt"])
def test_figures_refuse_a_path_that_names_no_image_format(tmp_path, name):
    # Without the check, "run" got PNG bytes under no ending and "run.gif.txt"
    # matplotlib's error about "txt".
    before = plt.get_fignums()
    with pytest.raises(ValueError, match=rf"path = '.*{name}' is not allowed; allowed: .*\.png"):
        path_figure(tmp_path / name, SimpleNamespace(poses=np.zeros((4, 3))), (1, 1, 0), title="")
    assert plt.get_fignums() == before
    assert not list(tmp_path.iterdir())
    written = path_figure(
        tmp_path / "run.SVG", SimpleNamespace(poses=np.zeros((4, 3))), (1, 1, 0), title=""
    )
    assert written is None and (tmp_path / "run.SVG").read_bytes().lstrip().startswith(b"<?xml")


@pytest.mark.parametrize("name", ["run.png", "run", "gif"])
def test_gifs_refuse_a_path_not_ending_in_gif(tmp_path, name):
    # A .png path used to get GIF bytes.
    with pytest.raises(ValueError, match=rf"path = '.*{name}' is not allowed; allowed: .*\.gif"):
        write_gif(tmp_path / name, np.zeros((1, 3, 3)), np.ones((1, 3)))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"loss": np.ones(2)},
            r"history\['loss'\] has 2 iterations and history\['temperature'\] 3",
        ),
        (
            {"temperature": [1.0, 1.0, 0.0]},
            r"history\['temperature'\] = .*0\.0.*finite numbers > 0",
        ),
        ({"loss": "abc"}, r"history\['loss'\] = 'abc' is not allowed; allowed: real numbers"),
        ({"loss": np.ones((3, 1))}, r"history\['loss'\] has shape \(3, 1\)"),
        ({"gains": [[True] * 7] * 3}, r"history\['gains'\] = .*True.*allowed: real numbers"),
    ],
)
def test_tuning_curve_checks_the_values_of_the_history(tmp_path, change, message):
    # A short loss used to fail inside matplotlib, a zero temperature vanished
    # from the log axis and bools were drawn as gains.
    with pytest.raises(ValueError, match=message):
        tuning_curve(tmp_path / "curve.png", {**_history(), **change})
    assert not list(tmp_path.iterdir())


def _contains_itself() -> dict:
    loop: dict = {}
    loop["self"] = loop
    return loop


def test_paper_fig7_and_soccer_writers_check_everything_before_the_first_file(tmp_path):
    # Stand-ins whose record cannot be written as JSON: each writer must fail
    # before it writes a figure or a table, leaving the folder empty.
    from wmr_jax._src.report.paper import _SUMMARY_NUMBERS, _TABLE_COLUMNS
    from wmr_jax.report import save_fig7, save_paper, write_soccer
    from wmr_jax.studies import SoccerStudy

    rows = [{"case": "a", "value": 1.0}]
    paper = SimpleNamespace(
        robot=SimpleNamespace(v_max=125.0),
        runs=[dict.fromkeys(_TABLE_COLUMNS, 1.0)],
        summary={"kr=60": {"condition": "met", **dict.fromkeys(_SUMMARY_NUMBERS, 1.0)}},
        table=_contains_itself,
    )
    fig7 = SimpleNamespace(gains=None, rows=rows, table=_contains_itself)
    soccer = SoccerStudy(
        rows=rows,
        runs=[],
        velocity=_contains_itself(),
        steps=10,
        pass_tol_r=1.0,
        pass_tol_theta=0.1,
    )
    for write, arg in ((save_paper, paper), (save_fig7, fig7), (write_soccer, soccer)):
        with pytest.raises(ValueError, match="contains itself"):
            write(tmp_path / "out", arg)
        assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_tuning_curve_marks_non_finite_losses_instead_of_a_silent_gap(tmp_path):
    import matplotlib.pyplot as plt

    from wmr_jax._src.report import figures

    drawn = []
    real = figures.closed_after

    def spy(*args, **kwargs):
        context = real(*args, **kwargs)

        class Keep:
            def __enter__(self):
                fig, axes = context.__enter__()
                drawn.append(axes[0, 0])
                return fig, axes

            def __exit__(self, *exc):
                drawn.append(drawn[-1].get_title())
                return context.__exit__(*exc)

        return Keep()

    history = {**_history(), "loss": np.array([1.0, np.nan, np.inf])}
    figures.closed_after = spy
    try:
        tuning_curve(tmp_path / "curve.png", history)
    finally:
        figures.closed_after = real
        plt.close("all")
    assert "2 non-finite or non-positive, marked ×" in drawn[-1]
    assert (tmp_path / "curve.png").exists()


def _robust_rows(horizon):
    """A seed of ``tune --robust --compare``: half the runs arrive at 2 s under each condition."""
    return [
        {"condition": condition, "method": "gradient", "seed": 0, "budget_s": 10.0,
         "candidates": 3, "success": 0.5, "mean arrival s": 2.0, "horizon s": horizon,
         "price": 4.0, "measured_price": 4.0, "budget_candidates": 12, "cpu_s": 10.0,
         "wall_s": 11.0, "per_cpu_s": 0.3}
        for condition in ("model robot", "nominal", "latency", "noise", "both")
    ]  # fmt: skip


@pytest.mark.parametrize(("horizon", "failure"), [(38.2, 76.4), (6.0, 12.0)])
def test_the_robust_comparison_scores_failures_at_twice_each_rows_horizon(horizon, failure):
    # What the searches minimise (tuning.robust.condition_score): failures at twice
    # the horizon, on a slow robot too.
    from wmr_jax._src.report.tuning import robust_comparison_table

    table = robust_comparison_table(_robust_rows(horizon))
    score = 0.5 * 2.0 + 0.5 * failure
    line = next(line for line in table.splitlines() if "| gradient | 0 |" in line)
    assert f"| {score:.3f} |" in line, line
