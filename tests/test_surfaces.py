"""What a person reads or types: units, flag spellings, reports without NaN, refused files.

Angles are degrees wherever a person reads or types them and radians in the
Python API; files name their units; a ratio that needs a run that never
arrived is null (with the reason) in JSON and "none arrived" in print; a
malformed file to resume from is refused in one line before any work.
"""

import json
import math
import re
import zipfile

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src import io
from wmr_jax._src.cli import flags
from wmr_jax._src.cli.main import build_parser
from wmr_jax._src.report import tuning as _report_tuning
from wmr_jax._src.tuning import run as tune_run
from wmr_jax._src.tuning.evaluation import Evaluation, report_ratios
from wmr_jax._src.tuning.training import TuneResult
from wmr_jax.cli import main

# Gains as tune might find them: Φ_m = 1.2573 rad = 72.04°.
TUNED = w.Gains(
    kr=65.59203, k_theta=9.367961, phi_m=1.2573394, r_m=16.12695, r_a=16.05891, r_e=0.80295,
    alpha=0.2572655,
)  # fmt: skip
TINY = ["--iters", "2", "--poses", "4", "--eval-poses", "4", "--horizon", "0.033"]


def _stand_in_train(monkeypatch, evaluation, gains=TUNED):
    """Replace the tuner by one that returns ``gains`` and ``evaluation`` at once."""
    calls = []

    def fake(config, *, robot, state, progress_fn, **_):
        calls.append(config)
        row = [float(getattr(gains, f)) for f in tuning.GAIN_FIELDS]
        history = {
            "loss": np.array([0.1, 0.08]),
            "temperature": np.array([0.1, 0.01]),
            "gains": np.array([row, row]),
            "validated_at": np.array([0, 2]),
            "validation": np.array([1.0, 0.9]),
        }
        return TuneResult(gains, evaluation, history, 1.0, None, "fixed", 2)

    monkeypatch.setattr(tune_run.training, "train", fake)  # the one wmr-jax tune calls
    # The curve is drawn (test_the_schedule_curve_...), not rendered here: seconds of
    # matplotlib; and the held-out yardsticks are those of two poses, without JAX.
    monkeypatch.setattr(_report_tuning, "tuning_curve", lambda path, *a, **k: path)
    monkeypatch.setattr(tune_run, "held_out_bounds", lambda config, robot: BOUNDS)
    return calls


NONE_ARRIVED = Evaluation(math.inf, 0.0, 55.0, 4)
BOUNDS = w.studies.time_bounds(np.array([[30.0, 0.0, 0.0], [0.0, 30.0, 1.0]]))
ARRIVED = Evaluation(0.5, 1.0, 100.0, 4)


# ---------------------------------------------------------------- A: one unit per quantity


def test_tune_prints_degrees_and_its_printed_gains_feed_simulate(tmp_path, monkeypatch, capsys):
    """tune printed phi_m=1.257 (radians) while simulate --phi-m takes degrees."""
    _stand_in_train(monkeypatch, {"paper_feasible": ARRIVED, "tuned": ARRIVED})
    out = tmp_path / "t"
    assert main(["tune", "--out", str(out), *TINY, "--no-random-search"]) == 0
    printed = capsys.readouterr().out
    assert "Φ_m=72.04°" in printed and "phi_m=1.257" not in printed, printed
    line = next(x for x in printed.splitlines() if "as simulate flags:" in x)
    argv = line.split("as simulate flags:")[1].split()
    assert argv[argv.index("--phi-m") + 1] == "72.0402"
    # Typed into simulate, the printed flags give the file's gains (to the six digits printed).
    from wmr_jax._src.cli.simulate import _controller_and_gains

    base = ["simulate", "--ref", "25", "-10", "30"]
    _, typed, _ = _controller_and_gains(build_parser().parse_args([*base, *argv]))
    file_argv = [*base, "--gains", str(out / "tuned_gains.json")]
    _, saved, _ = _controller_and_gains(build_parser().parse_args(file_argv))
    assert saved == tuning.load_tuned(out / "tuned_gains.json").params
    for field in tuning.GAIN_FIELDS:
        assert float(getattr(typed, field)) == pytest.approx(float(getattr(saved, field)), 1e-5)
    assert float(saved.phi_m) == pytest.approx(TUNED.phi_m)  # radians in the API


