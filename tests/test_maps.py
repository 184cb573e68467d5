"""Pose-space maps: streamed metrics equal those of recorded rollouts (docs/model.md §6).

Every simulated run here uses the same 40 poses, chunks of 16 and the 6 s
horizon, so the compiled programs are shared between tests (and with test_sweep.py).
"""

import json
import math

import jax
import numpy as np
import pytest
from conftest import assert_metrics_of_runs, random_refs

import wmr_jax as w
from wmr_jax.cli import main
from wmr_jax.controllers import AicardiGains
from wmr_jax.studies import PoseMetrics, evaluate_poses, map_study, pose_grid, summarize

DT = 0.033


@pytest.fixture(scope="module")
def refs():
    """The 40 poses of every run here (drawn when first needed, not at collection)."""
    return random_refs(1, 40)


@pytest.mark.parametrize(
    ("controller", "params"), [("aicardi", AicardiGains(backward=True)), ("astolfi-corke", None)]
)
def test_streamed_metrics_equal_rollouts_and_metrics(refs, controller, params):
    """Shim–Sung's streamed metrics are checked against rollouts in test_sweep.py."""
    m = evaluate_poses(refs, params, controller=controller, chunk=16)  # 3 calls, the last padded
    traj = w.batch_rollout(refs, params, steps=w.studies.horizon_steps(DT), controller=controller)
    assert_metrics_of_runs(m, traj, refs, DT)
    final = np.asarray(traj.poses[:, -1, :2])
    np.testing.assert_allclose(m.final_distance, np.hypot(*(final - refs[:, :2]).T), atol=1e-12)
    assert m.success.mean() == 1.0


def test_baselines_hold_their_goal_in_float32_too(refs):
    # Once ρ is down to the rounding of the positions the polar laws' bearing
    # is noise; holding the goal within 1e-3 cm (docs/model.md §3) keeps them
    # arrived in float32 as in float64, with the same arrival times.
    params = AicardiGains(backward=True)
    m64 = evaluate_poses(refs, params, controller="aicardi", chunk=16)
    m32 = evaluate_poses(refs, params, controller="aicardi", chunk=16, x64=False)
    assert m64.success.all() and m32.success.all()
    np.testing.assert_allclose(m32.arrival, m64.arrival, atol=0.034)  # a sample at most


def test_float64_runs_check_their_poses_in_float64_in_a_float32_session():
    # 1e20 cm is beyond float32's position limit (1e18) but well within float64's.
    refs = np.array([[1e20, 0.0, 0.0], [40.1, 0.0, 0.0]])
    with jax.enable_x64(False):
        m = evaluate_poses(refs, w.Gains(kr=60.0), steps=1)
        with pytest.raises(ValueError, match=r"refs\[0\] = \[1e\+20, 0.0, 0.0\]"):
            evaluate_poses(refs, w.Gains(kr=60.0), steps=1, x64=False)
    # One period of a straight drive at k_r = 60 cm/s: exact in float64.
    assert m.final_distance[1] == pytest.approx(40.1 - 60.0 * w.DEFAULT_DT, abs=1e-12)


@pytest.mark.parametrize(
    ("n", "r_min", "r_max"), [(1, 5.0, 80.0), (19, 5.0, 80.0), (100, 50.0, 50.000001)]
)
def test_a_small_pose_grid_or_a_thin_annulus_still_has_poses(n, r_min, r_max):
    # Two points a side would be the corners, all outside the annulus; a thin
    # annulus asks for a grid finer than memory holds, and is capped.
    grid = pose_grid(n, r_min=r_min, r_max=r_max)
    dist = np.hypot(grid.refs[:, 0], grid.refs[:, 1])
    assert len(grid.refs) >= 1 and np.all((dist >= r_min) & (dist <= r_max))
    assert len(grid.xs) <= 4098


def test_pose_grid_covers_the_evaluation_annulus():
    grid = pose_grid(4000, (0.0, 90.0))
    dist = np.hypot(grid.refs[:, 0], grid.refs[:, 1])
    assert dist.min() >= w.studies.EVAL_R_MIN and dist.max() <= w.studies.EVAL_R_MAX
    assert abs(len(grid.refs) - 4000) < 0.1 * 4000
    assert len(grid.refs) == 2 * grid.inside.sum()
    np.testing.assert_allclose(np.unique(grid.refs[:, 2]), [0.0, math.pi / 2])


def _metrics(arrival, peak_wheel, zigzag):
    arrival = np.asarray(arrival, dtype=float)
    n = len(arrival)
    path = np.arange(n, dtype=float)
    return PoseMetrics(
        arrival, path, np.asarray(peak_wheel, float), np.asarray(zigzag), np.zeros(n)
    )


