"""wmr-jax evaluate: a tuned loop judged on the user's references under one condition."""

import json

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src.cli.main import main
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.sim.sensing.estimators import ObserverParams
from wmr_jax._src.sim.sensing.loop import ClosedLoop
from wmr_jax._src.studies import conditions
from wmr_jax._src.tuning.saved import tuned_json

# A few references within reach in 6 s (x cm, y cm, θ rad), and one far beyond.
REFS = np.array([[30.0, 20.0, 0.3], [-20.0, 15.0, 1.0], [25.0, -10.0, -0.5], [15.0, 30.0, 2.0]])
DT = 0.033
STEPS_6S = 182  # ceil(6 s / 33 ms): the horizon evaluate_loop runs


def _gains_file(tmp_path, loop_or_gains, name="tuned_gains.json"):
    path = tmp_path / name
    path.write_text(json.dumps(tuned_json(loop_or_gains)))
    return str(path)


def _npy(tmp_path, refs, name="refs.npy"):
    path = tmp_path / name
    np.save(path, refs)
    return str(path)


def _csv(tmp_path, refs, name="refs.csv", header="x_cm,y_cm,theta_rad\n"):
    path = tmp_path / name
    rows = "".join(",".join(repr(float(v)) for v in row) + "\n" for row in np.atleast_2d(refs))
    path.write_text(header + rows)
    return str(path)


def _evaluate(capsys, *argv):
    code = main(["evaluate", *argv])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured.out


def test_the_result_names_its_dtype():
    one = conditions.evaluate_loop(w.Gains(kr=60.0), REFS[:2], horizon=0.5, x64=False)
    assert one["dtype"] == "float32"


def test_npy_and_csv_give_the_same_result_as_the_library(capsys, tmp_path):
    gains = w.Gains(kr=60.0)
    gfile = _gains_file(tmp_path, gains)
    common = ["--gains", gfile, "--condition", "both", "--seed", "3", "--horizon", "6"]
    results = []
    for refs_file in (_npy(tmp_path, REFS), _csv(tmp_path, REFS)):
        out_file = tmp_path / f"{refs_file}.json"
        out = _evaluate(capsys, *common, "--refs", refs_file, "--json", str(out_file))
        result = json.loads(out_file.read_text())
        assert result["refs_file"] == refs_file and result["gains_file"] == gfile
        assert f"evaluate -> {out_file}" in out and "| success |" in out and "cm/s" in out
        results.append(result)
    a, b = (
        {k: v for k, v in r.items() if k not in ("refs_file", "gains_file", "gains")}
        for r in results
    )
    assert a == b
    # The gains themselves are recorded (the file may be tuned again), and the dtype.
    assert results[0]["gains"] == results[1]["gains"] == tuned_json(gains)
    assert a["dtype"] == "float64"
    assert 0.0 <= a["success"] <= 1.0 and a["n"] == len(REFS)
    direct = conditions.evaluate_loop(
        gains, REFS, condition="both", mismatch=0.03, seed=3, horizon=6.0
    )
    assert a == json.loads(json.dumps(direct))  # None stays null
    assert a["condition"] == "both" and a["feedback"] == "raw" and a["mismatch"] == 0.03
    # The printed table carries the same numbers, with units.
    assert f"| success | {100 * direct['success']:.1f} % |" in out
    peak = f"{direct['peak_wheel_speed']:.1f} cm/s at the rims, wheel-radius mismatch included"
    assert f"| peak wheel speed | {peak} |" in out


def test_a_single_row_is_one_reference_and_none_arrived_is_said(capsys, tmp_path):
    far = [500.0, 400.0, 0.0]  # beyond reach in 6 s
    gfile = _gains_file(tmp_path, w.Gains(kr=60.0))
    for refs_file in (_npy(tmp_path, np.array(far)), _csv(tmp_path, far, header="")):
        out = _evaluate(capsys, "--gains", gfile, "--refs", refs_file, "--condition", "nominal")
        assert "| success | 0.0 % |" in out and "| mean arrival | none arrived |" in out
        assert "| references (n) | 1 |" in out and "evaluate ->" not in out  # printed only
    out_file = tmp_path / "far.json"
    argv = ["--gains", gfile, "--refs", refs_file, "--condition", "nominal"]
    _evaluate(capsys, *argv, "--json", str(out_file))
    result = json.loads(out_file.read_text())
    assert result["mean_arrival_s"] is None and result["median_arrival_s"] is None