def test_tuned_gains_files_name_their_units_and_old_files_still_load(tmp_path):
    path = tmp_path / "g.json"
    values = tuning.tuned_json(TUNED)
    assert values["units"] == {
        "kr": "cm/s", "k_theta": "rad/s", "phi_m": "rad", "r_m": "cm", "r_a": "cm",
        "r_e": "cm", "alpha": "1",
    }  # fmt: skip
    path.write_text(json.dumps(values))
    new = tuning.load_tuned(path).params
    # A file from before units were recorded: the same numbers, radians.
    old = {k: v for k, v in values.items() if k != "units"}
    path.write_text(json.dumps(old))
    assert tuning.load_tuned(path).params == new
    path.write_text(json.dumps({k: float(getattr(TUNED, k)) for k in tuning.GAIN_FIELDS}))
    assert tuning.load_tuned(path).params == new
    # A file may give an angle in degrees, if it says so.
    path.write_text(json.dumps({**values, "phi_m": 72.0, "units": {"phi_m": "deg"}}))
    assert tuning.load_tuned(path).params.phi_m == pytest.approx(math.radians(72.0))
    # The estimator's angle too.
    loop = tuning.tuned_json(TUNED, w.studies.EKFParams())
    assert loop["units"]["estimator.sigma_theta"] == "rad"
    loop["estimator"]["sigma_theta"] = 2.0
    loop["units"]["estimator.sigma_theta"] = "deg"
    path.write_text(json.dumps(loop))
    sigma = tuning.load_tuned(path).estimator.sigma_theta
    assert float(sigma) == pytest.approx(math.radians(2.0))
    for units, message in (
        ({"phi_m": "degrees?"}, r"units\['phi_m'\] = 'degrees\?' is not allowed; allowed: 'rad'"),
        ({"kr": "m/s"}, r"units\['kr'\] = 'm/s' is not allowed; allowed: 'cm/s'"),
        ({"kr": "deg"}, r"units\['kr'\] = 'deg' is not allowed; allowed: 'cm/s'"),
        ({"k_turn": "rad/s"}, r"units\['k_turn'\] is not allowed; allowed: keys among kr"),
        (["rad"], r"units = \['rad'\] is not allowed; allowed: an object"),
    ):
        path.write_text(json.dumps({**values, "units": units}))
        with pytest.raises(ValueError, match=rf"^'.*g.json': {message}"):
            tuning.load_tuned(path)


# ---------------------------------------------------------------- B: gain flags


def test_every_gain_flag_has_one_hyphenated_style_and_keeps_its_old_spelling(tmp_path, capsys):
    parser = build_parser()
    base = ["simulate", "--ref", "1", "1", "0"]
    new = flags.gains_from(parser.parse_args([*base, "--k-r", "60", "--k-theta", "8"]))
    old = flags.gains_from(parser.parse_args([*base, "--kr", "60", "--k-theta", "8"]))
    assert new == old and new.kr == 60.0
    # Each flag in one style, the field's name hyphenated: --k-r beside --k-theta.
    assert set(flags.GAIN_FLAG.values()) == {
        "--k-r", "--k-theta", "--phi-m", "--r-m", "--r-a", "--r-e", "--alpha",
    }  # fmt: skip
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "--k-r V, --kr V k_r, cm/s (default: 120.0)" in shown, shown
    # --init's default as numbers, not ['0', '0', '0'].
    assert "--init X Y THETA_DEG initial pose: cm, cm, degrees (default: 0 0 0)" in shown
    # A message names the flag as it was typed.
    good = tmp_path / "g.json"
    good.write_text(json.dumps(tuning.tuned_json(TUNED)))
    for spelling in ("--kr", "--k-r"):
        assert main([*base, "--gains", str(good), spelling, "60"]) == 2
        assert f"{spelling} is not allowed with --gains" in capsys.readouterr().err
        assert main([*base, spelling, "-1"]) == 2
        assert f"{spelling}: gains.kr = -1.0 is not allowed" in capsys.readouterr().err


# ---------------------------------------------------------------- C: no NaN in a report