def test_summary_rows():
    inf = math.inf
    results = {
        "aicardi": _metrics([1.0, 3.0, inf, 2.0], [100.0, 130.0, 90.0, 125.0], [0, 2, 0, 1]),
        "shim-sung": _metrics([2.0, 1.0, 1.0, 3.0], [120.0, 120.0, 120.0, 120.0], [3, 3, 0, 0]),
    }
    rows = summarize(results)
    assert [r["controller"] for r in rows] == ["aicardi", "shim-sung"]
    a, s = rows
    assert a["poses"] == 4 and a["success"] == 0.75 and s["success"] == 1.0
    assert a["mean arrival s"] == 2.0 and a["median arrival s"] == 2.0  # over the 3 successes
    assert a["p90 arrival s"] == pytest.approx(2.8)
    assert a["mean path cm"] == 1.5 and a["max peak wheel cm/s"] == 130.0
    assert a["over V_max"] == 0.25  # 130 > 125; 125 itself is not over
    assert a["mean zigzag"] == 0.75 and a["any zigzag"] == 0.5
    assert a["faster than shim-sung"] == 0.5 and s["faster than shim-sung"] == 0.0
    none = summarize({"x": _metrics([inf], [1.0], [0])})[0]
    assert none["success"] == 0.0 and none["mean arrival s"] == inf
    assert "faster than shim-sung" not in none
    with pytest.raises(ValueError, match="results is a list; allowed: a dict of controller name"):
        summarize([results["aicardi"]])


