"""What a user reads: per-reference results, units that look wrong, horizons, errors, progress."""

import io
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src.cli import simulate
from wmr_jax._src.cli.main import main
from wmr_jax._src.report import progress
from wmr_jax._src.studies import conditions
from wmr_jax._src.tuning.saved import tuned_json

REFS = np.array([[30.0, 20.0, 0.3], [-20.0, 15.0, 1.0], [25.0, -10.0, -0.5]])


def _file(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _gains(tmp_path, gains=None):
    return _file(tmp_path, "g.json", json.dumps(tuned_json(gains or w.Gains(kr=60.0))))


# ---------------------------------------------------------------- evaluate, per reference


def test_each_reference_has_its_own_result_in_the_library():
    # Two within reach in 2 s and one 400 cm away, which the paper's gains cannot reach in 2 s.
    refs = np.array([[30.0, 20.0, 0.3], [400.0, 0.0, 0.0], [-20.0, 15.0, 1.0]])
    result = conditions.evaluate_loop(w.Gains(kr=60.0), refs, horizon=2.0, mismatch=0.0)
    per = result["per_reference"]
    assert [r["success"] for r in per] == [True, False, True]
    assert [r["ref"] for r in per] == refs.tolist()
    assert per[1]["arrival_s"] is None and per[1]["final_distance_cm"] > 100.0
    # Each arrival is that of the single rollout of its reference (nominal, model robot).
    for ref, r in zip(refs[[0, 2]], (per[0], per[2]), strict=True):
        traj = w.rollout(ref, w.Gains(kr=60.0), steps=math.ceil(2.0 / w.DEFAULT_DT))
        expected = float(w.arrival_time(traj, ref, dt=w.DEFAULT_DT))
        assert r["arrival_s"] == pytest.approx(expected, abs=1e-9)
        final = np.asarray(traj.poses[-1])
        assert r["final_distance_cm"] == pytest.approx(np.hypot(*(final[:2] - ref[:2])), abs=1e-6)
        assert r["settled_at_horizon"] is False
    # The summary is the mean over the list.
    assert result["success"] == pytest.approx(2 / 3)


def test_evaluate_names_the_references_that_failed_and_writes_them_all(capsys, tmp_path):
    refs = _file(tmp_path, "refs.csv", "x_cm,y_cm,theta_rad\n30,20,0.3\n400,0,0\n-20,15,1\n")
    per_ref, out_json = tmp_path / "per.csv", tmp_path / "out.json"
    argv = ["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "2"]
    assert main([*argv, "--per-ref", str(per_ref), "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert "| not arrived | line 3 |" in out  # the file's own line numbers, header counted
    lines = per_ref.read_text().splitlines()
    assert lines[0].startswith("where,x_cm,y_cm,theta_rad,arrived,arrival_s,final_distance_cm")
    assert [line.split(",")[:5] for line in lines[1:]] == [
        ["line 2", "30", "20", "0.3", "true"],
        ["line 3", "400", "0", "0", "false"],
        ["line 4", "-20", "15", "1", "true"],
    ]
    assert lines[2].split(",")[5] == ""  # no arrival time where it did not arrive
    saved = json.loads(out_json.read_text())["per_reference"]
    assert [r["success"] for r in saved] == [True, False, True]
    assert float(lines[1].split(",")[5]) == pytest.approx(saved[0]["arrival_s"], rel=1e-5)


def test_many_failures_are_counted_not_all_listed(capsys, tmp_path):
    far = "".join(f"{400 + k},0,0\n" for k in range(7))
    refs = _file(tmp_path, "refs.csv", far)
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "1"]) == 0
    out = capsys.readouterr().out
    assert "| not arrived | line 1, line 2, line 3, line 4, line 5 and 2 more (--per-ref" in out


def test_a_bad_per_ref_path_is_refused_before_the_run(capsys, tmp_path):
    refs = _file(tmp_path, "refs.csv", "30,20,0.3\n")
    argv = ["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--per-ref", "/dev/null/x"]
    assert main(argv) == 2
    assert "--per-ref '/dev/null/x' is not allowed" in capsys.readouterr().err


# ---------------------------------------------------------------- references in another unit


def test_references_in_metres_are_warned_about(capsys, tmp_path):
    refs = _file(tmp_path, "refs.csv", "0.3,0.2,0.8\n-0.4,0.1,3.1\n")
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "1"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wmr-jax: warning: --refs {refs!r}: every ")
    assert "within 1 cm of the start" in err[0] and "metres" in err[0]


def test_headings_in_degrees_are_warned_about(capsys, tmp_path):
    refs = _file(tmp_path, "refs.csv", "30,20,45\n-40,10,180\n")
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "1"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "headings up to 180 look like degrees" in err[0]


def test_references_in_cm_and_radians_pass_without_a_word(capsys, tmp_path):
    # Not every reference within 1 cm of the start, a heading just below 2π:
    # neither warning. Two references, as in the two warned files above, so
    # the three tests run one compiled program.
    refs = _file(tmp_path, "refs.csv", "30,20,0.8\n0.5,0,6.2\n")
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "1"]) == 0
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------- what each number is