def test_tune_writes_null_and_prints_none_arrived_when_nothing_arrives(
    tmp_path, monkeypatch, capsys
):
    """speedup_vs_paper was "nan" in evaluation.json and nan× in print (inf / inf)."""
    _stand_in_train(monkeypatch, {"paper_feasible": NONE_ARRIVED, "tuned": NONE_ARRIVED})
    out = tmp_path / "t"
    assert main(["tune", "--out", str(out), *TINY, "--no-random-search"]) == 0
    printed = capsys.readouterr().out
    text = (out / "evaluation.json").read_text()
    assert "nan" not in text.lower() and "nan" not in printed.lower()
    assert "inf×" not in printed and "| tuned | none arrived | none arrived |" in printed
    row = json.loads(text)["rows"]["tuned"]
    for key in ("speedup_vs_paper", "vs_turn_drive_turn", "vs_lower_bound"):
        assert row[key] is None and row[f"{key}_reason"].startswith("none arrived"), row
    # Only the paper's gains never arrive: the speed-up says whose runs did not.
    _stand_in_train(monkeypatch, {"paper_feasible": NONE_ARRIVED, "tuned": ARRIVED})
    assert main(["tune", "--out", str(out), *TINY, "--no-random-search"]) == 0
    printed = capsys.readouterr().out
    assert "| tuned | 0.500 | paper: none arrived | 100.00 % |" in printed, printed
    row = json.loads((out / "evaluation.json").read_text())["rows"]["tuned"]
    assert row["speedup_vs_paper"] is None and "paper's gains" in row["speedup_vs_paper_reason"]
    assert row["vs_lower_bound"] > 1


def test_every_ratio_of_a_comparison_is_a_number_or_says_none_arrived():
    ratios = report_ratios(math.inf, BOUNDS, paper=0.5)
    assert ratios["vs_lower_bound"] is None and ratios["speedup_vs_paper"] is None
    assert math.isfinite(report_ratios(0.6, BOUNDS, paper=0.5)["speedup_vs_paper"])
    from wmr_jax._src.report.tuning import comparison_table

    row = {"problem": "fixed", "method": "gradient", "mean_arrival": 0.5, "wall_s": 1.0}
    row.update(success_rate=1.0, lower_bound_s=0.35, turn_drive_turn_s=0.4)
    # As read back from compare.json: "inf" strings (they raised TypeError).
    rows = [row, {**row, "mean_arrival": "inf", "success_rate": 0.0}, row]
    table = comparison_table(rows)
    assert "0.500 / none arrived / 0.500" in table and "none arrived in 1 of 3" in table
    assert "nan" not in table and "inf" not in table
    table = comparison_table([{**row, "mean_arrival": math.inf}])
    assert "| none arrived | 0.0 %" not in table and "none arrived" in table
    assert "nan" not in table and "inf" not in table
    with pytest.raises(ValueError, match=r"rows\[0\]\['mean_arrival'\] = 'nan' is not allowed"):
        comparison_table([{**row, "mean_arrival": "nan"}])


# ---------------------------------------------------------------- D: the tuning curve


def test_the_schedule_curve_shows_every_parameter_and_names_k_turn(tmp_path, monkeypatch):
    from wmr_jax._src.report import tuning as report

    titles = []

    def keep_titles(fig, path, **_):
        titles.append([ax.get_title() for ax in fig.axes if ax.get_title()])
        return path

    monkeypatch.setattr(report, "save_figure", keep_titles)
    knots = 2
    columns = len(tuning.schedule_problem(knots).columns)
    history = {
        "loss": np.array([0.2, 0.1]),
        "temperature": np.array([0.1, 0.01]),
        "gains": np.ones((2, columns)),
    }
    report.tuning_curve(tmp_path / "c.png", history, problem="schedule")
    shown = " | ".join(titles[0])
    assert "k_turn(r_e)" in shown and "α" in shown, shown  # α was left out
    for label in ("k_r(r_e)", "k_θ(r_e)", "Φ_m (deg)", "R_m", "R_a", "R_e"):
        assert label in shown
    # A non-finite loss is still marked.
    history = {**history, "gains": np.ones((2, 7)), "loss": np.array([np.nan, 0.1])}
    report.tuning_curve(tmp_path / "c.png", history, problem="fixed")
    assert "1 non-finite or non-positive, marked ×" in titles[1][0]
    assert len(titles[1]) == 8  # the loss and the seven gains


