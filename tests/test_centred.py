"""Robust training centred on an identified robot (tuning/centred.py, docs/model.md §10)."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wmr_jax._src.tuning import centred

# An identified.json's content, written here by hand: the intervals are what the draws must fill.
CONTENT = {
    "wheel_scale": {"left": 1.015, "right": 0.99},
    "latency_samples": 2,
    "noise": {"sigma_xy": 0.3, "sigma_theta": 0.0087},
    "ci95": {
        "wheel_scale_left": [1.013, 1.017],
        "wheel_scale_right": [0.989, 0.991],
        "half_track": [17.9, 18.1],
        "speed_gain": [60.0, 70.0],
        "sigma_xy": [0.29, 0.31],
        "sigma_theta": [0.0084, 0.009],
    },
    # Latency 1 costs within 1 % of 2's: the profile cannot tell them apart; 3 costs far more.
    "latency_profile": [900.0, 100.5, 100.0, 400.0, 800.0],
}


def test_the_ranges_are_the_intervals_and_the_latencies_the_profile_allows():
    r = centred.around(CONTENT)
    assert r.scale_left == (1.013, 1.017) and r.scale_right == (0.989, 0.991)
    assert r.noise_xy == (0.29, 0.31) and r.noise_theta == (0.0084, 0.009)
    assert r.latency == (1, 2)
    sharp = {**CONTENT, "latency_profile": [900.0, 150.0, 100.0, 400.0]}
    assert centred.around(sharp).latency == (2,)
    first = {**sharp, "latency_samples": 0, "latency_profile": [1, 1.001]}
    assert centred.around(first).latency == (0, 1)


def test_bad_content_is_refused_naming_the_field():
    bad = {**CONTENT, "ci95": {**CONTENT["ci95"], "sigma_xy": [0.31, 0.4]}}
    with pytest.raises(ValueError, match="ci95.sigma_xy"):
        centred.around(bad)
    for latency in (1.5, True, -1):  # true would have been one sample
        with pytest.raises(ValueError, match=f"latency_samples = {latency!r} is not allowed"):
            centred.around({**CONTENT, "latency_samples": latency})
    with pytest.raises(ValueError, match="ci95 is missing"):
        centred.around({k: v for k, v in CONTENT.items() if k != "ci95"})


def test_the_draws_are_uniform_over_the_intervals_and_centred_on_them():
    """4,000 runs: every draw inside its interval, the means at the intervals' centres."""
    ranges = centred.around(CONTENT)
    n, steps = 4000, 50
    refs = jnp.zeros((n, 3), jnp.float32)
    spec = centred.draw(jax.random.key(3), refs, steps, ranges)
    mis = np.asarray(spec.mismatch)
    assert mis.shape == (n, 3) and np.all(mis[:, 2] == 1.0)
    for col, (low, high) in ((0, ranges.scale_left), (1, ranges.scale_right)):
        assert low <= mis[:, col].min() and mis[:, col].max() <= high
        # uniform: mean at the centre, standard deviation width / √12 (±4 standard errors)
        width = high - low
        assert abs(mis[:, col].mean() - (low + high) / 2) < 4 * width / math.sqrt(12 * n)
        assert abs(mis[:, col].std() - width / math.sqrt(12)) < 0.05 * width / math.sqrt(12)
    delay = np.asarray(spec.delay)
    assert set(np.unique(delay)) == {1.0, 2.0}
    assert abs(np.mean(delay == 2.0) - 0.5) < 4 * 0.5 / math.sqrt(n)
    # Each run's noise: its own σ, between the interval's ends (measured over its 50 samples).
    noise = np.asarray(spec.noise, np.float64)
    pooled_xy = np.sqrt(np.mean(noise[:, :, :2] ** 2))
    pooled_t = np.sqrt(np.mean(noise[:, :, 2] ** 2))
    # The pooled σ² is the mean of σ² over U(low, high): (low² + low high + high²) / 3.
    for got, (low, high) in ((pooled_xy, ranges.noise_xy), (pooled_t, ranges.noise_theta)):
        expected = math.sqrt((low**2 + low * high + high**2) / 3)
        assert abs(got - expected) < 0.01 * expected