def test_the_peak_rim_speed_beside_v_max_says_it_includes_the_mismatch(capsys, tmp_path):
    refs = _file(tmp_path, "refs.csv", "30,20,0.3\n")
    argv = ["evaluate", "--gains", _gains(tmp_path, w.Gains(kr=120.0, k_theta=1.0))]
    assert main([*argv, "--refs", refs, "--horizon", "2"]) == 0
    out = capsys.readouterr().out
    assert "cm/s at the rims, wheel-radius mismatch included |" in out
    # 125 cm/s × 1.03: the rim speed a command within V_max may reach.
    assert "a wheel up to 3 % larger than modelled turns that into up to 128.8 cm/s" in out
    assert main([*argv, "--refs", refs, "--horizon", "2", "--mismatch", "0"]) == 0
    out = capsys.readouterr().out
    assert "| V_max | 125 cm/s, every wheel command within it |" in out
    assert "mismatch included" not in out


def test_a_failing_run_under_noise_points_to_robust_tuning(capsys, tmp_path):
    # Two references, as the files above: the program they compiled.
    refs = _file(tmp_path, "refs.csv", "400,0,0\n-400,0,0\n")
    argv = ["evaluate", "--gains", _gains(tmp_path), "--refs", refs, "--horizon", "1"]
    assert main([*argv, "--condition", "noise"]) == 0
    assert "hint: these gains were not tuned for this noise; wmr-jax tune --robust" in (
        capsys.readouterr().out
    )
    assert main([*argv, "--condition", "nominal"]) == 0  # not a matter of noise there
    assert "hint" not in capsys.readouterr().out


def test_runs_held_by_the_noise_until_the_horizon_call_for_the_hint_too():
    # Every run arrived, but half settled only at the horizon: counted as
    # arrived, yet the noise kept them off the goal until the end.
    import argparse

    from wmr_jax._src.cli.evaluate import hint
    from wmr_jax._src.model.robots import robot_json

    args = argparse.Namespace(robot=None)
    result = {"condition": "noise", "success": 1.0, "robot": robot_json(w.Robot())}
    result["feedback"] = "raw"
    assert hint({**result, "settled_at_horizon": 0.5}, args).startswith(
        "hint: these gains were not tuned for this noise"
    )
    assert hint({**result, "settled_at_horizon": 0.05}, args) == ""  # 95 % before it
    assert hint({**result, "settled_at_horizon": 0.06}, args) != ""
    assert hint({**result, "condition": "latency", "settled_at_horizon": 0.5}, args) == ""
    # A loop with a filter was tuned for noise, if not this one; a compiled one is exported again.
    tuned = {**result, "feedback": "ekf", "settled_at_horizon": 0.5}
    assert hint(tuned, args).startswith(
        "hint: fewer than 95 % of the runs arrived before the horizon under this noise; "
        "wmr-jax tune --robust --out DIR"
    )
    assert hint(tuned, argparse.Namespace(robot=None, c="ctl")).endswith(
        "then wmr-jax export --gains DIR/tuned_gains.json and evaluate --c its folder"
    )


