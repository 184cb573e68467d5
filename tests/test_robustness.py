"""Robustness Monte Carlo: reproducible draws, and the nominal run when undisturbed."""

import argparse

import jax
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import baselines, metrics, robustness
from wmr_jax.robustness import Disturbance, draw_disturbances, monte_carlo, perturbed_metrics

DT = 0.033
# One batch shape for every run here (and in test_maps): compiled programs are reused.
N, STEPS = 23, 182


def nominal(refs, controller, steps, params=None, velocity="ideal"):
    traj = w.batch_rollout(refs, params, steps=steps, controller=controller, velocity=velocity)
    return traj


def quiet(refs, steps, *, delay=0.0):
    n = len(refs)
    return Disturbance(refs, np.zeros((n, steps, 3)), np.ones((n, 3)), np.float64(delay))


@pytest.mark.parametrize("controller", ["shim-sung", "aicardi", "astolfi-corke"])
def test_zero_disturbance_is_the_nominal_run(controller):
    refs, _, _ = draw_disturbances(jax.random.PRNGKey(3), N, 1)
    m = perturbed_metrics(quiet(refs, STEPS), controller=controller)
    traj = nominal(refs, controller, STEPS)
    # The same closed loop and the same arithmetic on the pose: arrival times
    # and counts agree exactly, the sums to rounding.
    np.testing.assert_array_equal(m.arrival, np.asarray(metrics.arrival_time(traj, refs, dt=DT)))
    np.testing.assert_array_equal(m.zigzag, np.asarray(metrics.zigzag_count(traj)))
    np.testing.assert_allclose(m.path, np.asarray(metrics.path_length(traj)), rtol=1e-12)
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(-1, -2))
    np.testing.assert_allclose(m.peak_wheel, peak, rtol=1e-12)
    ok = np.asarray(metrics.arrived(traj.poses[:, 1:], refs[:, None, :]))
    first = np.where(ok.any(axis=1), (np.argmax(ok, axis=1) + 1) * DT, np.inf)
    np.testing.assert_allclose(m.first_arrival, first, rtol=1e-12)
    assert np.all(m.first_arrival <= m.arrival)


def test_zero_disturbance_is_the_nominal_run_nonideal():
    refs, _, _ = draw_disturbances(jax.random.PRNGKey(4), 6, 1)
    m = perturbed_metrics(quiet(refs, 40), controller="aicardi", velocity="nonideal")
    traj = nominal(refs, "aicardi", 40, velocity="nonideal")
    np.testing.assert_allclose(m.path, np.asarray(metrics.path_length(traj)), rtol=1e-10)
    final = np.asarray(traj.poses[:, -1, :2])
    np.testing.assert_allclose(m.final_distance, np.hypot(*(final - refs[:, :2]).T), atol=1e-9)


def test_equal_wheel_factors_scale_the_gains():
    # Both rims s times as fast as commanded: for v = k_ρ ρ, ω = k_α α + k_β β
    # that is the same law with every gain times s.
    refs, _, _ = draw_disturbances(jax.random.PRNGKey(5), N, 1)
    s = 1.05
    spec = quiet(refs, STEPS)._replace(mismatch=np.tile([s, s, 1.0], (N, 1)))
    m = perturbed_metrics(spec, controller="astolfi-corke")
    gains = baselines.AstolfiGains(k_rho=3.0 * s, k_alpha=8.0 * s, k_beta=-3.0 * s)
    traj = nominal(refs, "astolfi-corke", STEPS, params=gains)
    np.testing.assert_array_equal(m.arrival, np.asarray(metrics.arrival_time(traj, refs, dt=DT)))
    np.testing.assert_allclose(m.path, np.asarray(metrics.path_length(traj)), rtol=1e-9)


def test_latency_changes_the_run():
    refs, _, _ = draw_disturbances(jax.random.PRNGKey(6), N, 1)
    prompt = perturbed_metrics(quiet(refs, STEPS), controller="aicardi")
    late = perturbed_metrics(quiet(refs, STEPS, delay=1.0), controller="aicardi")
    # One period at rest first: the late runs are not the prompt ones.
    assert np.all(late.path != prompt.path)


def test_same_seed_same_numbers():
    kwargs = dict(n_runs=12, noise_xy=(0.0, 1.0), noise_deg=(0.0, 2.0), radius_mismatch=0.03)
    a = monte_carlo(jax.random.PRNGKey(11), controller="aicardi", latency=True, **kwargs)
    b = monte_carlo(jax.random.PRNGKey(11), controller="aicardi", latency=True, **kwargs)
    c = monte_carlo(jax.random.PRNGKey(12), controller="aicardi", latency=True, **kwargs)
    assert a == b
    assert a != c
    assert [r["noise xy cm"] for r in a] == [0.0, 1.0]
    assert all(0.0 <= r["success"] <= 1.0 for r in a)


def test_draws_are_spec_poses_and_bounded_mismatch():
    refs, unit, mismatch = draw_disturbances(
        jax.random.PRNGKey(0), 500, 7, radius_mismatch=0.03, mass_mismatch=0.2
    )
    dist = np.hypot(refs[:, 0], refs[:, 1])
    assert dist.min() >= 5.0 and dist.max() <= 80.0 and unit.shape == (500, 7, 3)
    assert np.abs(mismatch[:, :2] - 1).max() <= 0.03 and np.abs(mismatch[:, 2] - 1).max() <= 0.2
    assert abs(unit.mean()) < 0.05 and abs(unit.std() - 1) < 0.05  # 10500 N(0, 1) draws


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"delay": np.float64(0.5)}, "disturbance.delay"),
        ({"mismatch": np.zeros((4, 3))}, "mismatch > 0"),
        ({"noise": np.zeros((4, 10, 2))}, "disturbance.noise has shape (4, 10, 2)"),
        ({"ref": np.zeros((4, 2))}, "disturbance.ref has shape (4, 2)"),
    ],
)
def test_bad_disturbances_are_rejected(change, message):
    spec = quiet(np.zeros((4, 3)) + [10.0, 0.0, 0.0], 10)._replace(**change)
    with pytest.raises(ValueError) as info:
        perturbed_metrics(spec)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_runs": 0}, "n_runs = 0"),
        ({"noise_xy": (0.0, -1.0), "noise_deg": (0.0, 1.0)}, "noise_xy level -1.0"),
        ({"noise_xy": (0.0,), "noise_deg": (0.0, 1.0)}, "the same number"),
        ({"radius_mismatch": 1.5}, "radius_mismatch = 1.5"),
    ],
)
def test_bad_monte_carlo_options(kwargs, message):
    with pytest.raises(ValueError) as info:
        monte_carlo(jax.random.PRNGKey(0), **kwargs)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--runs", "0"], "--runs = 0"),
        (["--controller", "nope"], "--controller = 'nope'"),
        (["--velocity", "warp"], "--velocity = 'warp'"),
        (["--seed", "-1"], "--seed = -1"),
    ],
)
def test_cli_bad_values(tmp_path, argv, message):
    parser = argparse.ArgumentParser()
    robustness.configure_parser(parser)
    args = parser.parse_args(["--out", str(tmp_path), *argv])
    with pytest.raises(ValueError) as info:
        args.func(args)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_study_writes_figure_and_tables(tmp_path):
    rows = robustness.robustness_study(
        tmp_path, controller_names=["aicardi"], n_runs=8, noise_xy=(0.0, 1.0), noise_deg=(0.0, 2.0)
    )
    assert len(rows) == 3 * 2
    for name in ("robustness.png", "robustness.md", "robustness.json"):
        assert (tmp_path / name).stat().st_size > 100
