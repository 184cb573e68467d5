"""Chunked sweeps: the streamed metrics equal those of stored trajectories (docs/model.md §6),
and an interrupted sweep resumes from its checked chunk files."""

import math
import warnings

import jax
import numpy as np
import pytest
from conftest import random_refs, run_metrics

import wmr_jax as w
from wmr_jax import studies

DT = 0.033
STEPS = 40
N, HORIZON = 40, 182  # as in test_maps.py: the reference metrics compile once for both


def _poses(seed, n):
    return random_refs(seed, n)  # w.sample_poses(seed, n) as a writable NumPy copy


def _expected(refs, gains, **kwargs):
    """The docs/model.md §6 metrics from whole trajectories, as the rest of the package has them."""
    traj = w.batch_rollout(refs, gains, dt=DT, **kwargs)
    metrics = run_metrics(traj, refs, DT)
    final = np.asarray(traj.poses[:, -1])
    return {
        "final_x": final[:, 0],
        "final_y": final[:, 1],
        "final_theta": final[:, 2],
        "arrival_time": metrics["arrival"],
        "path_length": metrics["path"],
        "peak_wheel_speed": np.abs(np.asarray(traj.wheel_speeds)).max(axis=(1, 2)),
        "zigzags": metrics["zigzag"],
    }


def _assert_matches(got, want):
    np.testing.assert_array_equal(got["arrival_time"], want["arrival_time"])
    np.testing.assert_array_equal(got["success"], np.isfinite(want["arrival_time"]))
    np.testing.assert_array_equal(got["zigzags"], want["zigzags"])
    for name in ("final_x", "final_y", "final_theta", "peak_wheel_speed"):
        # Same float64 arithmetic in a different program: a few ulps at most.
        np.testing.assert_allclose(got[name], want[name], rtol=0, atol=1e-10, err_msg=name)
    # A running sum against jnp.sum's pairwise one: rounding differs by ~1e-14.
    np.testing.assert_allclose(got["path_length"], want["path_length"], rtol=1e-12)


def test_streamed_metrics_equal_trajectory_metrics():
    refs = _poses(0, N)
    refs[:3, :2] *= 10.0  # a few too far to reach within the horizon
    gains = w.Gains(kr=60.0)
    got = w.sweep(refs, gains, dt=DT, steps=HORIZON, chunk_size=16)  # 3 chunks, the last padded
    assert set(got) == set(w.studies.SWEEP_FIELDS)
    assert all(v.shape == (N,) for v in got.values())
    want = _expected(refs, gains, steps=HORIZON)
    assert 0 < np.isfinite(want["arrival_time"]).sum() < N  # both outcomes occur
    assert want["zigzags"].max() > 0
    _assert_matches(got, want)


def test_nonideal_loop_and_per_pose_gains():
    refs = _poses(1, N)
    gains = w.Gains(kr=np.linspace(40.0, 100.0, N))
    got = w.sweep(
        refs,
        gains,
        dt=DT,
        steps=HORIZON,
        velocity="nonideal",
        controller="shim-sung",
        chunk_size=16,
    )
    _assert_matches(got, _expected(refs, gains, steps=HORIZON, velocity="nonideal"))


def test_chunking_does_not_change_results():
    refs = _poses(2, 25)
    whole = w.sweep(refs, steps=STEPS, chunk_size=1000)
    # 3 chunks, the last padded; chunks of 10, as the resumed sweeps below compile them.
    part = w.sweep(refs, steps=STEPS, chunk_size=10)
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_allclose(part[name], whole[name], rtol=0, atol=1e-12, err_msg=name)


def _inodes(folder):
    """Chunk file -> inode: a chunk that is computed again is written anew (a new inode)."""
    return {p.name: p.stat().st_ino for p in sorted(folder.glob("chunk_*.npz"))}