def test_the_hint_names_the_robot_the_file_was_tuned_for(capsys, tmp_path):
    burger = w.ROBOTS["turtlebot3-burger"]
    gains = _file(
        tmp_path, "g.json", json.dumps(tuned_json(w.Gains(kr=9.0, k_theta=1.5), robot=burger))
    )
    refs = _file(tmp_path, "refs.csv", "400,0,0\n")
    argv = ["evaluate", "--gains", gains, "--refs", refs, "--horizon", "1", "--condition", "both"]
    assert main(argv) == 0
    assert "wmr-jax tune --robust --robot turtlebot3-burger --out DIR" in capsys.readouterr().out


# ---------------------------------------------------------------- simulate


def test_simulate_stretches_its_run_on_a_slow_robot(capsys):
    burger = w.ROBOTS["turtlebot3-burger"]
    # The studies' horizon, 37 s there against 6 s, stretches the 150 steps alike.
    assert simulate.default_steps(None) == 150
    assert simulate.default_steps(w.Robot()) == 150
    assert simulate.default_steps(burger) == math.ceil(150 * 37.0 / 6.0)
    argv = ["simulate", "--robot", "turtlebot3-burger", "--ref", "30", "20", "45"]
    assert main([*argv, "--k-r", "9.7", "--k-theta", "1.6"]) == 0
    out = capsys.readouterr().out
    assert f"after {925 * 0.033:.3f} s" in out and "arrival time   : never" not in out


def test_simulate_says_what_to_do_when_not_arrived(capsys):
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10"]) == 0
    out = capsys.readouterr().out
    assert "arrival time   : never (not arrived at the end)" in out
    assert "not arrived in 0.33 s; a longer run, such as --steps 40" in out
    # A far goal: three times the drive at V_max, 1000 cm / (125 cm/s) / 0.033 s = 242.4 periods.
    assert main(["simulate", "--ref", "1000", "0", "0", "--steps", "10"]) == 0
    assert "a longer run, such as --steps 728, shows" in capsys.readouterr().out
    assert main(["simulate", "--ref", "1e9", "0", "0", "--steps", "10"]) == 0
    assert "the goal is 1e+09 cm away, at least 8e+06 s at V_max = 125 cm/s: more than one run" in (
        capsys.readouterr().out
    )


def test_simulate_points_to_dt_when_the_sampled_law_cannot_settle(capsys, monkeypatch):
    from wmr_jax._src.cli import main as cli

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10", "--dt", "0.5"]) == 0
    out, err = capsys.readouterr()
    assert "warning: k_theta*dt = 5 and k_r*pi*dt/(2*R_m) = 4.71" in err
    assert "not arrived in 5 s; the sampled law cannot settle with these gains at this --dt" in out
    assert "a longer run" not in out


def test_simulate_warns_of_a_goal_inside_the_tolerance(capsys):
    assert main(["simulate", "--ref", "0.3", "0.3", "0", "--steps", "10"]) == 0
    assert "--ref lies 0.424 cm from the start, inside the arrival tolerance (1 cm)" in (
        capsys.readouterr().err
    )


@pytest.mark.parametrize(
    ("radians", "degrees"),
    [
        (math.radians(945.0), -135.0),
        (math.radians(180.0), 180.0),
        (math.radians(-180.0), 180.0),
        (math.radians(-30.0), -30.0),
        (math.radians(360.0), 0.0),
    ],
)
def test_simulate_prints_headings_wrapped(radians, degrees):
    assert simulate._degrees(radians) == pytest.approx(degrees, abs=1e-9)


def test_simulate_prints_the_reference_heading_wrapped(capsys):
    # Three steps, as the test below: one compiled run for both.
    assert main(["simulate", "--ref", "10", "0", "405", "--steps", "3"]) == 0
    assert "θ=45.00°" in capsys.readouterr().out