def test_the_files_estimator_is_used_unless_overridden(capsys, tmp_path):
    gains = w.Gains(kr=60.0)
    ekf = w.studies.EKFParams(sigma_xy=0.8)  # not the defaults: --estimator ekf keeps the file's
    gfile = _gains_file(tmp_path, ClosedLoop(SHIM_SUNG, gains, ekf))
    refs_file = _npy(tmp_path, REFS[:3])
    base = ["--gains", gfile, "--refs", refs_file, "--condition", "noise", "--seed", "1"]
    expected = {
        None: ClosedLoop(SHIM_SUNG, gains, ekf),
        "ekf": ClosedLoop(SHIM_SUNG, gains, ekf),
        "none": gains,
        "observer": ClosedLoop(SHIM_SUNG, gains, ObserverParams()),
    }
    feedback = {None: "ekf", "ekf": "ekf", "none": "raw", "observer": "observer"}
    for flag, loop in expected.items():
        out_file = tmp_path / f"{flag}.json"
        extra = [] if flag is None else ["--estimator", flag]
        _evaluate(capsys, *base, *extra, "--json", str(out_file))
        result = json.loads(out_file.read_text())
        assert result["feedback"] == feedback[flag]
        direct = conditions.evaluate_loop(loop, REFS[:3], condition="noise", seed=1)
        assert {k: result[k] for k in direct} == json.loads(json.dumps(direct)), flag


def test_the_model_robot_under_nominal_is_the_nominal_rollout(capsys, tmp_path):
    gains = w.Gains(kr=60.0)
    out_file = tmp_path / "nominal.json"
    argv = ["--gains", _gains_file(tmp_path, gains), "--refs", _csv(tmp_path, REFS)]
    argv += ["--condition", "nominal", "--mismatch", "0", "--json", str(out_file)]
    _evaluate(capsys, *argv)
    result = json.loads(out_file.read_text())
    arrival = np.asarray(
        w.arrival_time(w.batch_rollout(REFS, gains, steps=STEPS_6S, dt=DT), REFS, dt=DT)
    )
    assert np.isfinite(arrival).all()  # every reference is reached: the means compare
    assert result["success"] == 1.0 and result["mismatch"] == 0.0
    assert result["mean_arrival_s"] == pytest.approx(float(arrival.mean()), abs=1e-9)
    assert result["median_arrival_s"] == pytest.approx(float(np.median(arrival)), abs=1e-9)
    assert result["horizon_s"] == pytest.approx(STEPS_6S * DT)