def test_resume_after_interruption(tmp_path):
    refs = _poses(3, 50)
    full = w.sweep(refs, steps=STEPS, chunk_size=10)

    class Stop(Exception):
        pass

    def interrupt(done, total):
        if done == 3:
            raise Stop

    (tmp_path / ".chunk_000004.npz.x1y2.tmp").write_bytes(b"left by a killed run")
    with pytest.raises(Stop):
        w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path, on_chunk=interrupt)
    # Chunks finished before the interruption are on disk; nothing half-written.
    first = _inodes(tmp_path)
    assert list(first) == [f"chunk_{i:06d}.npz" for i in range(3)]
    assert not list(tmp_path.glob(".*.tmp"))

    resumed = w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path)
    after = _inodes(tmp_path)
    assert len(after) == 5
    assert all(after[name] == ino for name, ino in first.items())  # reused, not recomputed
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(resumed[name], full[name], err_msg=name)
    with np.load(tmp_path / "results.npz") as saved:
        np.testing.assert_array_equal(saved["arrival_time"], full["arrival_time"])

    # Other poses: only the chunk holding the changed pose is computed again.
    moved = refs.copy()
    moved[12] += 1.0
    w.sweep(moved, steps=STEPS, chunk_size=10, out=tmp_path)
    changed = [name for name, ino in _inodes(tmp_path).items() if after[name] != ino]
    assert changed == ["chunk_000001.npz"]
    # Other settings: none is reused, and the user is told why.
    before = _inodes(tmp_path)
    with pytest.warns(UserWarning, match=r"holds 5 chunk file\(s\) of a sweep with other"):
        w.sweep(refs, steps=STEPS + 1, chunk_size=10, out=tmp_path)
    assert all(before[name] != ino for name, ino in _inodes(tmp_path).items())
    with pytest.warns(UserWarning, match=r"other settings \(chunk 10 -> 20"):
        w.sweep(refs, steps=STEPS + 1, chunk_size=20, out=tmp_path)


def test_damaged_or_altered_chunks_are_recomputed_with_a_warning(tmp_path):
    refs = _poses(3, 50)
    full = w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path)
    damaged = tmp_path / "chunk_000001.npz"
    damaged.write_bytes(damaged.read_bytes()[:-40])  # truncated
    altered = tmp_path / "chunk_000003.npz"
    with np.load(altered) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["arrival_time"] = arrays["arrival_time"] + 1.0  # edited, checksum left as it was
    np.savez(altered, **arrays)
    before = _inodes(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path)
    messages = [str(c.message) for c in caught if "recomputing" in str(c.message)]
    assert len(messages) == 2 and all("\n" not in m for m in messages), messages
    assert "chunk_000001.npz" in messages[0] and "chunk_000003.npz" in messages[1]
    changed = [name for name, ino in _inodes(tmp_path).items() if before[name] != ino]
    assert changed == ["chunk_000001.npz", "chunk_000003.npz"]
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(again[name], full[name], err_msg=name)


def test_bad_inputs_are_named_before_tracing(tmp_path):
    refs = _poses(4, 5)
    # A folder that cannot be written is named before any run, not after the first chunk.
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match=r"out = '.*file.x' is not allowed; '.*file' is a file"):
        w.sweep(refs, out=tmp_path / "file" / "x")
    with pytest.raises(ValueError, match=r"cache = '.*file' is not allowed; allowed: a folder"):
        studies.evaluate_poses(refs, cache=tmp_path / "file")
    with pytest.raises(ValueError, match=r"refs has shape \(5, 2\)"):
        w.sweep(refs[:, :2])
    with pytest.raises(ValueError, match="chunk_size = 0"):
        w.sweep(refs, chunk_size=0)
    with pytest.raises(ValueError, match="tol_theta"):
        w.sweep(refs, tol_theta=math.pi / 2)
    with pytest.raises(ValueError, match="gains.kr"):
        w.sweep(refs, w.Gains(kr=-1.0))
    with pytest.raises(ValueError, match="velocity"):
        w.sweep(refs, velocity="fast")
    bad = refs.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"refs\[3\]"):
        w.sweep(bad, chunk_size=2)
    with pytest.raises(ValueError, match="on_chunk = 5 is not allowed"):
        w.sweep(refs, on_chunk=5)
    with pytest.raises(ValueError, match="allowed: JAX devices"):
        w.sweep(refs, devices=[0])
    # NumPy would read True as 1.0 and fail on ragged rows with a message of its own.
    with pytest.raises(ValueError, match=r"init = \[0.0, 0.0, True\] is not allowed"):
        w.sweep(refs, init=[0.0, 0.0, True])
    with pytest.raises(ValueError, match=r"refs = \[\[1.0, 2.0, 3.0\], \[1.0, 2.0\]\] is not"):
        w.sweep([[1.0, 2.0, 3.0], [1.0, 2.0]])