def test_simulate_names_the_files_it_runs(capsys, tmp_path):
    robot = _file(tmp_path, "bot.json", json.dumps({"half_track": 5.0, "v_max": 60.0}))
    assert main(["simulate", "--ref", "30", "20", "0", "--robot", robot, "--steps", "3"]) == 0
    out = capsys.readouterr().out
    assert "robot          : custom (L = 5 cm, V_max = 60 cm/s" in out
    assert f", from {robot}\n" in out
    gains = _gains(tmp_path)
    assert main(["simulate", "--ref", "30", "20", "0", "--gains", gains, "--steps", "3"]) == 0
    assert f"gains          : {gains} (shim-sung)\n" in capsys.readouterr().out


def test_the_plot_title_names_the_gains():
    ref = [30.0, 20.0, math.radians(45.0)]
    title = simulate.plot_title(ref, None, w.Gains(kr=9.7, k_theta=1.6), None)
    assert title == "ref = (30, 20, 45°); k_r = 9.7, k_θ = 1.6, Φ_m = 70°"
    title = simulate.plot_title(ref, None, w.Gains(kr=60.0), "results/tune/tuned_gains.json")
    assert title.endswith("k_r = 60, k_θ = 10, Φ_m = 70° (tuned_gains.json)")


# ---------------------------------------------------------------- errors in one voice


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["simulate", "--ref", "1", "2"], "wmr-jax: error: argument --ref: expected 3 arguments"),
        (
            ["simulate", "--ref", "1", "2", "3", "--gains", "{missing}"],
            "wmr-jax: error: --gains '{missing}' cannot be read: there is no such file\n",
        ),
        (
            ["evaluate", "--gains", "{missing}", "--refs", "{refs}"],
            "wmr-jax: error: --gains '{missing}' cannot be read: there is no such file\n",
        ),
        (
            ["robustness", "--nominal-gains", "{missing}", "--out", "{out}"],
            "wmr-jax: error: --nominal-gains '{missing}' cannot be read: there is no such file\n",
        ),
        (
            ["simulate", "--ref", "1", "2", "3", "--gains", "{refs}"],
            "wmr-jax: error: --gains '{refs}' is not a JSON gains file (not JSON at line 1 "
            "column 3); allowed: the tuned_gains.json of wmr-jax tune, or a JSON object of "
            "Gains fields\n",
        ),
        (
            ["simulate", "--ref", "1", "2", "3", "--gains", "{folder}"],
            "wmr-jax: error: --gains '{folder}' cannot be read: it is a folder\n",
        ),
    ],
)
def test_errors_have_one_prefix_and_one_wording(capsys, tmp_path, argv, expected):
    files = {
        "missing": str(tmp_path / "none.json"),
        "refs": _file(tmp_path, "refs.csv", "30,20,0.3\n"),
        "out": str(tmp_path / "out"),
        "folder": str(tmp_path),
    }
    try:
        status = main([part.format(**files) for part in argv])
    except SystemExit as exit_:  # the parser's own errors
        status = exit_.code
    assert status == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Errno" not in err
    assert err.startswith(expected.format(**files))


# ---------------------------------------------------------------- progress off a terminal


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_off_a_terminal_is_plain_lines():
    stream = io.StringIO()
    shown = progress.bar(total=4, desc="tune (ideal)", file=stream, dynamic_ncols=True)
    for _ in range(4):
        shown.update(1)
        shown.set_postfix(loss="0.5s", refresh=False)
    shown.close()
    text = stream.getvalue()
    assert "\r" not in text and "\x1b" not in text and "█" not in text
    lines = text.splitlines()
    assert lines and all(line.startswith("tune (ideal): ") for line in lines)
    assert lines[-1].startswith("tune (ideal): 4/4 [")
    # A bar made and never moved says nothing.
    stream = io.StringIO()
    progress.bar(total=3, desc="hard-law evaluation", file=stream).close()
    assert stream.getvalue() == ""


