"""The robot through sweep, compare, waypoints and bench; what a sweep keeps and trusts.

Every command here runs a handful of poses: the sweeps share one compiled
program (8 poses in chunks of 4, the 6 s horizon), so most tests only run it.
"""

import json
import math
import os
import warnings

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src import io
from wmr_jax._src.cli.main import main
from wmr_jax._src.model.params import Robot
from wmr_jax._src.model.robots import TURTLEBOT3_BURGER, robot_json
from wmr_jax._src.studies import maps
from wmr_jax._src.studies.robustness import study_horizon

# Eight poses (two headings), two chunks of four: the compiled sweep every test shares.
SWEEP = ["--poses", "8", "--headings", "0", "90", "--chunk", "4", "--controller", "shim-sung"]


@pytest.fixture
def no_figures(monkeypatch):
    """The commands' figures are other tests' business: drawing them costs seconds."""
    from wmr_jax._src.report import figures as report_figures
    from wmr_jax._src.report import maps as report_maps

    monkeypatch.setattr(report_maps, "map_figure", lambda path, *args, **kwargs: path)
    monkeypatch.setattr(report_figures, "save_figure", lambda fig, path, **kwargs: path)


def _robot_file(tmp_path, name, **fields):
    path = tmp_path / name
    path.write_text(json.dumps(fields))
    return str(path)


def _sweep_refs():
    return maps.pose_grid(8, (0.0, 90.0)).refs


def _chunks_run():
    """How many chunks the sweeps of ``SWEEP`` run: their size is a multiple of the devices."""
    import jax

    devices = len(jax.local_devices())  # the command may have split the CPU into several
    return math.ceil(8 / (math.ceil(4 / devices) * devices))


def _chunks_text(done):
    total = _chunks_run()
    return f"shim-sung {done} of {total} chunk{'s' if total > 1 else ''}"


def _inodes(folder):
    return {p.name: os.stat(p).st_ino for p in sorted(folder.glob("chunk_*.npz"))}


# ---------------------------------------------------------------- sweep


def test_sweep_runs_the_robot_and_records_it(tmp_path, capsys, no_figures):
    slow = _robot_file(tmp_path, "slow.json", half_track=4.0, v_max=50.0)
    out = tmp_path / "maps"
    # The paper robot's horizon, asked for: the compiled sweep of the other tests.
    argv = ["sweep", "--out", str(out), *SWEEP, "--no-progress", "--robot", slow, "--horizon", "6"]
    assert main(argv) == 0
    printed = capsys.readouterr()
    assert f"robot {slow!r}: custom (L = 4 cm, V_max = 50 cm/s" in printed.out
    # Shim-Sung runs the paper's feasible gains within these wheels (30 + 4 × 5 =
    # 50 cm/s), not its default k_r = 120, which would ask 160 cm/s of them.
    assert "; horizon 6 s; shim-sung at k_r = 30 cm/s, k_theta = 5 rad/s" in printed.out
    assert "exceeds v_max" not in printed.err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot"] == robot_json(Robot(half_track=4.0, v_max=50.0))
    assert summary["robot_label"] == slow and summary["horizon_s"] == 6.0
    # The figures' titles and the table's heading name the robot they ran.
    assert f"start (0, 0, 0°), robot {slow}" in (out / "summary.md").read_text()
    # "over V_max" is counted against this robot's 50 cm/s: none.
    row = summary["rows"][0]
    assert 40 < row["max peak wheel cm/s"] <= 50 and row["over V_max"] == 0