# ---------------------------------------------------------------- E: files to resume from


def _row(problem, seed, method, **changes):
    row = {"problem": problem, "parameters": 7 if problem == "fixed" else 35, "seed": seed}
    row.update(method=method, wall_s=1.0, candidates=None, mean_arrival=0.5, success_rate=1.0)
    row.update(peak_wheel_speed=100.0, poses=2, turn_drive_turn_s=0.4, lower_bound_s=0.35)
    row.update(vs_turn_drive_turn=1.25, vs_lower_bound=1.4)
    return {**row, **changes}


def _whole(problem="fixed", seed=0, **changes):
    return [_row(problem, seed, m, **changes) for m in ("gradient", "cma-es", "random search")]


def _first_run_then_stop(calls):
    """A stand-in ``compare`` whose first run returns its rows; the next is interrupted."""

    def fake(*, seeds, problems, configs, progress, robot=None):
        calls.append((problems[0], seeds[0]))
        if len(calls) > 1:
            raise KeyboardInterrupt
        return _whole(problems[0], seeds[0])

    return fake


def _write_rows(record, rows):
    """``rows`` into ``record`` beside its settings, sealed as ``tune --compare`` writes them."""
    settings = json.loads(record.read_text())["settings"]
    record.write_text(json.dumps(io.sealed({"settings": settings, "rows": rows})))


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ({"rows": []}, r"compare.json rows are a JSON object; allowed: an array of comparison"),
        ([["fixed", 0, "gradient"]], r"compare.json row 0 is a JSON array; allowed: an object"),
        (
            [{"problem": "fixed", "seed": 0, "method": "gradient"}],
            r"row 0 has no 'mean_arrival'",
        ),
        ([_row(["s"], 0, "gradient")], r"row 0: problem = \['s'\] is not allowed"),
        (_whole(seed=7), r"row 0: seed = 7 is not allowed; allowed: 0, 1, 2"),
        (_whole(seed="0"), r"row 0: seed = '0' is not allowed"),
        ([*_whole(), _row("fixed", 0, "annealing")], r"row 3: method = 'annealing'"),
        (_whole(parameters=9), r"row 0: parameters = 9 is not allowed; allowed: 7"),
        (_whole(mean_arrival="nan"), r"row 0\['mean_arrival'\] = 'nan' is not allowed"),
        (_whole(lower_bound_s=None), r"row 0\['lower_bound_s'\] = None is not allowed"),
        (_whole()[:2], r"holds fixed seed 0 without 'random search'"),
        ([*_whole(), _whole()[0]], r"row 3: fixed seed 0 gradient is given twice"),
    ],
)
def test_resume_refuses_a_malformed_compare_json_before_any_work(
    tmp_path, monkeypatch, capsys, rows, message
):
    from wmr_jax._src.tuning import compare as compare_module

    calls = []
    monkeypatch.setattr(compare_module, "compare", _first_run_then_stop(calls))
    argv = ["tune", "--out", str(tmp_path), "--compare", "--iters", "1"]
    assert main(argv) == 130  # writes compare.json after its first run, then stops
    capsys.readouterr()
    _write_rows(tmp_path / "compare.json", rows)
    calls.clear()
    assert main([*argv, "--resume"]) == 2
    err = capsys.readouterr().err
    assert not calls, "the comparison started"
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "compare.json" in err
    assert re.search(message, err), err