def test_progress_on_a_terminal_is_a_bar():
    stream = _Terminal()
    shown = progress.bar(total=4, desc="tune", file=stream)
    shown.update(4)
    shown.close()
    assert "\r" in stream.getvalue() and progress.on_terminal(stream)
    assert not progress.on_terminal(io.StringIO())


def test_sweep_written_to_a_file_has_no_bar_escapes(capsys, tmp_path):
    argv = ["sweep", "--out", str(tmp_path / "s"), "--poses", "6", "--chunk", "3"]
    argv += ["--controller", "shim-sung"]  # the bar is the same for every controller
    assert main([*argv, "--horizon", "0.2", "--headings", "0"]) == 0
    err = capsys.readouterr().err
    assert "sweep, " in err and "\r" not in err and "\x1b" not in err


# ---------------------------------------------------------------- the tuning curve


def _drawn_axes(monkeypatch, draw):
    """The axes ``draw`` drew on (their lines and titles), kept past the figure's closing."""
    from wmr_jax._src.report import figures

    kept = []
    real = figures.closed_after

    def spy(*args, **kwargs):
        context = real(*args, **kwargs)

        class Keep:
            def __enter__(self):
                fig, axes = context.__enter__()
                kept.append(axes)
                return fig, axes

            def __exit__(self, *exc):
                kept[-1] = [
                    (ax.get_title(), [(line.get_label(), line.get_ydata()) for line in ax.lines])
                    for ax in kept[-1].flat
                ]
                return context.__exit__(*exc)

        return Keep()

    monkeypatch.setattr(figures, "closed_after", spy)
    draw()
    return kept[-1]


def _history(iters=3):
    return {"loss": np.ones(iters), "temperature": np.ones(iters), "gains": np.ones((iters, 7))}


def test_the_tuning_curve_draws_the_baseline_of_the_robot_tuned_for(monkeypatch, tmp_path):
    from wmr_jax import report

    burger = w.ROBOTS["turtlebot3-burger"]
    panels = _drawn_axes(
        monkeypatch, lambda: report.tuning_curve(tmp_path / "c.png", _history(), robot=burger)
    )
    title, lines = panels[1]  # k_r
    assert title == "k_r (cm/s)"
    ((label, y),) = [(label, y) for label, y in lines if "paper" in label]
    # 60 · 22.72 / (60 + 8 · 10): the paper's gains scaled into the Burger's budget.
    assert y[0] == pytest.approx(60.0 * 22.72 / 140.0)
    assert label == "paper's, scaled into the wheel budget (k_r = 9.74, k_θ = 1.62)"
    panels = _drawn_axes(monkeypatch, lambda: report.tuning_curve(tmp_path / "c.png", _history()))
    ((label, y),) = [(label, y) for label, y in panels[1][1] if "paper" in label]
    assert label == "paper (feasible)" and y[0] == 60.0


def test_the_tuning_curve_marks_gains_it_cannot_draw(monkeypatch, tmp_path):
    from wmr_jax import report

    history = _history(4)
    history["gains"][1:3, 0] = [np.nan, np.inf]  # k_r at iterations 2 and 3
    panels = _drawn_axes(monkeypatch, lambda: report.tuning_curve(tmp_path / "c.png", history))
    title, lines = panels[1]
    assert title == "k_r (cm/s); 2 non-finite, marked ×"
    assert panels[2][0] == "k_θ (rad/s)"  # the others as they were
    drawn = [y for label, y in lines if not label.startswith("paper")]
    assert [len(y) for y in drawn] == [2, 2]  # the two finite values, then the two marks


# ---------------------------------------------------------------- the paper's figures


def _legends(monkeypatch, draw):
    """The legend of each figure ``draw`` saves: ``(title, [entries])``."""
    from wmr_jax._src.report import paper

    legends = []

    def keep(fig, path, **kwargs):
        legend = fig.axes[0].get_legend()
        legends.append(
            (Path(path).name, legend.get_title().get_text(), [t.get_text() for t in legend.texts])
        )
        return Path(path)

    monkeypatch.setattr(paper, "save_figure", keep)
    draw()
    return legends


