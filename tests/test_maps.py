"""Pose-space maps: streamed metrics equal those of recorded rollouts (SPEC §6)."""

import argparse
import json
import math

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import maps, metrics
from wmr_jax.baselines import AicardiGains

DT = 0.033


@pytest.mark.parametrize(
    ("controller", "params"),
    [("shim-sung", None), ("aicardi", AicardiGains(backward=True)), ("astolfi-corke", None)],
)
def test_streamed_metrics_equal_rollouts_and_metrics(controller, params):
    refs = maps.spec_poses(1, 23)
    # A chunk of 10: three calls, the last one padded.
    m = maps.evaluate_poses(refs, params, controller=controller, chunk=10)
    traj = w.batch_rollout(refs, params, steps=maps.horizon_steps(DT), controller=controller)
    # Arrival times and counts are decided by the same comparisons on the same
    # poses: exact. Sums and maxima agree to rounding.
    np.testing.assert_array_equal(m.arrival, np.asarray(metrics.arrival_time(traj, refs, dt=DT)))
    np.testing.assert_array_equal(m.zigzag, np.asarray(metrics.zigzag_count(traj)))
    np.testing.assert_allclose(m.path, np.asarray(metrics.path_length(traj)), rtol=1e-12)
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(-1, -2))
    np.testing.assert_allclose(m.peak_wheel, peak, rtol=1e-12)
    final = np.asarray(traj.poses[:, -1, :2])
    np.testing.assert_allclose(m.final_distance, np.hypot(*(final - refs[:, :2]).T), atol=1e-12)
    assert m.success.mean() == 1.0


def test_pose_grid_covers_the_spec_annulus():
    grid = maps.pose_grid(4000, (0.0, 90.0))
    dist = np.hypot(grid.refs[:, 0], grid.refs[:, 1])
    assert dist.min() >= 5.0 and dist.max() <= 80.0
    assert abs(len(grid.refs) - 4000) < 0.1 * 4000
    assert len(grid.refs) == 2 * grid.inside.sum()
    np.testing.assert_allclose(np.unique(grid.refs[:, 2]), [0.0, math.pi / 2])


def test_summary_rows():
    refs = maps.spec_poses(3, 23)
    results = {
        "shim-sung": maps.evaluate_poses(refs, chunk=10),
        "aicardi": maps.evaluate_poses(
            refs, AicardiGains(backward=True), controller="aicardi", chunk=10
        ),
    }
    rows = maps.summarize(results)
    assert [r["controller"] for r in rows] == ["shim-sung", "aicardi"]
    assert rows[0]["faster than shim-sung"] == 0.0
    faster = float(np.mean(results["aicardi"].arrival < results["shim-sung"].arrival))
    assert rows[1]["faster than shim-sung"] == faster
    ok = results["aicardi"].success
    assert rows[1]["median arrival s"] == float(np.median(results["aicardi"].arrival[ok]))


def test_sweep_writes_maps_and_tables(tmp_path):
    summary = maps.sweep(
        tmp_path,
        n_poses=120,
        controller_names=["shim-sung", "astolfi-corke"],
        headings_deg=(0.0, 180.0),
        chunk=64,
        progress=False,
    )
    for name in ("maps_shim-sung.png", "maps_astolfi-corke.png", "winner.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "| astolfi-corke |" in (tmp_path / "summary.md").read_text()
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(summary["rows"]))
    assert saved["poses"] == summary["poses"] > 0
    assert not list(tmp_path.glob(".*tmp"))


def test_float32_shows_the_baselines_singular_goal():
    # In float32 the polar laws lose their heading once ρ reaches the rounding
    # of the positions: the reason the maps compute in float64.
    refs = maps.spec_poses(0, 8)
    m64 = maps.evaluate_poses(refs, controller="aicardi")
    m32 = maps.evaluate_poses(refs, controller="aicardi", x64=False)
    assert m64.success.all()
    assert m32.success.mean() < 1.0


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--poses", "0"], "--poses = 0"),
        (["--controller", "nope"], "--controller = 'nope'"),
        (["--controller", "aicardi", "--controller", "nope"], "--controller = 'nope'"),
        (["--velocity", "warp"], "--velocity = 'warp'"),
        (["--chunk", "0"], "--chunk = 0"),
        (["--headings", "nan"], "--headings = nan"),
    ],
)
def test_cli_bad_values(tmp_path, argv, message):
    parser = argparse.ArgumentParser()
    maps.configure_parser(parser)
    args = parser.parse_args(["--out", str(tmp_path), *argv])
    with pytest.raises(ValueError) as info:
        args.func(args)
    assert message in str(info.value) and "allowed" in str(info.value)
    assert "\n" not in str(info.value)


def test_cli_runs(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    maps.configure_parser(parser)
    args = parser.parse_args(
        ["--out", str(tmp_path), "--poses", "60", "--controller", "aicardi", "--no-progress"]
    )
    assert args.func(args) == 0
    assert "| aicardi |" in capsys.readouterr().out
    assert (tmp_path / "maps_aicardi.png").exists()


def test_bad_inputs():
    with pytest.raises(ValueError, match="refs has shape"):
        maps.evaluate_poses(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="chunk = 0"):
        maps.evaluate_poses(np.zeros((4, 3)) + 10, chunk=0)
    with pytest.raises(ValueError, match="init has shape"):
        maps.evaluate_poses(np.zeros((4, 3)) + 10, init=np.zeros((4, 3)))