def test_sweep_command_writes_what_the_study_returns(tmp_path, capsys):
    argv = ["sweep", "--out", str(tmp_path), "--poses", "120", "--controller", "shim-sung"]
    argv += ["--controller", "astolfi-corke", "--headings", "0", "180", "--chunk", "16"]
    assert main([*argv, "--no-progress", "--resume"]) == 0
    for name in ("maps_shim-sung.png", "maps_astolfi-corke.png", "winner.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "| astolfi-corke |" in (tmp_path / "summary.md").read_text()
    assert "| astolfi-corke |" in capsys.readouterr().out
    assert (tmp_path / "chunks" / "astolfi-corke" / "chunk_000000.npz").is_file()  # --resume
    assert not list(tmp_path.glob(".*tmp"))

    # The engine returns the same numbers and writes nothing.
    before = sorted(tmp_path.rglob("*"))
    study = map_study(
        120, controller_names=["shim-sung", "astolfi-corke"], headings_deg=(0.0, 180.0), chunk=16
    )
    assert sorted(tmp_path.rglob("*")) == before
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved == json.loads(json.dumps(study.summary))
    assert saved["poses"] == len(study.grid.refs) > 0
    np.testing.assert_array_equal(study.results["shim-sung"].path.shape, (saved["poses"],))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--poses", "0"], "--poses '0'"),
        (["--controller", "aicardi", "--controller", "nope"], "--controller 'nope'"),
        (["--velocity", "warp"], "--velocity 'warp'"),
        (["--chunk", "0"], "--chunk '0'"),
        (["--headings", "nan"], "--headings 'nan'"),
    ],
)
def test_sweep_command_bad_values(tmp_path, capsys, argv, message):
    assert main(["sweep", "--out", str(tmp_path / "out"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "allowed" in err[0], err
    assert not (tmp_path / "out").exists()


def test_bad_inputs():
    with pytest.raises(ValueError, match="refs has shape"):
        evaluate_poses(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="chunk = 0"):
        evaluate_poses(np.zeros((4, 3)) + 10, chunk=0)
    with pytest.raises(ValueError, match="init has shape"):
        evaluate_poses(np.zeros((4, 3)) + 10, init=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="n_poses = 0"):
        map_study(0)
    with pytest.raises(ValueError, match=r"headings_deg = .*nan.*allowed: finite degrees"):
        pose_grid(100, (0.0, math.nan))
    # One heading twice (here 0° and 360°) would map the same runs as two columns.
    with pytest.raises(ValueError, match=r"360 repeats a heading \(modulo 360\); allowed: dis"):
        pose_grid(100, (0.0, 90.0, 360.0))
    assert len(np.unique(pose_grid(100, (0.0, 90.0, 270.0, -45.0)).refs[:, 2])) == 4
    with pytest.raises(ValueError, match=r"n_poses = 100000000000000 is not allowed"):
        pose_grid(10**14)
    with pytest.raises(ValueError, match="not known|allowed"):
        map_study(10, controller_names=["nope"])
    # Every name is known before the first controller runs.
    with pytest.raises(ValueError, match="controller = 'typo' is not known"):
        map_study(10, controller_names=["shim-sung", "typo"])
    with pytest.raises(ValueError, match=r"controller_names = \[\] is not allowed"):
        map_study(10, controller_names=[])


def test_a_map_of_gains_of_ones_own_runs_them_and_says_so(tmp_path, monkeypatch):
    """A researcher maps tuned gains, not only each controller's defaults."""
    from wmr_jax import report
    from wmr_jax._src.report import maps as report_maps

    slow = w.Gains(kr=20.0, k_theta=3.0)
    kw = {"headings_deg": (0.0,), "chunk": 16}
    mine = map_study(
        40, controller_names=["shim-sung", "aicardi"], params={"shim-sung": slow}, **kw
    )
    grid = mine.grid.refs
    want = evaluate_poses(grid, slow, chunk=16)  # over the same horizon, the robot's
    np.testing.assert_array_equal(mine.results["shim-sung"].arrival, want.arrival)
    default = map_study(40, controller_names=["aicardi"], **kw)
    np.testing.assert_array_equal(
        mine.results["aicardi"].arrival, default.results["aicardi"].arrival
    )
    assert mine.summary["params_given"] == ["shim-sung"] and "params_given" not in default.summary
    # The figures' titles and summary.md say whose parameters were given.
    titles = []
    monkeypatch.setattr(
        report_maps, "map_figure", lambda path, *a, title, **k: titles.append(title)
    )
    monkeypatch.setattr(report_maps, "winner_figure", lambda path, *a, **k: path)
    report.save_map_study(tmp_path, mine)
    assert [t.split(":")[0] for t in titles] == ["shim-sung (parameters given)", "aicardi"]
    summary = (tmp_path / "summary.md").read_text()
    assert summary.endswith("Parameters given for shim-sung; the others ran their defaults.\n")
    with pytest.raises(
        ValueError, match=r"params = \['astolfi-corke'\] is not allowed; allowed: a"
    ):
        map_study(40, controller_names=["shim-sung"], params={"astolfi-corke": slow}, **kw)
    with pytest.raises(ValueError, match=r"params = .* is not allowed; allowed: a dict of"):
        map_study(40, controller_names=["shim-sung"], params=[slow], **kw)


def test_a_single_heading_may_be_a_number():
    # pose_grid takes 90.0 as (90.0,); the study's summary has to as well.
    study = map_study(10, controller_names=["shim-sung"], headings_deg=90.0, chunk=16)
    assert study.summary["headings_deg"] == [90.0]
    np.testing.assert_array_equal(study.grid.refs[:, 2], math.pi / 2)


def test_the_maps_draw_the_wheel_limit_of_the_robot_the_study_ran(tmp_path, monkeypatch):
    from wmr_jax import report
    from wmr_jax._src.report import maps as report_maps

    drawn = []
    monkeypatch.setattr(report_maps, "map_figure", lambda path, *a, v_max, **k: drawn.append(v_max))
    study = map_study(40, controller_names=["shim-sung"], headings_deg=(0.0,), chunk=16)
    study.summary["robot"]["v_max"] = 22.0  # as a study of a slow robot records it
    # The figures of an earlier study of other controllers do not stay beside this one's.
    for stale in ("maps_aicardi.png", "winner.png", "maps_shim-sung.png"):
        (tmp_path / stale).write_text("an earlier study")
    for own in ("notes.png", "maps_of_my_notes.png"):  # not a controller's map
        (tmp_path / own).write_text("the user's")
    report.save_map_study(tmp_path, study)
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [
        "maps_of_my_notes.png",
        "maps_shim-sung.png",
        "notes.png",
    ]
    del study.summary["robot"]  # a summary from before robots were recorded: the paper robot
    report.save_map_study(tmp_path, study)
    assert drawn == [22.0, 125.0]


def test_compare_runs_a_registered_law_beside_the_baselines(tmp_path, monkeypatch, capsys):
    """The paper's law registered again under another name: its row is shim-sung's."""
    from wmr_jax._src.model.controllers import base

    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))
    sung = w.controllers.SHIM_SUNG
    copy = w.Controller(
        name="shim-copy", command=sung.command, params_type=w.Gains, validate=sung.validate
    )
    w.register_controller(copy)
    argv = ["compare", "--out", str(tmp_path), "--poses", "40", "--horizon", "2", "--no-progress"]
    assert main([*argv, "--controller", "shim-copy"]) == 0
    rows = {
        r["controller"]: r for r in json.loads((tmp_path / "comparison.json").read_text())["rows"]
    }
    assert list(rows)[-1] == "shim-copy" and len(rows) == 6
    assert {**rows["shim-copy"], "controller": "shim-sung"} == rows["shim-sung"]
    assert "shim-copy" in capsys.readouterr().out
    for name, said in (
        ("aicardi", "--controller: also = 'aicardi' is not allowed: it is compared already"),
        ("nope", "--controller 'nope' is not known"),
    ):
        assert main([*argv, "--controller", name]) == 2
        assert said in capsys.readouterr().err