def test_fig7_has_one_legend_entry_per_coloured_path(monkeypatch, tmp_path):
    from wmr_jax._src.report import paper
    from wmr_jax._src.studies import paper as runs

    fig7 = runs.fig7_runs()
    ((name, title, entries),) = _legends(monkeypatch, lambda: paper.save_fig7(tmp_path, fig7))
    assert name == "fig7.png" and title == "robot paths (ideal loop)"
    expected = [
        f"to ({x:g}, {y:g}, {math.degrees(theta):g}°)" for x, y, theta in np.asarray(fig7.refs)
    ]
    # Then the references, and the circle of the one the robot reaches backwards.
    backwards = "arrived backwards (θ = θ_r ± 180°)"
    assert len(expected) == 7 and entries == [*expected, "reference", backwards]


def test_fig9_keeps_one_entry_per_loop(monkeypatch, tmp_path):
    from wmr_jax._src.report import paper

    refs = np.array([[30.0, 20.0, 0.3], [-20.0, 15.0, 1.0]])
    traj = w.batch_rollout(refs, w.Gains(kr=60.0), steps=5)
    runs = [("ideal", traj, "--", "tab:blue"), ("non-ideal", traj, "-", "tab:red")]
    path = tmp_path / "fig9.png"
    legends = _legends(monkeypatch, lambda: paper._paths_figure(path, "t", refs, runs))
    assert legends == [("fig9.png", "", ["ideal", "non-ideal", "reference"])]


def test_gain_files_of_two_robots_are_refused_in_a_short_line(capsys, tmp_path):
    burger, pioneer = w.ROBOTS["turtlebot3-burger"], w.ROBOTS["pioneer-3dx"]
    nominal = _file(tmp_path, "n.json", json.dumps(tuned_json(w.Gains(kr=9.0), robot=burger)))
    robust = _file(tmp_path, "r.json", json.dumps(tuned_json(w.Gains(kr=9.0), robot=pioneer)))
    argv = ["robustness", "--out", str(tmp_path / "o"), "--nominal-gains", nominal]
    assert main([*argv, "--robust-gains", robust]) == 2
    assert capsys.readouterr().err == (
        f"wmr-jax: error: --robust-gains {robust!r} is not allowed with --nominal-gains "
        f"{nominal!r}: tuned for pioneer-3dx, the other for turtlebot3-burger; allowed: gain "
        "files tuned for one robot\n"
    )


def test_the_wheel_bound_warning_says_when_the_gains_are_the_defaults(capsys, monkeypatch):
    from wmr_jax._src.cli import main as cli

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10"]) == 0
    err = capsys.readouterr().err
    assert "exceeds v_max = 125 cm/s" in err
    assert "these are the default gains, the paper's Fig. 7 (docs/paper.md)" in err
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10", "--k-r", "121"]) == 0
    err = capsys.readouterr().err
    assert "k_r + L*k_theta = 139.5 cm/s exceeds" in err and "default gains" not in err


def test_simulate_says_its_warnings_before_an_error_they_explain(capsys, monkeypatch):
    from wmr_jax._src.cli import main as cli

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10", "--dt", "1e30"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("wmr-jax: error: the run left the range")
    assert any(line.startswith("wmr-jax: warning: k_theta*dt = 1e+31") for line in err[:-1])


def test_a_phi_m_that_looks_like_radians_is_warned_of(capsys):
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10", "--phi-m", "1.2"]) == 0
    err = capsys.readouterr().err
    assert "--phi-m 1.2 is read in degrees (1.2°); a value in radians needs times 180/pi" in err
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "10", "--phi-m", "2"]) == 0
    assert "read in degrees" not in capsys.readouterr().err  # above π/2 degrees: meant