def test_a_slower_robot_gets_a_longer_horizon(monkeypatch):
    steps, gains = [], []

    def fake(refs, params=None, **kwargs):
        steps.append(kwargs["steps"])
        gains.append(params)
        n = len(refs)
        ones = np.ones(n)
        return maps.PoseMetrics(ones, ones, ones, np.zeros(n, np.int32), ones)

    monkeypatch.setattr(maps, "evaluate_poses", fake)
    # The paper's feasible gains ask 60 + 10 L = 100 cm/s, twice this robot's wheels.
    half = Robot(half_track=4.0, v_max=50.0)
    assert study_horizon(half) == 12.0 and study_horizon() == 6.0
    assert study_horizon(Robot(v_max=250.0)) == 6.0  # a faster robot keeps 6 s
    assert study_horizon(TURTLEBOT3_BURGER) == 37.0
    study = maps.map_study(8, controller_names=["shim-sung"], robot=half)
    assert steps == [math.ceil(12.0 / 0.033)] and study.summary["horizon_s"] == 12.0
    assert study.summary["robot_label"] == "custom"
    # ... for the gains it runs: the paper's feasible ones within these wheels
    # (k_r = 30, k_theta = 5: 30 + 4 × 5 = 50 cm/s), not the default k_r = 120.
    assert len(gains) == 1 and (gains[0].kr, gains[0].k_theta) == pytest.approx((30.0, 5.0))


def test_a_resumed_sweep_with_another_robot_is_refused_by_name(tmp_path, capsys, no_figures):
    # The same horizon (v_max 125); on another robot than the paper's the sweep
    # also runs its own Shim-Sung gains (the paper's feasible ones), so the two
    # settings that differ are named.
    wide = _robot_file(tmp_path, "wide.json", half_track=3.0)
    argv = ["sweep", "--out", str(tmp_path / "maps"), *SWEEP, "--no-progress", "--resume"]
    assert main(argv) == 0
    chunks = tmp_path / "maps" / "chunks" / "shim-sung"
    before = _inodes(chunks)
    capsys.readouterr()
    assert main([*argv, "--robot", wide]) == 2
    err = capsys.readouterr().err
    assert "--resume:" in err and "other settings (gains, robot)" in err, err
    assert _inodes(chunks) == before  # refused, not replaced


def _errors(text):
    """The lines of stderr other than warnings (each is shown once per process)."""
    return [line for line in text.splitlines() if not line.startswith("wmr-jax: warning:")]


def _interrupt_after_the_first_chunk(monkeypatch):
    real = maps.sweep

    def interrupted(*args, on_chunk=None, **kwargs):
        def stop(done, total):
            if on_chunk is not None:  # the command's count of finished chunks
                on_chunk(done, total)
            raise KeyboardInterrupt

        return real(*args, on_chunk=stop, **kwargs)

    monkeypatch.setattr(maps, "sweep", interrupted)
    return real


def test_an_interrupted_sweep_without_resume_says_nothing_was_kept(tmp_path, capsys, monkeypatch):
    _interrupt_after_the_first_chunk(monkeypatch)
    out = tmp_path / "maps"
    assert main(["sweep", "--out", str(out), *SWEEP, "--no-progress"]) == 130
    err = _errors(capsys.readouterr().err)
    assert len(err) == 1 and f"nothing was kept ({_chunks_text(1)} finished)" in err[0], err
    assert "--resume keeps" in err[0] and not (out / "chunks").exists()


def test_an_interrupted_sweep_with_resume_says_what_it_kept_and_reuses_it(
    tmp_path, capsys, monkeypatch, no_figures
):
    real = _interrupt_after_the_first_chunk(monkeypatch)
    out = tmp_path / "maps"
    argv = ["sweep", "--out", str(out), *SWEEP, "--no-progress", "--resume"]
    assert main(argv) == 130
    chunks = out / "chunks" / "shim-sung"
    said, err = capsys.readouterr()
    # Nothing to resume yet: said, as tune says it of a missing checkpoint.
    assert f"--resume: no finished chunks of shim-sung in {out / 'chunks'}; starting from" in said
    err = _errors(err)
    assert err == [
        f"wmr-jax: interrupted; kept in {out / 'chunks'}: {_chunks_text(1)} (the same "
        "command, with --resume, reuses them)"
    ]
    kept = _inodes(chunks)
    assert list(kept) == ["chunk_000000.npz"]
    monkeypatch.setattr(maps, "sweep", real)
    assert main(argv) == 0
    said = f"--resume: finished chunks in {out / 'chunks'} (shim-sung 1): reused if they are of"
    assert said in capsys.readouterr().out
    after = _inodes(chunks)
    assert list(after) == [f"chunk_{i:06d}.npz" for i in range(_chunks_run())]
    assert after["chunk_000000.npz"] == kept["chunk_000000.npz"]  # reused, not recomputed


