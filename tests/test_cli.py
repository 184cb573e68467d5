"""The wmr-jax command line: output, files, and one-line errors with exit status 2."""

import json
import math
import subprocess
import sys
from types import SimpleNamespace

import pytest

import wmr_jax as w
from wmr_jax.cli import main


def test_simulate_prints_report(capsys, tmp_path):
    plot = tmp_path / "run.png"
    code = main(["simulate", "--ref", "30", "30", "0", "--kr", "60", "--plot", str(plot)])
    out = capsys.readouterr().out
    ref = [30.0, 30.0, 0.0]
    expected = w.reference_rollout(ref, w.Gains(kr=60.0))
    arrival = float(w.arrival_time(SimpleNamespace(poses=expected["poses"]), ref, dt=0.033))
    assert code == 0 and math.isfinite(arrival)
    assert "final pose" in out and f"arrival time   : {arrival:.3f} s" in out
    assert "R0=" in out and "R3=" in out
    assert plot.stat().st_size > 1000


def test_simulate_nonideal(capsys):
    assert (
        main(["simulate", "--ref", "20", "-10", "45", "--kr", "60", "--velocity", "nonideal"]) == 0
    )
    assert "arrival time" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--ref", "1", "nan", "0"], "is not finite"),
        (["simulate", "--ref", "1", "2", "0", "--alpha", "0.7"], "gains.alpha = 0.7"),
        (["simulate", "--ref", "1", "2", "0", "--dt", "0"], "dt = 0.0"),
        (["simulate", "--ref", "1", "2", "0", "--velocity", "warp"], "velocity = 'warp'"),
        (["simulate", "--ref", "1", "2", "0", "--phi-m", "95"], "gains.phi_m"),
    ],
)
def test_bad_values_give_one_line_and_status_2(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wmr-jax: error:") and message in err[0]


def test_argparse_errors_are_status_2():
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--ref", "1", "2"])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--ref", "1", "2", "3", "--steps", "0"])
    assert info.value.code == 2


def test_paper_command_writes_figures_and_table(tmp_path, capsys):
    assert main(["paper", "--out", str(tmp_path)]) == 0
    for name in ("fig6", "fig7", "fig8", "fig9", "fig10", "wheels_k120", "wheels_k60"):
        assert (tmp_path / f"{name}.png").stat().st_size > 5000
    table = json.loads((tmp_path / "paper_table.json").read_text())
    assert len(table["runs"]) == 28  # 7 references × 2 gains × 2 loops
    assert table["summary"]["kr=120"]["condition"] == "violated"
    assert table["summary"]["kr=60"]["condition"] == "holds"
    assert "| kr | loop | ref |" in (tmp_path / "paper_table.md").read_text()
    assert not list(tmp_path.glob(".*.tmp"))  # no half-written files left


def test_console_script_help():
    out = subprocess.run(
        [sys.executable, "-m", "wmr_jax.cli", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "simulate" in out and "demo" in out and "paper" in out