@pytest.mark.parametrize(
    ("noise", "noise_theta", "said"),
    [
        (
            0.005,
            0.0087,
            [
                "--noise 0.005 is read in cm, finer than most motion-capture trackers (under "
                "0.01 cm); a value in metres needs times 100",
                "--noise-theta 0.0087 is read in degrees, finer than most motion-capture "
                "trackers (under 0.05 degrees); a value in radians needs times 180/pi",
            ],
        ),
        (
            50,
            60,
            [
                "--noise 50 is read in cm, over ten times the arrival tolerance the tuner judges "
                "by (1 cm): no loop settles within it under such noise (a value in mm needs /10)",
                "--noise-theta 60 is read in degrees, over ten times the arrival tolerance the "
                "tuner judges by (5 degrees): no loop settles within it",
            ],
        ),
    ],
    ids=["metres-or-radians", "no-loop-settles"],
)
def test_a_robust_noise_of_another_unit_or_none_can_settle_under_is_warned_of(
    noise, noise_theta, said
):
    from types import SimpleNamespace

    from wmr_jax._src.cli.tune_robust import config_from

    with pytest.warns(UserWarning) as caught:
        config = config_from(SimpleNamespace(noise=noise, noise_theta=noise_theta))
    assert (config.noise_xy, config.noise_theta) == (noise, noise_theta)  # warned, still taken
    assert [str(w.message) for w in caught] == said
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # noiseless, a mocap tracker's and a coarse one's: meant
        config_from(SimpleNamespace(noise=0, noise_theta=0))
        config_from(SimpleNamespace(noise=0.01, noise_theta=0.05))
        config_from(SimpleNamespace(noise=10, noise_theta=50))


def test_a_period_or_horizon_that_looks_like_milliseconds_is_warned_of(
    tmp_path, capsys, monkeypatch
):
    from wmr_jax._src.cli import main as cli
    from wmr_jax._src.studies import maps

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "2", "--dt", "33"]) == 0
    ms = "is read in s; a value in milliseconds needs /1000"
    assert f"wmr-jax: warning: --dt 33 {ms}" in capsys.readouterr().err
    assert main(["simulate", "--ref", "30", "20", "45", "--steps", "2", "--dt", "0.5"]) == 0
    assert "milliseconds" not in capsys.readouterr().err

    def stop(*args, **kwargs):
        raise ValueError("stopped before the runs")

    monkeypatch.setattr(maps, "compare_controllers", stop)
    assert main(["compare", "--out", str(tmp_path), "--horizon", "6000"]) == 2
    err = capsys.readouterr().err
    assert (
        "wmr-jax: warning: --horizon 6000 is read in s, 1000 times this robot's study horizon "
        "(6 s); a value in milliseconds needs /1000"
    ) in err
    assert main(["compare", "--out", str(tmp_path), "--horizon", "600"]) == 2  # 100 times: meant
    assert "milliseconds" not in capsys.readouterr().err
    from wmr_jax._src.tuning import run as tuning_run

    monkeypatch.setattr(tuning_run, "tune", stop)
    assert main(["tune", "--out", str(tmp_path), "--horizon", "3000"]) == 2
    assert "warning: --horizon 3000 is read in s, 500 times" in capsys.readouterr().err
    # A slower robot's study horizon is longer (37 s): there the same horizon is 81 times it.
    burger = ["--robot", "turtlebot3-burger"]
    assert main(["tune", "--out", str(tmp_path), "--horizon", "3000", *burger]) == 2
    assert "milliseconds" not in capsys.readouterr().err


