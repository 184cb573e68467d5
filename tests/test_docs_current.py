"""The committed docs figures and data files are what their commands compute today.

``experiments/docs_fingerprint.py`` records, per stage of
``experiments/reproduce_readme.sh``, probes of the loops the stage's outputs
depend on and the checksums of the files it wrote; a change to a loop, or a
hand edit of a file, names the stage to rerun.
"""

import json
from pathlib import Path

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