def test_every_run_is_checked_as_final_poses_checks_it():
    refs = _poses(4, 6)
    # Per-run values beyond the first chunk, named with their rows in the batch.
    kr = np.full(6, 60.0)
    kr[4] = -5.0
    with pytest.raises(ValueError, match=r"gains.kr = .*-5.0.* \(among runs 4 to 5\)"):
        w.sweep(refs, w.Gains(kr=kr), chunk_size=2)
    v_max = np.full(6, 125.0)
    v_max[5] = -1.0
    with pytest.raises(ValueError, match=r"robot.v_max = .*-1.0.*among runs 4 to 5"):
        w.sweep(refs, robot=w.Robot(v_max=v_max), chunk_size=2)
    init = np.zeros((6, 3))
    init[3, 0] = np.nan
    with pytest.raises(ValueError, match=r"init\[3\] = \[nan, 0.0, 0.0\] is not finite"):
        w.sweep(refs, init=init, chunk_size=2)
    far = refs.copy()
    far[5, 2] = 1e13
    with pytest.raises(ValueError, match=r"refs\[5\] = .* has a heading beyond"):
        w.sweep(far, chunk_size=2)
    # A batch axis of size one is shared; another size is named.
    shared = w.sweep(refs, w.Gains(kr=np.array([60.0])), chunk_size=2)
    plain = w.sweep(refs.tolist(), w.Gains(kr=60.0), chunk_size=2)  # a list works as an array
    np.testing.assert_array_equal(shared["final_x"], plain["final_x"])
    with pytest.raises(ValueError, match=r"gains.kr has 2 values; allowed: one, or one per"):
        w.sweep(refs, w.Gains(kr=np.array([60.0, 70.0])))
    # Bools are named as given, not as the one-run sample the other checks look at.
    flags = np.array([True, False] * 3)
    with pytest.raises(ValueError, match=r"gains.kr = array\(\[ True, False, True, False"):
        w.sweep(refs, w.Gains(kr=flags))


def test_a_run_that_leaves_the_range_is_an_error_not_nans():
    # γ dt = 33: the sampled Aicardi law diverges, past float32 within 300 periods
    # (at γ dt = 3.3 it may wander near 1e15 cm instead, as rounding decides).
    with warnings.catch_warnings(), jax.enable_x64(False):
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match=r"1 run\(s\), e.g. run 0, left the range"):
            w.sweep(
                [[30.0, 30.0, 0.0]],
                w.controllers.AicardiGains(gamma=1000.0),
                controller="aicardi",
                steps=300,
            )


@pytest.mark.parametrize("field", ["final_x", "final_y", "final_theta"])
def test_a_computed_run_with_any_coordinate_out_of_range_is_named(monkeypatch, field):
    # Each coordinate of a computed chunk's final poses is checked, and the
    # run is named by its row in the whole batch (row 1 of the second chunk).
    from wmr_jax._src.studies import sweep as sweep_module

    real = sweep_module._launcher

    def launcher(job):
        launch = real(job)

        def spoiled(chunk):
            values = dict(launch(chunk))
            if chunk.i == 1:
                bad = np.array(values[field])
                bad[1] = np.inf
                values[field] = bad
            return values

        return spoiled

    monkeypatch.setattr(sweep_module, "_launcher", launcher)
    with pytest.raises(ValueError, match=r"1 run\(s\), e.g. run 3, left the range"):
        w.sweep(_poses(4, 6), w.Gains(kr=60.0), steps=STEPS, dt=DT, chunk_size=2)