def test_the_progress_bar_names_the_controller(monkeypatch):
    import tqdm.auto

    shown = []

    class Bar:
        def __init__(self, **kwargs):
            shown.append(kwargs["desc"])

        def update(self, n):
            pass

        def close(self):
            pass

    monkeypatch.setattr(tqdm.auto, "tqdm", Bar)
    maps.evaluate_poses(_sweep_refs(), controller="shim-sung", chunk=4, progress=True)
    assert shown == ["shim-sung sweep, 8 poses"]


def _resumed(refs, folder):
    """Resume the sweep in ``folder``: its results and the warnings that recompute a chunk."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        results = w.sweep(refs, steps=182, chunk_size=4, out=folder)
    return results, [str(c.message) for c in caught if "recomputing" in str(c.message)]


def test_chunk_metadata_of_another_shape_or_edited_is_recomputed_with_one_warning(tmp_path):
    refs = _sweep_refs()
    full = w.sweep(refs, steps=182, chunk_size=4, out=tmp_path)
    first = tmp_path / "chunk_000000.npz"
    values, meta = io.load_arrays(first)

    # A list for metadata, with a checksum that matches it: no AttributeError, one warning.
    io.save_arrays(first, values, ["fingerprint", meta["fingerprint"]])
    inode = os.stat(first).st_ino
    again, messages = _resumed(refs, tmp_path)
    assert len(messages) == 1 and str(first) in messages[0], messages
    assert "that is no JSON object" in messages[0] and os.stat(first).st_ino != inode
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(again[name], full[name], err_msg=name)

    # A dict without a key this sweep writes: one warning naming the file and the key.
    io.save_arrays(first, values, {"fingerprint": meta["fingerprint"]})
    _, messages = _resumed(refs, tmp_path)
    assert len(messages) == 1 and str(first) in messages[0], messages
    assert "without a text refs_digest" in messages[0]

    # Only the metadata edited, the arrays and their checksum left as they were: the
    # checksum covers the metadata, so the chunk is not trusted.
    with np.load(first) as data:
        stored = {name: data[name] for name in data.files}
    edited = json.loads(str(stored["__meta__"]))
    edited["refs_digest"] = "0" * 16
    stored["__meta__"] = np.asarray(json.dumps(edited, sort_keys=True))
    np.savez(first, **stored)
    inode = os.stat(first).st_ino
    again, messages = _resumed(refs, tmp_path)
    assert len(messages) == 1 and str(first) in messages[0], messages
    assert "checksum does not match" in messages[0] and os.stat(first).st_ino != inode
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(again[name], full[name], err_msg=name)


# ---------------------------------------------------------------- compare


def test_compare_runs_the_robot_and_records_it(tmp_path, capsys, monkeypatch):
    seen, gains = [], []

    def fake(refs, params=None, **kwargs):
        seen.append((kwargs["robot"], kwargs["steps"]))
        gains.append((kwargs["controller"], params))
        n = len(refs)
        return maps.PoseMetrics(
            arrival=np.ones(n),
            path=np.ones(n),
            peak_wheel=np.full(n, 50.0),  # over the Burger's 22.72 cm/s, under the paper's 125
            zigzag=np.zeros(n, np.int32),
            final_distance=np.zeros(n),
        )

    monkeypatch.setattr(maps, "evaluate_poses", fake)
    argv = ["compare", "--out", str(tmp_path), "--poses", "2", "--no-progress"]
    assert main([*argv, "--robot", "turtlebot3-burger"]) == 0
    printed = capsys.readouterr().out
    horizon = 37.0  # 6 s × (60 + 10 × 8 cm) / 22.72 cm/s, rounded up to 0.1 s
    assert "horizon 37 s (6 s × (60 + 10 L) / v_max, rounded up to 0.1 s)" in printed
    # Shim-Sung runs the paper's feasible gains within the Burger's wheels
    # (k_r : k_theta = 60 : 10, k_r + 8 k_theta = 22.72 cm/s), and says so; the
    # baselines keep their published gains.
    kr = 22.72 * 60 / (60 + 8 * 10)
    assert f"shim-sung at k_r = {kr:.4g} cm/s, k_theta = {kr / 6:.4g} rad/s" in printed
    shim = [p for name, p in gains if name == "shim-sung"]
    assert len(shim) == 1 and (shim[0].kr, shim[0].k_theta) == pytest.approx((kr, kr / 6))
    assert [p for name, p in gains if name != "shim-sung"][0::2] == [None, None]
    assert all(robot is TURTLEBOT3_BURGER for robot, _ in seen) and len(seen) == 5
    assert {steps for _, steps in seen} == {math.ceil(horizon / 0.033)}
    stored = json.loads((tmp_path / "comparison.json").read_text())
    assert stored["robot"] == robot_json(TURTLEBOT3_BURGER)
    assert stored["robot_label"] == "turtlebot3-burger" and stored["horizon_s"] == horizon
    assert all(row["over V_max"] == 1.0 for row in stored["rows"])
    assert printed.endswith(
        "note: 5 of the 5 rows have runs over V_max = 22.72 cm/s: the ideal loop follows each "
        "wheel command as asked; --velocity nonideal holds each wheel within V_max "
        "(docs/model.md §4.3)\n"
    )
    # Peaks of 50 cm/s, within the paper robot's 125: nothing to say. Nor in the non-ideal loop.
    assert main(argv) == 0
    assert "note:" not in capsys.readouterr().out
    assert main([*argv, "--robot", "turtlebot3-burger", "--velocity", "nonideal"]) == 0
    assert "note:" not in capsys.readouterr().out


# ---------------------------------------------------------------- waypoints


def test_waypoints_run_the_robot_for_longer_and_say_time_since_start(
    tmp_path, capsys, monkeypatch, no_figures
):
    from wmr_jax._src.studies import waypoints

    asked = []

    def chain(wp, *, params=None, robot=None, steps=None, **kwargs):
        # A two-period stand-in (the loop itself is test_waypoints' business).
        asked.append((robot, steps, params))
        traj = w.Trajectory(
            np.zeros((3, 3)), np.ones(2), np.ones(2), np.zeros(2, np.int32), np.ones((2, 2)),
            np.ones(2),
        )  # fmt: skip
        return waypoints.ChainRun(traj, np.zeros(2, np.int32), np.arange(1.0, 7.0))

    monkeypatch.setattr(waypoints, "chain_rollout", chain)
    slow = _robot_file(tmp_path, "slow.json", half_track=4.0, v_max=50.0)
    argv = ["waypoints", "--out", str(tmp_path / "wp"), "--controller", "shim-sung"]
    assert main([*argv, "--robot", slow]) == 0
    printed = capsys.readouterr().out
    assert "900 control periods (450 × 12 s / 6 s, the studies' horizon on it)" in printed
    assert "shim-sung at k_r = 30 cm/s, k_theta = 5 rad/s" in printed
    header = next(line for line in printed.splitlines() if line.startswith("| controller"))
    assert "| waypoint 1: time since start (s) |" in header and "leg 1 s" not in header
    assert len(asked) == 2 and all(float(r.v_max) == 50.0 and n == 900 for r, n, _ in asked)
    # Both runs (stop and pass) with the paper's feasible gains within its wheels.
    assert all((p.kr, p.k_theta) == pytest.approx((30.0, 5.0)) for _, _, p in asked)
    saved = json.loads((tmp_path / "wp" / "soccer.json").read_text())
    assert saved["robot"] == robot_json(Robot(half_track=4.0, v_max=50.0))
    assert saved["robot_label"] == slow and saved["steps"] == 900


# ---------------------------------------------------------------- bench


def test_bench_runs_the_robot_and_records_it(tmp_path, capsys, monkeypatch):
    from wmr_jax._src.sim import rollout

    robots = []

    def spy(refs, *args, robot=None, **kwargs):
        robots.append(robot)  # the rate of a stand-in: the engine is test_bench's business
        return np.asarray(refs)

    monkeypatch.setattr(rollout, "final_poses", spy)
    path = tmp_path / "b.json"
    argv = ["bench", "--sizes", "2", "--steps", "1", "--repeats", "1", "--cases", "final_poses"]
    argv += ["--dtype", "float64", "--cpu-devices", "1", "--json", str(path)]
    assert main([*argv, "--robot", "turtlebot3-burger"]) == 0
    assert "robot 'turtlebot3-burger': turtlebot3-burger (L = 8 cm" in capsys.readouterr().out
    assert robots and all(robot is TURTLEBOT3_BURGER for robot in robots)
    saved = json.loads(path.read_text())
    assert saved["robot"] == robot_json(TURTLEBOT3_BURGER)
    assert saved["robot_label"] == "turtlebot3-burger" and "robot" not in saved["config"]


# ---------------------------------------------------------------- animate


def test_animate_runs_the_robot_and_flags_are_spelled_whole(tmp_path, capsys, monkeypatch):
    from types import SimpleNamespace

    from wmr_jax._src.report import animation
    from wmr_jax._src.sim import rollout

    asked, drawn = [], []

    def fake(refs, params=None, **kwargs):
        asked.append((params, kwargs["robot"]))
        # What the runs are computed in: float64, whatever the session's default.
        dtype = jax.numpy.zeros(()).dtype
        return SimpleNamespace(poses=np.zeros((len(refs), kwargs["steps"] + 1, 3), dtype))

    def draw(path, poses, refs, **kwargs):
        drawn.append((poses.dtype, refs.shape, kwargs))
        return path

    monkeypatch.setattr(rollout, "batch_rollout", fake)
    monkeypatch.setattr(animation, "write_gif", draw)
    argv = ["animate", "--out", str(tmp_path / "a.gif"), "--seconds", "0.5"]
    assert main([*argv, "--robot", "turtlebot3-burger"]) == 0
    ((params, robot),) = asked
    assert robot == TURTLEBOT3_BURGER
    kr = 22.72 * 60 / (60 + 8 * 10)  # the paper's feasible gains within its wheels
    assert (params.kr, params.k_theta) == pytest.approx((kr, kr / 6))
    assert "robot 'turtlebot3-burger'" in capsys.readouterr().out
    with jax.enable_x64(False):
        assert main(argv) == 0 and asked[-1] == (None, None)  # the paper robot, its defaults
    dtype, shape, kwargs = drawn[-1]
    assert dtype == np.float64 and shape == (8, 3)
    title = "shim-sung, ideal loop: 8 robots from (0, 0, 0°)"
    assert kwargs == {"dt": 0.033, "title": title, "speed": 1.0}
    # A prefix of a flag is not that flag (``--robot`` once read as ``--robots``).
    with pytest.raises(SystemExit) as refused:
        main([*argv, "--rob", "3"])
    assert refused.value.code == 2
    # Named with the command's own help, which lists its flags.
    assert "unrecognized arguments: --rob 3 (see wmr-jax animate --help)" in capsys.readouterr().err
