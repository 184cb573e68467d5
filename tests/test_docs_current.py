"""The committed docs figures and data files are what their commands compute today.

``experiments/docs_fingerprint.py`` records, per stage of
``experiments/reproduce_readme.sh``, probes of the loops the stage's outputs
depend on and the checksums of the files it wrote; a change to a loop, or a
hand edit of a file, names the stage to rerun.
"""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _fingerprint_tool():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "docs_fingerprint", ROOT / "experiments" / "docs_fingerprint.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_docs_files_are_what_their_stage_computes_today():
    """A change to a loop that moves a committed figure or table names the stage to rerun."""
    assert _fingerprint_tool().check() == []


def test_the_check_command_checks_every_stage_unless_told_which(monkeypatch, capsys):
    tool = _fingerprint_tool()
    asked = []
    monkeypatch.setattr(tool, "check", lambda stages=None: asked.append(stages) or [])
    assert tool.main(["check"]) == 0  # argparse of Python 3.11 refused the empty list
    assert tool.main(["check", "maps", "tune"]) == 0
    assert asked == [[], ["maps", "tune"]]
    assert "every docs stage holds" in capsys.readouterr().out
    with pytest.raises(SystemExit) as info:
        tool.main(["check", "mapz"])
    assert info.value.code == 2
    assert "stage = 'mapz' is not allowed; allowed: paper, compare" in capsys.readouterr().err


def test_the_fingerprint_notices_a_moved_loop_and_an_edited_file(tmp_path, monkeypatch):
    tool = _fingerprint_tool()
    stored = json.loads(tool.RECORD.read_text())
    moved = json.loads(json.dumps(stored))
    moved["compare"]["probes"]["aicardi"][0] += 1e-6  # as if the baseline had moved
    moved["paper"]["files"]["fig6.png"] = "0" * 64  # as if fig6.png were edited by hand
    record = tmp_path / "fingerprints.json"
    record.write_text(json.dumps(moved))
    monkeypatch.setattr(tool, "RECORD", record)
    problems = tool.check(["compare", "paper"])
    assert any(p.startswith("compare: the aicardi loop moved") for p in problems), problems
    assert "paper: docs/fig6.png is not the file its stage wrote" in " ".join(problems)
    assert all("reproduce_readme.sh results/readme" in p for p in problems)


def test_the_settled_at_horizon_prose_is_the_committed_table():
    """docs/robustness.md's shares of the paper's gains under noise, from the data file."""
    import re

    rows = json.loads((ROOT / "docs" / "data" / "standard_conditions.json").read_text())["rows"]
    row = next(r for r in rows if r["condition"] == "noise" and r["gains"].startswith("paper"))
    runs, success, settled = row["runs"], row["success"], row["settled at horizon"]
    text = " ".join((ROOT / "docs" / "robustness.md").read_text().split())
    arrived, late = round(success * runs), round(settled * runs)
    assert f"{100 * success:.1f} % of the {runs} held-out runs count as arrived" in text
    # Both shares are of all runs (the table's column), and the count says what they mean.
    assert f"{100 * settled:.1f} % of the {runs} only settle" in text
    assert f"{late} of the {arrived} successes" in text
    assert re.search(rf"arrive. at {row['mean arrival s']:.2f} s of 6 on average", text)
