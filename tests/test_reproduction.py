"""experiments/reproduction.py: the check docs/robustness.md gives for another machine."""

import copy
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
COMMITTED = ROOT / "docs" / "data" / "robust_compare_price.json"


def _script():
    spec = importlib.util.spec_from_file_location(
        "reproduction", ROOT / "experiments" / "reproduction.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(tmp_path, capsys, fresh, *flags):
    path = tmp_path / "fresh.json"
    path.write_text(json.dumps(fresh), encoding="utf-8")
    status = _script().main([str(COMMITTED), str(path), *flags])
    return status, capsys.readouterr().out


def _committed():
    return json.loads(COMMITTED.read_text(encoding="utf-8"))


def _slower(data, method, seed, factor):
    """Every arrival of one method's seed stretched by ``factor``; timings changed too."""
    data = copy.deepcopy(data)
    for row in data["rows"]:
        row["cpu_s"] += 1.0  # a timing: never counted as a difference
        if (row["method"], row["seed"]) == (method, seed):
            assert row["success"] == 1.0  # then the judged score is the mean arrival
            row["mean arrival s"] *= factor
    return data


def test_the_same_run_reproduces_in_every_field(tmp_path, capsys):
    status, out = _run(tmp_path, capsys, _slower(_committed(), "gradient", 1, 1.0))
    assert status == 0
    assert "rows equal in every field but the timings: 45 of 45" in out
    assert "held-out poses: the same" in out
    assert out.count("+0.00% |") == 9
    assert "every row in both runs, every judged score within 2%: yes" in out
    # The committed run's ranking, as docs/robustness.md states it at C = 5.
    assert "gradient ahead of CMA-ES on the mean by +3.9%, at seeds [0, 1] of [0, 1, 2]" in out


@pytest.mark.parametrize(("factor", "status"), [(1.019, 0), (0.981, 0), (1.021, 1), (0.979, 1)])
def test_a_score_beyond_the_tolerance_fails_the_check(tmp_path, capsys, factor, status):
    got, out = _run(tmp_path, capsys, _slower(_committed(), "gradient", 1, factor))
    assert got == status
    line = next(line for line in out.splitlines() if line.startswith("| gradient | 1 |"))
    assert line.split("|")[5].strip().startswith(f"{factor - 1.0:+.2%}")
    assert ("beyond 2%" in line) == (status == 1)
    assert "rows equal in every field but the timings: 40 of 45" in out


def test_a_wider_tolerance_is_honoured(tmp_path, capsys):
    status, out = _run(
        tmp_path, capsys, _slower(_committed(), "gradient", 2, 1.04), "--tolerance", "0.05"
    )
    assert status == 0 and "every row in both runs, every judged score within 5%: yes" in out
    # 4 % slower at seed 2 puts CMA-ES ahead there and narrows the lead on the mean.
    assert "this run: gradient ahead of CMA-ES on the mean by +2.6%, at seeds [0, 1]" in out


def test_runs_of_other_settings_are_not_compared(tmp_path, capsys):
    fresh = _committed()
    fresh["settings"]["config"]["price"] = None  # the price measured, not given
    status, out = _run(tmp_path, capsys, fresh)
    assert status == 2
    assert "config.price: committed 5.0, this run None" in out
    assert "|" not in out


def test_a_row_in_one_run_only_fails_the_check(tmp_path, capsys):
    fresh = _committed()
    fresh["rows"] = [r for r in fresh["rows"] if (r["method"], r["seed"]) != ("gradient", 2)]
    status, out = _run(tmp_path, capsys, fresh)
    assert status == 1
    assert out.count("only in the committed run: ('gradient', 2, ") == 5  # its five conditions
    extra = _committed()
    extra["rows"].append({**extra["rows"][0], "condition": "wind"})
    status, out = _run(tmp_path, capsys, extra)
    assert status == 1 and "only in this run: ('gradient', 0, 'wind')" in out
    assert "rows equal in every field but the timings: 45 of 45" in out


def test_a_file_that_is_no_comparison_is_refused(tmp_path, capsys):
    broken = _committed()
    del broken["rows"][3]["held_out"]
    status, out = _run(tmp_path, capsys, broken)
    assert status == 3 and out.endswith("fresh.json: row 3 has no held_out\n")
    status, out = _run(tmp_path, capsys, {"rows": []})
    assert status == 3 and "no 'settings'" in out
    path = tmp_path / "fresh.json"
    path.write_text("{", encoding="utf-8")
    assert _script().main([str(COMMITTED), str(path)]) == 3
    assert "cannot be read" in capsys.readouterr().out


def test_another_file_format_is_not_compared(tmp_path, capsys):
    fresh = _committed()
    fresh["settings"]["format"] = 4
    status, out = _run(tmp_path, capsys, fresh)
    assert status == 2 and "format: committed 3, this run 4" in out


@pytest.mark.parametrize("tolerance", ["-0.1", "1.0"])
def test_a_tolerance_outside_0_1_is_refused(tmp_path, capsys, tolerance):
    with pytest.raises(SystemExit):
        _run(tmp_path, capsys, _committed(), "--tolerance", tolerance)
    assert f"--tolerance {float(tolerance)!r} is not allowed" in capsys.readouterr().err