@pytest.mark.parametrize(
    ("field", "value", "why"),
    [
        ("final_x", math.nan, "a final pose that is not finite"),
        (
            "arrival_time",
            -5.0,
            "an arrival time that is no whole number of periods within the horizon",
        ),
        (
            "arrival_time",
            0.05,
            "an arrival time that is no whole number of periods within the horizon",
        ),
        ("success", False, "success flags that disagree with its arrival times"),
        ("path_length", -1.0, "a path_length that is negative or not finite"),
    ],
)
def test_a_chunk_rewritten_with_a_valid_checksum_is_checked_like_a_computed_one(
    tmp_path, field, value, why
):
    # Rewritten through save_arrays (the checksum is valid, the fingerprint
    # kept): the values themselves must still be ones the sweep can produce.
    from wmr_jax._src import io

    refs = _poses(3, 20)
    full = w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path)
    edited = tmp_path / "chunk_000001.npz"
    values, meta = io.load_arrays(edited)
    arrived = int(np.flatnonzero(values["success"])[0])
    values[field] = values[field].copy()
    values[field][arrived] = value
    io.save_arrays(edited, values, meta)
    with pytest.warns(UserWarning, match=f"chunk_000001.npz holds {why}; recomputing it"):
        again = w.sweep(refs, steps=STEPS, chunk_size=10, out=tmp_path)
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(again[name], full[name], err_msg=name)


def test_a_resumed_sweep_sees_a_changed_static_gain_field(tmp_path):
    # backward is a static field: no pytree leaf, yet it decides the run.
    refs = _poses(4, 12)
    refs[:, 0] = -np.abs(refs[:, 0]) - 5.0  # behind the robot: backward driving matters
    gains = w.controllers.AicardiGains(backward=False)
    forward = w.sweep(refs, gains, controller="aicardi", out=tmp_path, steps=STEPS)
    with pytest.warns(UserWarning, match="other settings \\(gains\\)"):
        resumed = w.sweep(refs, w.controllers.AicardiGains(backward=True), controller="aicardi",
                          out=tmp_path, steps=STEPS)  # fmt: skip
    fresh = w.sweep(
        refs, w.controllers.AicardiGains(backward=True), controller="aicardi", steps=STEPS
    )
    for name in w.studies.SWEEP_FIELDS:
        np.testing.assert_array_equal(resumed[name], fresh[name], err_msg=name)
    assert not np.array_equal(resumed["final_x"], forward["final_x"])


def test_the_streamed_arrival_is_the_settled_one_for_runs_that_arrive_leave_and_return():
    # With a 5 cm / 45° tolerance many runs pass through the goal zone before
    # settling in it: the sweep's arrival must be the last entry, as
    # arrival_time has it, never the first.
    tol_r, tol_theta = 5.0, math.radians(45.0)
    refs = _poses(0, 64)
    traj = w.batch_rollout(refs, w.Gains(), steps=100)
    want = np.asarray(w.arrival_time(traj, refs, dt=DT, tol_r=tol_r, tol_theta=tol_theta))
    inside = np.asarray(w.studies.arrived(traj.poses[:, 1:], refs[:, None, :], tol_r=tol_r,
                                  tol_theta=tol_theta))  # fmt: skip
    first = (np.argmax(inside, axis=1) + 1) * DT
    came_back = np.isfinite(want) & (np.abs(first - want) > DT / 2)
    assert came_back.sum() >= 5, came_back.sum()  # the case this test is about
    got = w.sweep(refs, steps=100, tol_r=tol_r, tol_theta=tol_theta)
    np.testing.assert_array_equal(got["arrival_time"], want)


def test_the_timing_script_of_docs_scale_records_what_it_timed(tmp_path):
    # experiments/time_sweep.py gives docs/scale.md its sweep figures.
    import importlib.util
    import json
    import statistics
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "experiments" / "time_sweep.py"
    spec = importlib.util.spec_from_file_location("time_sweep", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "sweep.json"
    argv = ["--poses", "48", "--steps", "5", "--chunk", "16", "--repeats", "2"]
    assert script.main([*argv, "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    assert (record["poses"], record["steps"], record["chunk"]) == (48, 5, 16)
    assert len(record["runs_s"]) == 2 and record["median_s"] == statistics.median(record["runs_s"])
    assert record["robot_steps_per_s"] == pytest.approx(48 * 5 / record["median_s"])
    assert record["backend"] == jax.default_backend() and record["devices"] >= 1
    assert record["jax"] == jax.__version__ and record["peak_rss_mb"] > 0