@pytest.mark.parametrize(
    ("record", "message"),
    [
        ("[1, 2]", r"compare.json holds no comparison settings"),
        ("[{", r"compare.json cannot be read"),
        ('[{"problem": "fixed", "problem": "x"}]', r"the key 'problem' is given twice"),
    ],
)
def test_resume_refuses_unreadable_comparison_files(tmp_path, monkeypatch, capsys, record, message):
    from wmr_jax._src.tuning import compare as compare_module

    def fake(**kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(compare_module, "compare", fake)
    argv = ["tune", "--out", str(tmp_path), "--compare", "--iters", "1"]
    assert main(argv) == 130
    capsys.readouterr()
    (tmp_path / "compare.json").write_text(record)
    assert main([*argv, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.replace("\\", "") in err, err


def test_resume_keeps_whole_rows_of_runs_that_never_arrived(tmp_path, monkeypatch, capsys):
    """Rows read back with "inf" and null ratios are kept, and the table says none arrived."""
    from wmr_jax._src.tuning import compare as compare_module

    def fake(*, seeds, problems, configs, progress, robot=None):
        return _whole(problems[0], seeds[0])

    monkeypatch.setattr(compare_module, "compare", _first_run_then_stop([]))
    argv = ["tune", "--out", str(tmp_path), "--compare", "--schedule", "--iters", "1"]
    assert main(argv) == 130  # writes compare.json after its first run, then stops
    kept = _whole("schedule", 0, mean_arrival="inf", vs_lower_bound=None)
    _write_rows(tmp_path / "compare.json", kept)
    monkeypatch.setattr(compare_module, "compare", fake)
    assert main([*argv, "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "schedule seed 0: kept from" in printed
    assert "none arrived / 0.500 / 0.500" in printed and "nan" not in printed, printed


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda saved: saved["rows"][1].update(mean_arrival=0.45), r"compare.json was changed"),
        (lambda saved: saved["rows"][2].update(seed=1), r"compare.json was changed after"),
        (lambda saved: saved.pop("sha256"), r"compare.json has no checksum"),
        (lambda saved: saved["rows"].reverse(), r"compare.json was changed after"),
        (lambda saved: saved.pop("rows"), r"compare.json holds no rows"),
        (lambda saved: None, None),  # layout and key order are not content
    ],
)
def test_resume_keeps_no_row_whose_values_changed_after_they_were_written(
    tmp_path, monkeypatch, capsys, edit, message
):
    from wmr_jax._src.tuning import compare as compare_module

    calls, interrupt = [], [True]

    def fake(*, seeds, problems, configs, progress, robot=None):
        calls.append((problems[0], seeds[0]))
        if interrupt[0] and len(calls) == 2:
            raise KeyboardInterrupt
        return _whole(problems[0], seeds[0])

    monkeypatch.setattr(compare_module, "compare", fake)
    argv = ["tune", "--out", str(tmp_path), "--compare", "--schedule", "--iters", "1"]
    assert main(argv) == 130  # seed 0 written by the command, seed 1 interrupted
    record = tmp_path / "compare.json"
    saved = json.loads(record.read_text())
    assert [row["seed"] for row in saved["rows"]] == [0, 0, 0] and "sha256" in saved
    edit(saved)
    record.write_text(json.dumps(saved, indent=4, sort_keys=True))
    capsys.readouterr()
    calls.clear()
    interrupt[0] = False
    code = main([*argv, "--resume"])
    out, err = capsys.readouterr()
    if message is None:
        assert code == 0 and "schedule seed 0: kept from" in out, err
        assert calls == [("schedule", 1), ("schedule", 2)]
        return
    assert code == 2 and not calls, "the comparison started"
    assert err.count("\n") == 1 and re.search(message, err), err
    assert "remove it, or use a fresh --out" in err


def test_resume_on_another_robot_names_both_robots_in_words(tmp_path, monkeypatch, capsys):
    from wmr_jax._src.model.robots import describe_robot
    from wmr_jax._src.tuning import compare as compare_module

    monkeypatch.setattr(compare_module, "compare", _first_run_then_stop([]))
    argv = ["tune", "--out", str(tmp_path), "--compare", "--iters", "1"]
    assert main(argv) == 130
    capsys.readouterr()
    assert main([*argv, "--robot", "turtlebot3-burger", "--resume"]) == 2
    err = capsys.readouterr().err
    paper, burger = (describe_robot(w.ROBOTS[n]) for n in ("paper", "turtlebot3-burger"))
    # The horizon is the robot's too (its study horizon), then the robot in words.
    assert "is of another comparison (configs.fixed.horizon = 6.0 there, 37.0 now;" in err, err
    assert f"; robot: {paper} there, {burger} now); allowed: the same settings" in err, err
    assert err.count("\n") == 1 and "half_track" not in err, err


def _checkpoint_args(tmp_path):
    return ["tune", "--out", str(tmp_path), *TINY, "--no-random-search", "--resume"]


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        ([2, {}], r"has metadata of the wrong shape \(\[2, \{\}\]"),
        # Format 3 held no logits of the lowest-scored iterate.
        ({"format": 3, "identity": {}}, r"has an unknown format \(format = 3; allowed: 4\)"),
        ({"format": 4, "identity": "run"}, r"metadata of the wrong shape \(identity = 'run'"),
        ({"format": 4, "identity": {"config": [], "robot": {}}}, r"identity = \{'config': \[\]"),
        ({"format": 4, "identity": {"config": {}}}, r"with a 'config' and a 'robot' object"),
    ],
)
def test_resume_refuses_a_checkpoint_whose_metadata_has_the_wrong_shape(
    tmp_path, monkeypatch, capsys, meta, message
):
    calls = _stand_in_train(monkeypatch, {"paper_feasible": ARRIVED, "tuned": ARRIVED})
    io.save_arrays(tmp_path / tune_run.CHECKPOINT_NAME, {"iteration": np.asarray(1)}, meta)
    assert main(_checkpoint_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert not calls and err.count("\n") == 1, err
    assert re.search(rf"--resume: checkpoint .*checkpoint.npz .*{message}", err), err


def test_a_checkpoint_of_rows_without_axes_is_refused_in_one_line():
    config = tuning.TuneConfig(iters=2, poses=4, eval_poses=4, horizon=0.033)
    fresh = tuning.init_state(config)
    arrays = tuning.state_arrays(fresh)
    arrays.update(gains=np.asarray(1.0))  # an IndexError before
    with pytest.raises(ValueError, match=r"^the saved state is incomplete \(IndexError"):
        tuning.restore_state(arrays, fresh)


# ---------------------------------------------------------------- F: the checksum


def test_editing_only_the_metadata_of_a_saved_file_is_detected(tmp_path, monkeypatch, capsys):
    path = tmp_path / tune_run.CHECKPOINT_NAME
    io.save_arrays(path, {"x": np.arange(3.0)}, {"format": 3, "identity": {"seed": 0}})
    with np.load(path) as data:
        stored = {name: data[name] for name in data.files}
    # The same arrays and checksum; the metadata alone edited.
    stored["__meta__"] = np.asarray(str(stored["__meta__"]).replace('"seed": 0', '"seed": 1'))
    edited = tmp_path / "edited.npz"
    np.savez(edited, **stored)
    with zipfile.ZipFile(edited) as z:
        assert sorted(z.namelist()) == ["__meta__.npy", "__sha256__.npy", "x.npy"]
    with pytest.raises(io.DamagedFileError, match="its checksum does not match its contents"):
        io.load_arrays(edited)
    # As a checkpoint to resume from: one line, before any work.
    edited.replace(path)
    calls = _stand_in_train(monkeypatch, {"paper_feasible": ARRIVED, "tuned": ARRIVED})
    assert main(_checkpoint_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert not calls and err.count("\n") == 1 and "checksum does not match" in err, err


def test_a_new_comparison_leaves_no_rows_of_an_earlier_one_to_resume(tmp_path, monkeypatch, capsys):
    """A new comparison removes an earlier one's files before its first run ends.

    A comparison of one horizon, then one of another cut before its first
    seed ended: ``--resume`` of the second kept the first's rows as its own.
    """
    from wmr_jax._src.tuning import compare as compare_module

    def stop(**kwargs):
        raise KeyboardInterrupt

    def fake(*, seeds, problems, configs, progress, robot=None):
        return _whole(problems[0], seeds[0], mean_arrival=float(configs[problems[0]].horizon))

    monkeypatch.setattr(compare_module, "compare", fake)
    argv = ["tune", "--out", str(tmp_path), "--compare", "--schedule", "--iters", "1"]
    assert main([*argv, "--horizon", "1"]) == 0
    assert (tmp_path / "compare.json").exists() and (tmp_path / "compare.md").exists()
    monkeypatch.setattr(compare_module, "compare", stop)
    assert main([*argv, "--horizon", "2"]) == 130
    assert not (tmp_path / "compare.json").exists() and not (tmp_path / "compare.md").exists()
    capsys.readouterr()
    monkeypatch.setattr(compare_module, "compare", fake)
    assert main([*argv, "--horizon", "2", "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "kept from" not in printed
    rows = json.loads((tmp_path / "compare.json").read_text())["rows"]
    assert {row["mean_arrival"] for row in rows} == {2.0}