def test_angles_that_look_like_radians_and_a_pass_tolerance_in_metres_are_warned_of(
    tmp_path, capsys, monkeypatch
):
    from wmr_jax._src.cli import main as cli
    from wmr_jax._src.studies import maps, waypoints

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    radians = "a value in radians needs times 180/pi"
    assert main(["simulate", "--ref", "30", "30", "1.57", "--steps", "2"]) == 0
    assert f"--ref THETA_DEG 1.57 is read in degrees (1.57°); {radians}" in capsys.readouterr().err
    for theta in ("0", "3", "-45", "90.5"):  # whole degrees, or beyond ±π: meant
        assert main(["simulate", "--ref", "30", "30", theta, "--steps", "2"]) == 0
        assert "read in degrees" not in capsys.readouterr().err

    def stop(*args, **kwargs):
        raise ValueError("stopped before the runs")

    monkeypatch.setattr(maps, "map_study", stop)
    out = str(tmp_path)
    assert main(["sweep", "--out", out, "--headings", "0", "1.57", "3"]) == 2
    assert f"--headings 0 1.57 3 is read in degrees (1.57°); {radians}" in capsys.readouterr().err
    assert main(["sweep", "--out", out, "--headings", "0", "1.5", "90"]) == 2  # one beyond ±π
    assert "read in degrees" not in capsys.readouterr().err
    monkeypatch.setattr(waypoints, "soccer_study", stop)
    assert main(["waypoints", "--out", out, "--pass-tol", "0.05", "--pass-tol-deg", "0.5"]) == 2
    err = capsys.readouterr().err
    assert f"--pass-tol-deg 0.5 is read in degrees (0.5°); {radians}" in err
    assert (
        "--pass-tol 0.05 is read in cm, under the arrival tolerance (1 cm): a robot may never "
        "pass a waypoint; a value in metres needs times 100"
    ) in err
    assert main(["waypoints", "--out", out]) == 2  # the defaults: 5 cm and 30°
    assert "read in" not in capsys.readouterr().err


def test_a_gain_error_says_when_the_flag_blamed_was_not_given_and_aliases_conflict(capsys):
    assert main(["simulate", "--ref", "30", "30", "0", "--r-m", "0.2", "--r-a", "0.2"]) == 2
    assert capsys.readouterr().err.strip() == (
        "wmr-jax: error: --r-e (not given: its default, 1): gains.r_e = 1.0 is not allowed; "
        "allowed: 0 < r_e <= r_a (gains.r_a = 0.2)"
    )
    assert main(["simulate", "--ref", "30", "30", "0", "--r-e", "0.5", "--r-a", "0.2"]) == 2
    assert capsys.readouterr().err.startswith("wmr-jax: error: --r-e: gains.r_e = 0.5 is not")
    # Two spellings of one gain: refused, not the last one silently taken.
    with pytest.raises(SystemExit) as refused:  # as the parser refuses any flag
        main(["simulate", "--ref", "30", "30", "0", "--k-r", "60", "--kr", "90"])
    assert refused.value.code == 2
    assert capsys.readouterr().err == (
        "wmr-jax: error: --kr is not allowed with --k-r: both set kr; allowed: one of them "
        "(see wmr-jax simulate --help)\n"
    )
    assert main(["simulate", "--ref", "30", "30", "0", "--kr", "60", "--steps", "2"]) == 0


def test_evaluate_warns_when_no_reference_can_be_reached_within_the_horizon(
    tmp_path, capsys, monkeypatch
):
    from wmr_jax._src.cli import main as cli
    from wmr_jax._src.studies import conditions

    def stop(*args, **kwargs):
        raise ValueError("stopped before the runs")

    monkeypatch.setattr(cli, "_shown_warnings", set())  # each distinct warning printed once
    monkeypatch.setattr(conditions, "evaluate_loop", stop)
    far = _file(tmp_path, "far.csv", "x_cm,y_cm,theta_rad\n3000,3000,0\n-2500,0,1\n")
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", far]) == 2
    assert (
        f"--refs '{far}': every reference lies beyond 751 cm, as far as V_max drives within the "
        "horizon (the nearest 2500 cm): a robot within V_max cannot arrive; x and y are read as cm"
    ) in capsys.readouterr().err
    near = _file(tmp_path, "near.csv", "x_cm,y_cm,theta_rad\n3000,3000,0\n30,20,1\n")
    assert main(["evaluate", "--gains", _gains(tmp_path), "--refs", near]) == 2
    assert "cannot arrive" not in capsys.readouterr().err  # one of them can