def test_the_robust_loss_draws_the_centred_runs(monkeypatch):
    """``RobustConfig.around`` reaches the loss's batches: latencies and scales of the ranges."""
    from wmr_jax._src.sim.poses import sample_poses
    from wmr_jax._src.tuning import robust

    ranges = centred.around({**CONTENT, "latency_samples": 3, "latency_profile": [9, 9, 9, 1, 9]})
    joint = robust.joint_problem(robust.RobustConfig(law="fixed", estimator=None))
    refs = sample_poses(jax.random.key(0), 64)
    batches = robust.sample_conditions(
        jax.random.key(1), refs, refs[:8], 20, 0.1, joint, False, ranges
    )
    assert [o.velocity for _, o in batches] == ["ideal", "nonideal"]
    assert all(o.max_delay == 3 for _, o in batches)
    ideal, nonideal = batches[0][0], batches[1][0]
    # Each pose once per standard condition, as the standard training runs it.
    assert ideal.ref.shape == (4 * 64, 3) and nonideal.ref.shape == (8, 3)
    assert np.all(np.asarray(ideal.delay) == 3.0)
    mis = np.asarray(ideal.mismatch)
    assert np.all((mis[:, 0] >= 1.013) & (mis[:, 0] <= 1.017) & (mis[:, 2] == 1.0))
    mass = np.asarray(nonideal.mismatch)[:, 2]
    assert np.all(np.abs(mass - 1.0) <= 0.2) and np.any(mass != 1.0)
    # Without it, the standard batch: one-sample latency at most, ±3 % wheels.
    standard = robust.sample_conditions(
        jax.random.key(1), refs, refs[:0], 20, 0.1, joint, False, None
    )
    assert len(standard) == 1 and set(np.unique(np.asarray(standard[0][0].delay))) <= {0.0, 1.0}


def test_tune_robust_with_an_identified_json_sets_the_ranges_and_its_noise(tmp_path, capsys):
    from types import SimpleNamespace

    from wmr_jax._src.cli import tune_robust
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.model.robots import robot_json

    path = tmp_path / "identified.json"
    content = {**CONTENT, "robot": robot_json(Robot()), "base_robot": robot_json(Robot())}
    path.write_text(json.dumps(content))
    args = SimpleNamespace(robot=str(path), fixed=True, iters=3, poses=4)
    config = tune_robust._around_identified(tune_robust.config_from(args), args)
    assert config.around == centred.around(CONTENT)
    assert config.noise_xy == 0.3 and config.noise_theta == pytest.approx(math.degrees(0.0087))
    assert "training centred on the robot identified in" in capsys.readouterr().out
    plain = SimpleNamespace(robot="paper", fixed=True)
    assert tune_robust._around_identified(tune_robust.config_from(plain), plain).around is None
    with pytest.raises(ValueError, match="around = "):
        dataclasses.replace(config, around=(1.0, 1.0)).validate()
    noisy = SimpleNamespace(robot=str(path), fixed=True, noise=0.5)
    with pytest.raises(ValueError, match="--noise is not allowed with --robot"):
        tune_robust._around_identified(tune_robust.config_from(noisy), noisy)


def test_tune_robust_on_an_identified_robot_says_where_to_judge_it_there(
    tmp_path, capsys, monkeypatch
):
    from types import SimpleNamespace

    from wmr_jax._src.cli.main import main
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.tuning import robust, robust_run

    path = tmp_path / "identified.json"
    content = {**CONTENT, "robot": robot_json(Robot()), "base_robot": robot_json(Robot())}
    path.write_text(json.dumps(content))
    # The run itself is the robust tuner's (tested there): here only what the command says.
    seen = []
    result = SimpleNamespace(best_iteration=1, tune_cpu_s=1.0, note=None)
    monkeypatch.setattr(robust, "tune_robust", lambda config, **_: seen.append(config) or result)
    monkeypatch.setattr(robust_run, "write_evaluation", lambda *args: "| table |\n")
    out = tmp_path / "tuned"
    assert main(["tune", "--robust", "--fixed", "--robot", str(path), "--out", str(out)]) == 0
    assert seen[0].around == centred.around(CONTENT)
    printed = capsys.readouterr().out.splitlines()
    assert printed[printed.index("| table |") + 1] == (
        f"(the standard conditions, as for any loop; on the robot identified in {path}: "
        f"wmr-jax robustness --robot {path} --robust-gains {out / 'tuned_gains.json'} --out DIR)"
    )
    # On a robot typed by hand, the standard conditions are the judgement: no such line.
    assert main(["tune", "--robust", "--fixed", "--out", str(out)]) == 0
    assert "identified" not in capsys.readouterr().out
