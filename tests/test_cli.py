"""The wmr-jax command line: output, files, and one-line errors with exit status 2."""

import json
import math
import re
import subprocess
import sys
from pathlib import Path
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


def test_simulate_says_when_the_robot_faces_backwards(capsys):
    """θ = θ_r ± 180° counts as arrived; the report says so rather than look like a miss."""
    seen = []
    for ref in ([30.0, 30.0, 0.0], [30.0, -30.0, 90.0]):
        assert main(["simulate", "--ref", *map(str, ref)]) == 0
        out = capsys.readouterr().out
        theta_r = math.radians(ref[2])
        # The independent reference's last heading decides which way it faces.
        final = w.reference_rollout([ref[0], ref[1], theta_r], w.Gains())["poses"][-1]
        backwards = math.cos(final[2] - theta_r) < 0
        assert ("facing backwards: θ − θ_r = " in out) == backwards, out
        seen.append(backwards)
    assert seen == [True, False]  # one run of each kind
    # A run stopped on its way, turned more than 90° from θ_r, is not said to face backwards.
    assert main(["simulate", "--ref", "0", "30", "180", "--steps", "15"]) == 0
    out = capsys.readouterr().out
    assert "arrival time   : never" in out and "facing backwards" not in out


def test_simulate_says_a_run_diverged_not_that_a_pose_is_too_far(capsys):
    """Absurd gains: the run leaves the compute dtype's range, said as such after the warning."""
    assert main(["simulate", "--ref", "30", "30", "0", "--k-r", "1e300"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "cannot settle" in err[-2]
    reach = float(err[-1].split("the robot reached x or y = ±")[1].split(" cm")[0])
    assert reach > 1e153  # beyond float64's range for squared distances, float32's too
    assert err[-1] == (
        f"wmr-jax: error: the run diverged: the robot reached x or y = ±{reach:.3g} cm (the "
        "warning above says why); allowed: gains and a --dt the sampled law settles with"
    )


def test_simulate_nonideal(capsys):
    argv = ["simulate", "--ref", "20", "-10", "45", "--kr", "60", "--velocity", "nonideal"]
    assert main(argv) == 0
    assert "arrival time" in capsys.readouterr().out


def test_simulate_takes_gains_from_a_file(capsys, tmp_path):
    """A tuned_gains.json (Gains field names, phi_m in radians) stands for the gain flags."""
    path = tmp_path / "tuned_gains.json"
    gains = w.Gains(kr=60.0, k_theta=8.0, phi_m=math.radians(60.0))
    path.write_text(json.dumps({k: float(v) for k, v in vars(gains).items()}))
    ref = ["25", "-10", "30"]
    assert main(["simulate", "--ref", *ref, "--gains", str(path)]) == 0
    from_file = capsys.readouterr().out
    flags = ["--kr", "60", "--k-theta", "8", "--phi-m", "60"]
    assert main(["simulate", "--ref", *ref, *flags]) == 0
    # The same run; the file's output names the file the gains came from.
    named = f"gains          : {path} (shim-sung)\n"
    assert from_file == named + capsys.readouterr().out


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--ref", "1", "nan", "0"], "--ref Y 'nan' is not allowed"),
        (["simulate", "--ref", "1", "2", "0", "--alpha", "0.7"], "--alpha: gains.alpha = 0.7"),
        (["simulate", "--ref", "1", "2", "0", "--dt", "0"], "--dt '0' is not allowed"),
        (["simulate", "--ref", "1", "2", "0", "--velocity", "warp"], "--velocity 'warp'"),
        # A flag given in degrees is judged in degrees.
        (["simulate", "--ref", "1", "2", "0", "--phi-m", "95"], "--phi-m 95 is not allowed"),
        (["simulate", "--ref", "1", "2", "0", "--steps", "0"], "--steps '0' is not allowed"),
        (["simulate", "--ref", "1", "2", "0", "--plot", "/dev/null/x.png"], "is a file"),
        (["simulate", "--ref", "1", "2", "0", "--plot", "{dir}.txt"], "allowed: a path ending in"),
        (["simulate", "--ref", "1", "2", "0", "--gains", "{missing}"], "cannot be read"),
        (["simulate", "--ref", "1", "2", "0", "--gains", "{bad_key}"], "keys among kr"),
        (["simulate", "--ref", "1", "2", "0", "--gains", "{bad_value}"], "gains.alpha = 0.7"),
        (["simulate", "--ref", "1", "2", "0", "--gains", "{good}", "--kr", "60"], "--kr is not"),
        (["bench", "--sizes", "0"], "--sizes '0' is not allowed"),
        (["bench", "--dtype", "float16"], "allowed: float32, float64"),
        (["bench", "--cases", "warp_drive"], "--cases 'warp_drive' is not allowed"),
        (["bench", "--wait-idle", "-1"], "--wait-idle '-1' is not allowed"),
        (["bench", "--sizes", "10000000000000"], "--sizes '10000000000000' is not allowed"),
        (["bench", "--cpu-devices", "100000"], "allowed: an integer >= 1 and <= 1024"),
        # Checked before the benchmark runs: these sizes would take hours.
        (["bench", "--sizes", "100000000", "--json", "/dev/null/b.json"], "is a file"),
        (["paper", "--out", "/dev/null/results"], "is a file"),
        (["robustness", "--out", "{dir}", "--seed", "18446744073709551616"], "--seed '1844"),
        (["robustness", "--out", "{dir}", "--runs", "10000000"], "--runs '10000000'"),
        (["animate", "--out", "{dir}.gif", "--seconds", "100000"], "--seconds"),
        # Tried before the work, not found unwritable after it.
        (["sweep", "--out", "/proc/wmr-x", "--poses", "10"], "a place this process can write"),
        # tune: a flag its mode would ignore, and sizes, before any work.
        (
            ["tune", "--out", "{dir}", "--robust", "--schedule"],
            "--schedule is not allowed with --robust, which tunes a gain schedule already",
        ),
        (
            ["tune", "--out", "{dir}", "--compare", "--checkpoint-every", "5"],
            "--checkpoint-every is not allowed with --compare, which does not use it",
        ),
        (
            ["tune", "--out", "{dir}", "--robust", "--compare", "--horizon", "5"],
            "--horizon is not allowed with --robust, which does not use it",
        ),
        (
            ["tune", "--out", "{dir}", "--robust", "--compare", "--checkpoint-every", "5"],
            "--checkpoint-every is not allowed with --robust --compare, which keeps each seed",
        ),
        (["tune", "--out", "{dir}", "--robust", "--checkpoint-every", "0"], "'0' is not allowed"),
        (["tune", "--out", "{dir}", "--eval-poses", "1000000000000"], "--eval-poses '1000"),
        (["tune", "--out", "{dir}", "--poses", "1e12"], "--poses '1e12' is not allowed"),
        (["tune", "--out", "{dir}", "--horizon", "1e-12"], "horizon = 1e-12 s is shorter"),
        # A whole period used to be run for it.
        (["tune", "--out", "{dir}", "--horizon", "0.001"], "horizon = 0.001 s is shorter"),
        (["sweep", "--out", "{dir}", "--poses", "100000000000000"], "--poses: n_poses = 1000"),
        (["sweep", "--out", "{dir}", "--headings", "1e300"], "--headings: headings_deg = "),
        # The library's advice to switch JAX to float64 is not a flag: left out.
        (["simulate", "--ref", "1e300", "0", "0"], "--ref: ref = [1e+300, 0.0, 0.0] is too far"),
        (["simulate", "--ref", "1", "0", "0", "--dt", "1e-320"], "--dt: dt = 1e-320"),
        (["demo", "--out", "/dev/null"], "a folder (it is a file)"),
        # An empty path was the current folder.
        (["sweep", "--out", "", "--poses", "10"], "--out '' is not allowed; allowed: a folder"),
        (["bench", "--json", ""], "--json '' is not allowed; allowed: a file name"),
        # Only the scalar reference is timed on --reference-poses: for other cases it was ignored.
        (
            ["bench", "--cases", "final_poses", "--reference-poses", "5"],
            "--reference-poses is not allowed without the scalar_reference case",
        ),
        # --knots sizes a schedule's tables: alone it would size nothing.
        (["tune", "--out", "{dir}", "--knots", "30"], "--knots is not allowed without --schedule"),
        (["tune", "--out", "{dir}", "--schedule", "--knots", "61"], "--knots '61' is not"),
        # --robust tunes a schedule by default, whose tables --knots sizes; not --fixed gains.
        (["tune", "--out", "{dir}", "--robust", "--fixed", "--knots", "4"], "--knots is not"),
        (["tune", "--out", "{dir}", "--robust", "--knots", "61"], "--knots '61' is not"),
        # --compare runs its own seeds 0-2: --seed 3 was ignored without a word.
        (["tune", "--out", "{dir}", "--compare", "--seed", "3"], "--seed is not allowed with"),
        # Nested beyond Python's recursion limit: a RecursionError traceback before.
        (["simulate", "--ref", "1", "2", "0", "--gains", "{deep}"], "cannot be read"),
        (["simulate", "--ref", "1", "2", "0", "--gains", "{twice}"], "the key 'kr' is given twice"),
    ],
)
def test_bad_values_give_one_line_and_status_2(capsys, tmp_path, argv, message):
    files = {
        "missing": str(tmp_path / "nothing.json"),
        "bad_key": _write(tmp_path, "k.json", '{"kr": 60, "warp": 1}'),
        "bad_value": _write(tmp_path, "v.json", '{"alpha": 0.7}'),
        "good": _write(tmp_path, "g.json", '{"kr": 60}'),
        "dir": str(tmp_path / "out"),
        "deep": _write(tmp_path, "deep.json", "[" * 100_000 + "]" * 100_000),
        "twice": _write(tmp_path, "twice.json", '{"kr": 60, "kr": 70}'),
    }
    assert main([arg.format(**files) for arg in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wmr-jax: error:") and message in err[0]
    assert "jax_enable_x64" not in err[0]


def test_argparse_errors_are_one_line_and_status_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--ref", "1", "2"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--ref" in err[0]


def test_help_shows_the_defaults(capsys):
    with pytest.raises(SystemExit) as info:
        main(["bench", "--help"])
    assert info.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "(default: 100)" in out and "(default: 1000 10000 100000)" in out
    assert "grad_tuning_loss" in out  # the cases one may choose


def test_every_help_states_each_default_once(capsys):
    from wmr_jax._src.cli.main import COMMANDS

    for command in COMMANDS:
        with pytest.raises(SystemExit):
            main([command, "--help"])
        out = " ".join(capsys.readouterr().out.split())
        assert not re.search(r"\(default: [^()]*\) \(default:", out), command
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert out.count("(default: nominal)") == 1


def test_demo_writes_the_paper_figures_and_tables(tmp_path, capsys):
    """End to end: Fig. 7 and its table, then Figs. 6-10 and the paper table."""
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for name in ("fig6", "fig7", "fig8", "fig9", "fig10", "wheels_k120", "wheels_k60"):
        assert (tmp_path / f"{name}.png").stat().st_size > 5000
    fig7 = json.loads((tmp_path / "fig7.json").read_text())
    assert len(fig7["runs"]) == 7 and fig7["gains"]["kr"] == 120.0
    assert "| ref | arrival_s |" in (tmp_path / "fig7.md").read_text()
    table = json.loads((tmp_path / "paper_table.json").read_text())
    assert len(table["runs"]) == 28  # 7 references × 2 gains × 2 loops
    assert table["summary"]["fig6"]["bound_cm"] == pytest.approx(1.61, abs=0.005)
    k120, k60 = table["summary"]["kr=120"], table["summary"]["kr=60"]
    assert (k120["condition"], k60["condition"]) == ("violated", "holds")
    # The README's path gaps between the ideal and the non-ideal loop (cm).
    assert (k120["max_deviation_cm"], k120["mean_deviation_cm"]) == pytest.approx(
        (4.11, 3.39), abs=0.01
    )
    assert (k60["max_deviation_cm"], k60["mean_deviation_cm"]) == pytest.approx(
        (1.13, 1.03), abs=0.01
    )
    assert "max 4.11 cm, mean 3.39 cm" in out and "max 1.13 cm, mean 1.03 cm" in out
    assert "| kr | loop | ref |" in (tmp_path / "paper_table.md").read_text()
    assert not list(tmp_path.glob(".*.tmp"))  # no half-written files left


def test_console_script_help():
    out = subprocess.run(
        [sys.executable, "-m", "wmr_jax", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "simulate" in out and "demo" in out and "paper" in out and "bench" in out


def test_an_interrupted_compare_keeps_its_finished_seeds_and_resumes(tmp_path, monkeypatch, capsys):
    # compare is replaced by a stand-in that returns rows at once and is
    # interrupted at the fifth (problem, seed): the four before it are kept.
    from wmr_jax._src.tuning import compare as compare_module

    calls = []

    def fake(*, seeds, problems, configs, progress, robot=None):
        calls.append((problems[0], seeds[0]))
        if len(calls) == 5:
            raise KeyboardInterrupt
        row = {"mean_arrival": 0.5, "success_rate": 1.0, "peak_wheel_speed": 100.0, "poses": 2}
        extra = {"wall_s": 1.0, "candidates": None, "vs_turn_drive_turn": 1.2}
        bounds = {"turn_drive_turn_s": 0.4, "lower_bound_s": 0.35, "vs_lower_bound": 1.4}
        methods = ("gradient", "cma-es", "random search")
        return [
            {"problem": problems[0], "seed": seeds[0], "method": m, **row, **extra, **bounds}
            for m in methods
        ]

    monkeypatch.setattr(compare_module, "compare", fake)
    out = tmp_path / "cmp"
    argv = ["tune", "--out", str(out), "--compare", "--iters", "1"]
    assert main(argv) == 130
    assert "interrupted (the same command with --resume keeps" in capsys.readouterr().err
    kept = json.loads((out / "compare.json").read_text())["rows"]
    assert len(kept) == 12 and {r["problem"] for r in kept} == {"fixed", "schedule"}
    calls.clear()
    calls.append(None)  # the next call is the 2nd: not interrupted
    assert main([*argv, "--resume"]) == 0
    assert calls[1:] == [("schedule", 1), ("schedule", 2)]
    assert len(json.loads((out / "compare.json").read_text())["rows"]) == 18
    assert "fixed seed 0: kept from" in capsys.readouterr().out
    # Other settings are refused, naming the difference.
    assert main(["tune", "--out", str(out), "--compare", "--iters", "2", "--resume"]) == 2
    assert "iters = 1 there, 2 now" in capsys.readouterr().err


def test_compare_with_schedule_compares_that_schedule_alone(tmp_path, monkeypatch, capsys):
    """--compare --schedule --knots K hands compare the K-knot schedule's config only."""
    from wmr_jax._src.tuning import compare as compare_module

    seen = []

    def fake(*, seeds, problems, configs, progress, robot=None):
        seen.append((problems, configs[problems[0]].knots, seeds[0]))
        row = {"mean_arrival": 0.5, "success_rate": 1.0, "wall_s": 1.0, "parameters": 14}
        bounds = {"turn_drive_turn_s": 0.4, "lower_bound_s": 0.35}
        methods = ("gradient", "cma-es", "random search")
        return [
            {"problem": problems[0], "seed": seeds[0], "method": m, **row, **bounds}
            for m in methods
        ]

    monkeypatch.setattr(compare_module, "compare", fake)
    argv = ["tune", "--out", str(tmp_path), "--compare", "--schedule", "--knots", "3"]
    assert main(argv) == 0
    assert seen == [(("schedule",), 3, 0), (("schedule",), 3, 1), (("schedule",), 3, 2)]
    assert "| schedule (14) | gradient |" in capsys.readouterr().out
    # Resumed as another comparison, it names what differs (it raised AttributeError).
    assert main(["tune", "--out", str(tmp_path), "--compare", "--resume"]) == 2
    err = capsys.readouterr().err
    assert "configs.fixed only now; configs.schedule.knots = 3 there, 10 now" in err, err


def test_tune_robust_writes_its_gains_before_judging_them(tmp_path, monkeypatch):
    # The searches and the evaluation take longer than the tuning: an
    # interruption there used to lose the tuned gains.
    from wmr_jax._src.tuning import robust

    def fake(config, *, progress_fn, on_tuned, **_):
        on_tuned(w.Gains(kr=70.0), [1.0, 0.9])
        raise KeyboardInterrupt

    monkeypatch.setattr(robust, "tune_robust", fake)
    assert main(["tune", "--out", str(tmp_path), "--robust", "--iters", "2"]) == 130
    controller, gains, *_ = w.load_tuned(tmp_path / "tuned_gains.json")
    assert gains.kr == 70.0
    assert json.loads((tmp_path / "robust_loss.json").read_text()) == {"loss": [1.0, 0.9]}


def test_bench_adds_repeated_cases_and_names_a_case_it_cannot_run(tmp_path, capsys):
    path = tmp_path / "b.json"
    common = ["bench", "--sizes", "2", "--steps", "1", "--repeats", "1"]
    argv = [*common, "--cases", "final_poses", "--cases", "final_poses_sharded"]
    assert main([*argv, "--dtype", "float64", "--cpu-devices", "1", "--json", str(path)]) == 0
    rows = json.loads(path.read_text())["rows"]
    assert [r["case"] for r in rows] == ["final_poses", "final_poses_sharded"]
    assert rows[1]["skipped"].startswith("skipped: needs 2 or more devices (1 here")


def test_sweep_resume_refuses_chunks_of_other_settings_and_keeps_them(tmp_path, capsys):
    # They were replaced after a warning; --resume asked to keep them.
    out = tmp_path / "maps"
    argv = ["sweep", "--out", str(out), "--poses", "8", "--chunk", "4", "--controller"]
    argv += ["shim-sung", "--no-progress", "--resume"]
    assert main([*argv, "--float32"]) == 0
    chunks = out / "chunks" / "shim-sung"
    before = {p.name: p.read_bytes() for p in chunks.glob("chunk_*.npz")}
    assert before
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--resume:" in err and "dtype 'float32' -> 'float64'" in err and "a fresh --out" in err
    assert {p.name: p.read_bytes() for p in chunks.glob("chunk_*.npz")} == before


def test_library_errors_name_the_flag_and_leave_out_advice_no_flag_follows():
    from wmr_jax._src.checks import _FLOAT64_HINT
    from wmr_jax._src.cli import flags

    with pytest.raises(ValueError) as err, flags.as_flags({"ref": "--ref"}):
        raise ValueError(
            f"ref = [1e+30] is too far for float32; allowed: |x| <= 1e18{_FLOAT64_HINT}"
        )
    assert str(err.value) == "--ref: ref = [1e+30] is too far for float32; allowed: |x| <= 1e18"
    with pytest.raises(ValueError, match=r"^other = 1 is not allowed$"), flags.as_flags({}):
        raise ValueError("other = 1 is not allowed")


def test_the_program_ends_an_interrupted_run_at_once_with_status_130(monkeypatch):
    """An interrupted run's status is 130, not a crash of the interpreter's clean-up after it.

    Cut while XLA compiled, ``wmr-jax tune`` reported the interruption and then
    died in the interpreter's teardown (status 139, a segmentation fault) in
    four of six tries; the program now ends at once after the report.
    """
    import tomllib

    from wmr_jax._src.cli import main as cli_main

    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    scripts = tomllib.loads(pyproject.read_text())["project"]["scripts"]
    assert scripts == {"wmr-jax": "wmr_jax._src.cli.main:entry"}
    ended = []

    def os_exit(status):
        ended.append(status)
        raise SystemExit(status)

    monkeypatch.setattr(cli_main.os, "_exit", os_exit)
    for status, how in ((130, [130]), (0, []), (2, [])):
        monkeypatch.setattr(cli_main, "main", lambda status=status: status)
        with pytest.raises(SystemExit) as exit_:
            cli_main.entry()
        assert exit_.value.code == status and ended == how
        ended.clear()