def _write(tmp_path, name, content):
    path = tmp_path / name
    if isinstance(content, np.ndarray):
        np.save(path, content, allow_pickle=True)
    else:
        path.write_text(content)
    return str(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"--refs": "{missing_npy}"}, "--refs '{missing_npy}' cannot be read: there is no such"),
        ({"--refs": "{two_columns}"}, "it has shape (4, 2); allowed: (N, 3)"),
        ({"--refs": "{two_columns_csv}"}, "line 1 has 2 values; allowed: 3"),
        ({"--refs": "{one_d}"}, "it has shape (4,); allowed: (N, 3)"),
        ({"--refs": "{nan_npy}"}, "row 1 (from 0) = [1.0, nan, 0.0] is not finite"),
        ({"--refs": "{nan_csv}"}, "line 3 = [1.0, nan, 0.0] is not finite"),
        ({"--refs": "{text_csv}"}, "line 3, column 2 is 'abc'; allowed: a number"),
        ({"--refs": "{header_only}"}, "it holds no references"),
        ({"--refs": "{degrees_csv}"}, "line 1 names column 3 'theta_deg', in deg; allowed: rad"),
        ({"--refs": "{metres_csv}"}, "line 1 names column 2 'y (m)', in m; allowed: cm"),
        (
            {"--refs": "{semicolons_csv}"},
            "line 1 is separated by ';' ('30;20;0'); allowed: 3 comma-separated numbers a line",
        ),
        ({"--refs": "{tabs_csv}"}, "line 2 is separated by tabs"),
        ({"--refs": "{empty_npy}"}, "it holds no references"),
        ({"--refs": "{pickled}"}, "it holds Python objects (a pickle)"),
        ({"--refs": "{not_npy}"}, "it is no .npy array"),
        ({"--refs": "{txt}"}, "--refs '{txt}' is not allowed; allowed: a file ending in .npy"),
        ({"--refs": "{far}"}, "--refs '{far}' is not allowed: refs[0] = [1e+200, 0.0, 0.0]"),
        ({"--condition": "sunny"}, "--condition 'sunny' is not allowed; allowed: nominal, latency"),
        ({"--mismatch": "1.5"}, "--mismatch '1.5' is not allowed; allowed: a number >= 0 and < 1"),
        ({"--mismatch": "1"}, "--mismatch '1' is not allowed"),
        ({"--mismatch": "-0.1"}, "--mismatch '-0.1' is not allowed"),
        ({"--horizon": "0"}, "--horizon '0' is not allowed"),
        ({"--horizon": "0.01"}, "--horizon: horizon = 0.01 s is shorter than one control period"),
        ({"--horizon": "inf"}, "--horizon 'inf' is not allowed"),
        ({"--seed": "-1"}, "--seed '-1' is not allowed"),
        ({"--velocity": "warp"}, "--velocity 'warp' is not allowed"),
        ({"--estimator": "kalman"}, "--estimator 'kalman' is not allowed; allowed: none"),
        ({"--gains": "{missing_json}"}, "--gains '{missing_json}' cannot be read"),
        ({"--gains": "{garbled_json}"}, "--gains '{garbled_json}' is not a JSON gains file"),
        ({"--gains": "{bad_gains}"}, "--gains '{bad_gains}': key 'warp' is not allowed"),
        ({"--json": "/dev/null/out.json"}, "--json '/dev/null/out.json' is not allowed"),
        (
            {"--json": "{tmp}/out.csv"},
            "--json '{tmp}/out.csv' is not allowed; allowed: a path ending in .json",
        ),
        (
            {"--per-ref": "{tmp}/runs.json"},
            "--per-ref '{tmp}/runs.json' is not allowed; allowed: a path ending in .csv",
        ),
    ],
)
def test_bad_values_give_one_line_exit_2_and_no_run(capsys, tmp_path, monkeypatch, change, message):
    files = {
        "missing_npy": str(tmp_path / "none.npy"),
        "two_columns": _write(tmp_path, "two.npy", np.zeros((4, 2))),
        "two_columns_csv": _write(tmp_path, "two.csv", "1,2\n3,4\n"),
        "one_d": _write(tmp_path, "one_d.npy", np.zeros(4)),
        "nan_npy": _write(tmp_path, "nan.npy", np.array([[1.0, 2.0, 0.0], [1.0, np.nan, 0.0]])),
        "nan_csv": _write(tmp_path, "nan.csv", "x,y,theta\n1,2,0\n1,nan,0\n"),
        "text_csv": _write(tmp_path, "text.csv", "x,y,theta\n1,2,0\n1,abc,0\n"),
        "header_only": _write(tmp_path, "header.csv", "x,y,theta\n"),
        "degrees_csv": _write(tmp_path, "deg.csv", "x_cm,y_cm,theta_deg\n30,20,45\n"),
        "metres_csv": _write(tmp_path, "m.csv", "x (cm),y (m),theta (rad)\n0.3,0.2,0\n"),
        "semicolons_csv": _write(tmp_path, "semi.csv", "30;20;0\n"),
        "tabs_csv": _write(tmp_path, "tabs.csv", "x,y,theta\n30\t20\t0\n"),
        "empty_npy": _write(tmp_path, "empty.npy", np.zeros((0, 3))),
        "pickled": _write(tmp_path, "objects.npy", np.array([{"x": 1}, None], dtype=object)),
        "not_npy": _write(tmp_path, "text.npy", "1,2,3\n"),
        "txt": _write(tmp_path, "refs.txt", "1,2,3\n"),
        "tmp": str(tmp_path),
        "far": _write(tmp_path, "far.npy", np.array([[1e200, 0.0, 0.0]])),
        "missing_json": str(tmp_path / "none.json"),
        "garbled_json": _write(tmp_path, "garbled.json", "{kr: 60"),
        "bad_gains": _write(tmp_path, "bad.json", '{"kr": 60, "warp": 1}'),
    }
    good = {
        "--gains": _write(tmp_path, "g.json", '{"kr": 60}'),
        "--refs": _write(tmp_path, "ok.npy", REFS),
        "--condition": "nominal",
    }
    out_file = tmp_path / "out.json"
    values = {"--json": str(out_file), **good, **change}
    argv = ["evaluate"] + [part.format(**files) for pair in values.items() for part in pair]

    def no_run(*args, **kwargs):
        raise AssertionError("evaluate_loop ran despite a bad flag")

    monkeypatch.setattr(conditions, "evaluate_loop", no_run)
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wmr-jax: error:"), captured.err
    assert message.format(**files) in err[0]
    assert "jax_enable_x64" not in err[0] and captured.out == ""
    assert not out_file.exists()


def test_the_command_is_listed(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "evaluate" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    usage = capsys.readouterr().out
    for flag in ("--gains", "--refs", "--condition", "--mismatch", "--estimator", "--json"):
        assert flag in usage
