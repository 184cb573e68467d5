"""Chunked sweeps: the streamed metrics equal those of stored trajectories (SPEC §6)."""

import math

import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import metrics, sweep

DT = 0.033


def _expected(refs, gains, **kwargs):
    """The SPEC §6 metrics from whole trajectories, as the rest of the package computes them."""
    traj = w.batch_rollout(refs, gains, dt=DT, **kwargs)
    return {
        "final_x": np.asarray(traj.poses[:, -1, 0]),
        "final_y": np.asarray(traj.poses[:, -1, 1]),
        "final_theta": np.asarray(traj.poses[:, -1, 2]),
        "arrival_time": np.asarray(metrics.arrival_time(traj, refs, dt=DT)),
        "path_length": np.asarray(metrics.path_length(traj)),
        "peak_wheel_speed": np.abs(np.asarray(traj.wheel_speeds)).max(axis=(1, 2)),
        "zigzags": np.asarray(metrics.zigzag_count(traj)),
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


def _refs_with_failures(n, seed):
    """SPEC §6 references, a few too far to reach within the horizon."""
    refs = random_refs(np.random.default_rng(seed), n)
    refs[:3, :2] *= 4.0
    return refs


def test_streamed_metrics_equal_trajectory_metrics():
    refs = _refs_with_failures(40, 0)
    gains = w.Gains(kr=60.0)
    got = sweep.sweep(refs, gains, dt=DT, steps=90, chunk_size=16)  # 3 chunks, the last padded
    assert set(got) == set(sweep.FIELDS)
    assert all(v.shape == (40,) for v in got.values())
    want = _expected(refs, gains, steps=90)
    assert 0 < np.isfinite(want["arrival_time"]).sum() < 40  # both outcomes occur
    assert want["zigzags"].max() > 0
    _assert_matches(got, want)


def test_nonideal_loop_and_per_pose_gains():
    refs = random_refs(np.random.default_rng(1), 6)
    gains = w.Gains(kr=np.linspace(40.0, 100.0, 6))
    got = sweep.sweep(
        refs, gains, dt=DT, steps=40, velocity="nonideal", controller="shim-sung", chunk_size=4
    )
    _assert_matches(got, _expected(refs, gains, steps=40, velocity="nonideal"))


def test_chunking_does_not_change_results():
    refs = random_refs(np.random.default_rng(2), 30)
    whole = sweep.sweep(refs, steps=60, chunk_size=1000)
    for chunk in (1, 7, 16):
        part = sweep.sweep(refs, steps=60, chunk_size=chunk)
        for name in sweep.FIELDS:
            np.testing.assert_allclose(part[name], whole[name], rtol=0, atol=1e-12, err_msg=name)


def test_resume_after_interruption(tmp_path, monkeypatch):
    refs = random_refs(np.random.default_rng(3), 50)
    full = sweep.sweep(refs, steps=40, chunk_size=10)

    class Stop(Exception):
        pass

    def interrupt(done, total):
        if done == 3:
            raise Stop

    with pytest.raises(Stop):
        sweep.sweep(refs, steps=40, chunk_size=10, out=tmp_path, on_chunk=interrupt)
    # Chunks finished before the interruption are on disk; nothing half-written.
    assert sorted(p.name for p in tmp_path.glob("chunk_*.npz")) == [
        f"chunk_{i:06d}.npz" for i in range(3)
    ]
    assert not list(tmp_path.glob(".*.tmp"))

    launched = []
    real = sweep._sweep_jit

    def counting(*args, **kwargs):
        launched.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(sweep, "_sweep_jit", counting)
    resumed = sweep.sweep(refs, steps=40, chunk_size=10, out=tmp_path)
    assert len(launched) == 2  # only the two chunks that had not finished
    for name in sweep.FIELDS:
        np.testing.assert_array_equal(resumed[name], full[name], err_msg=name)
    with np.load(tmp_path / "results.npz") as saved:
        np.testing.assert_array_equal(saved["arrival_time"], full["arrival_time"])

    # Other settings, or other poses: the stored chunks are not reused.
    launched.clear()
    sweep.sweep(refs, steps=41, chunk_size=10, out=tmp_path)
    assert len(launched) == 5
    launched.clear()
    moved = refs.copy()
    moved[12] += 1.0
    sweep.sweep(moved, steps=41, chunk_size=10, out=tmp_path)
    assert len(launched) == 1  # only the chunk holding the changed pose


def test_bad_inputs_are_named_before_tracing():
    refs = random_refs(np.random.default_rng(4), 5)
    with pytest.raises(ValueError, match=r"refs has shape \(5, 2\)"):
        sweep.sweep(refs[:, :2])
    with pytest.raises(ValueError, match="chunk_size = 0"):
        sweep.sweep(refs, chunk_size=0)
    with pytest.raises(ValueError, match="tol_theta"):
        sweep.sweep(refs, tol_theta=math.pi / 2)
    with pytest.raises(ValueError, match="gains.kr"):
        sweep.sweep(refs, w.Gains(kr=-1.0))
    with pytest.raises(ValueError, match="velocity"):
        sweep.sweep(refs, velocity="fast")
    bad = refs.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"refs\[3\]"):
        sweep.sweep(bad, chunk_size=2)
