"""The README as a user meets it: its snippets run, its commands exist, its tables are the results.

The tables are held against the results that ``experiments/reproduce_readme.sh``
stores in ``docs/data/`` (the full-size runs take minutes); the commands
that print them are run here at a small size and must print what they store.
"""

import json
import math
import re
from pathlib import Path

import pytest

from wmr_jax.cli import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
STORED = ROOT / "docs" / "data"


def _blocks(language):
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def _table(text, first_column):
    """The rows (lists of cells) of the Markdown table whose header starts with ``first_column``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_column} |"))
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows[0], rows[2:]  # header, body (the --- line dropped)


def _agrees(text, value):
    """Whether a printed cell is ``value`` to the digits printed (3 significant, or all)."""
    text = text.strip("* ")
    if text.endswith("%"):
        text, value = text[:-1].strip(), 100.0 * value
    shown = float(text)
    if math.isinf(value):
        return math.isinf(shown)
    return shown in (float(f"{value:.3g}"), float(f"{value:g}"))


def _check_cells(cells, values):
    parts = [p for cell in cells for p in cell.split(" / ")]
    assert len(parts) == len(values), (cells, values)
    for part, value in zip(parts, values, strict=True):
        assert _agrees(part, value), (part, value)


def _check_comparison(text, rows):
    header, body = _table(text, "controller")
    assert header[1] == "success" and len(body) == len(rows)
    for cells, r in zip(body, rows, strict=True):
        assert cells[0].strip("* ").startswith(r["controller"]), (cells[0], r["controller"])
        _check_cells(
            cells[1:8],
            [r["success"], r["mean arrival s"], r["median arrival s"], r["p90 arrival s"]]
            + [r["mean path cm"], r["mean peak wheel cm/s"], r["max peak wheel cm/s"]]
            + [r["over V_max"], r["mean zigzag"], r["faster than shim-sung"]],
        )


def test_readme_python_snippets_run_as_written(tmp_path, monkeypatch):
    snippets = _blocks("python")
    assert snippets
    monkeypatch.chdir(tmp_path)  # anything a snippet writes stays out of the repository
    for code in snippets:
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})


def test_readme_commands_and_flags_exist(capsys):
    """Every ``wmr-jax`` line of the README names a command and flags its --help lists."""
    lines = [
        line.split("#")[0].split()
        for block in _blocks("bash")
        for line in block.splitlines()
        if line.startswith("wmr-jax ")
    ]
    assert len(lines) >= 8
    for words in lines:
        with pytest.raises(SystemExit) as done:
            main([words[1], "--help"])
        assert done.value.code == 0
        helptext = capsys.readouterr().out
        for flag in (w for w in words[2:] if w.startswith("--")):
            assert flag in helptext, (words, flag)


def test_readme_outputs_stay_under_results():
    """Files the README's commands write land in the git-ignored results/ folder."""
    for block in _blocks("bash"):
        for line in block.splitlines():
            for flag in ("--out", "--plot", "--json"):
                if line.startswith("wmr-jax ") and f"{flag} " in line:
                    path = line.split(f"{flag} ")[1].split()[0]
                    assert path.startswith("results"), line
    assert "results/" in (ROOT / ".gitignore").read_text()


def test_comparison_table_is_the_stored_run():
    stored = json.loads((STORED / "comparison.json").read_text())
    assert stored["poses"] == 200_000 and stored["seed"] == 0 and stored["dtype"] == "float64"
    assert "wmr-jax compare --poses 200000 --seed 0" in README.replace("--out results/compare ", "")
    _check_comparison(README, stored["rows"])


def test_paper_table_is_the_stored_run():
    summary = json.loads((STORED / "paper_table.json").read_text())["summary"]
    _, body = _table(README, "k_r")
    cases = [summary[f"kr={row[0]}"] for row in body]
    assert len(cases) == 2
    for cells, s in zip(body, cases, strict=True):
        assert _agrees(cells[1], s["k_r + L k_theta"]) and cells[2] == s["condition"]
        _check_cells(
            cells[3:6],
            [s["max_deviation_cm"], s["mean_deviation_cm"], s["ideal_arrival_s"]]
            + [s["nonideal_arrival_s"], s["ideal_zigzag"], s["nonideal_zigzag"]],
        )
        _check_cells(cells[6:7], [s["ideal_saturated_fraction"], s["nonideal_saturated_fraction"]])


def test_map_caption_states_the_pose_count():
    stored = json.loads((STORED / "maps_summary.json").read_text())
    assert f"{stored['poses']:,} poses" in README
    assert "over a million" not in README


def test_figures_and_results_come_from_the_reproduce_script():
    script = (ROOT / "experiments" / "reproduce_readme.sh").read_text()
    for name in re.findall(r"\(docs/([\w.-]+\.(?:png|gif))\)", README):
        assert (ROOT / "docs" / name).is_file(), name
        assert name.split(".")[0].split("_")[0] in script, name
    for path in STORED.glob("*.json"):
        assert f"docs/data/{path.name}" in script, path.name


def test_compare_command_prints_what_it_stores(tmp_path, capsys):
    argv = ["compare", "--out", str(tmp_path), "--poses", "40", "--seed", "3", "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    stored = json.loads((tmp_path / "comparison.json").read_text())
    assert stored["poses"] == 40 and stored["seed"] == 3
    _check_comparison(printed, stored["rows"])
    _check_comparison((tmp_path / "comparison.md").read_text(), stored["rows"])
    assert " %" in printed  # success is a percentage


def _slug(heading):
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces as -."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_links_between_pages_reach_a_file_and_heading():
    """Every relative link of the README and docs/*.md opens a file, and its #anchor a heading."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    checked = 0
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):  # an address elsewhere
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            assert file.is_file(), f"{page.name}: {target} opens no file"
            if anchor:
                headings = re.findall(r"^#+ (.+)$", file.read_text(encoding="utf-8"), re.M)
                slugs = {_slug(h) for h in headings}
                assert anchor in slugs, f"{page.name}: {target} names no heading of {file.name}"
            checked += 1
    assert checked > 20  # the pages do link to each other


def test_readme_robust_table_is_the_stored_standard_conditions():
    """The sensing table: success and mean arrival of each loop, as the robustness run stored."""
    stored = json.loads((STORED / "standard_conditions.json").read_text(encoding="utf-8"))
    rows = {(r["condition"], r["gains"]): r for r in stored["rows"]}
    header, body = _table(README, "condition")
    sets = ["paper (k_r = 60)", "robust-tuned, raw feedback", "robust-tuned"]
    assert header[1:] == [
        "paper (k_r = 60), raw", "robust-tuned, raw feedback", "robust-tuned with its EKF"
    ]  # fmt: skip
    conditions = ["model robot", "nominal", "latency", "noise", "both"]
    assert [cells[0].split(" (")[0] for cells in body] == conditions
    for cells, condition in zip(body, conditions, strict=True):
        for cell, name in zip(cells[1:], sets, strict=True):
            row = rows[(condition, name)]
            parts = [p.strip() for p in cell.strip("* ").split(",")]
            assert _agrees(parts[0], row["success"]), (condition, name, cell)
            if len(parts) > 1:
                assert _agrees(parts[1].removesuffix(" s"), row["mean arrival s"]), (cell, row)
            else:
                assert row["success"] == 0.0, (condition, name, cell)
    # The robust-tuned loop is the one with an estimator; the raw one has none.
    assert rows[("both", "robust-tuned")]["feedback"] == "ekf"
    assert rows[("both", "robust-tuned, raw feedback")]["feedback"] == "raw"
