"""Rollouts: batching, dtypes, recompilation and reaching the goal (docs/model.md §4, §6)."""

import dataclasses
import functools
import logging
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs, run_metrics

import wmr_jax as w
from wmr_jax.controllers import SHIM_SUNG

# One batch size and one horizon wherever a test does not need its own: each
# distinct shape or static option is a compilation, and the tests below share
# the rollout, batch_rollout and final_poses programs of (N, 3) refs over STEPS.
N, STEPS = 16, 60


def test_batch_row_equals_single_rollout():
    refs = random_refs(1, N)
    batch = w.batch_rollout(refs, w.Gains(kr=60.0), steps=STEPS)
    for i in (0, 7, 15):
        single = w.rollout(refs[i], w.Gains(kr=60.0), steps=STEPS)
        for field, a, b in zip(w.Trajectory._fields, batch, single, strict=True):
            # vmap may fuse differently from the unbatched program: a few ulps.
            np.testing.assert_allclose(
                np.asarray(a[i]), np.asarray(b), rtol=0, atol=1e-12, err_msg=field
            )


def test_batch_over_initial_poses_and_gains():
    rng = np.random.default_rng(2)
    ref = np.array([20.0, -10.0, 0.5])
    inits = np.concatenate([rng.uniform(-10, 10, (5, 2)), rng.uniform(-3, 3, (5, 1))], 1)
    kr = np.array([30.0, 60.0, 90.0, 100.0, 120.0])
    gains = w.Gains(kr=kr)
    traj = w.batch_rollout(ref, gains, init=inits, steps=STEPS)
    assert traj.poses.shape == (5, STEPS + 1, 3)
    for i in range(5):
        single = w.rollout(ref, w.Gains(kr=float(kr[i])), init=inits[i], steps=STEPS)
        np.testing.assert_allclose(np.asarray(traj.poses[i]), np.asarray(single.poses), atol=1e-12)
    # Gains batched alone, one shared reference.
    only_gains = w.final_poses(ref, gains, steps=STEPS)
    assert only_gains.shape == (5, 3)


def test_final_poses_equal_last_pose_of_rollout():
    refs = random_refs(3, N)
    traj = w.batch_rollout(refs, steps=STEPS)
    final = w.final_poses(refs, steps=STEPS)
    np.testing.assert_allclose(np.asarray(final), np.asarray(traj.poses[:, -1]), atol=1e-12)


def test_trajectory_shapes_and_initial_pose():
    init = (1.0, 2.0, 0.3)
    traj = w.rollout([30.0, 30.0, 0.0], init=init, steps=STEPS)
    assert traj.poses.shape == (STEPS + 1, 3)
    assert traj.v.shape == traj.omega.shape == traj.region.shape == traj.distance.shape == (STEPS,)
    assert traj.wheel_speeds.shape == (STEPS, 2)
    assert traj.region.dtype == jnp.int32
    np.testing.assert_array_equal(np.asarray(traj.poses[0]), init)
    rims = np.asarray(traj.wheel_speeds)
    half_track = float(w.Robot().half_track)
    np.testing.assert_allclose(rims[:, 0], np.asarray(traj.v - half_track * traj.omega), atol=1e-12)


def test_float32_default_path_stays_close_to_float64(paper_refs):
    with jax.enable_x64(False):
        t32 = w.batch_rollout(paper_refs, w.Gains(kr=60.0))
        assert t32.poses.dtype == jnp.float32
        t32 = np.asarray(t32.poses, dtype=np.float64)
    t64 = np.asarray(w.batch_rollout(paper_refs, w.Gains(kr=60.0)).poses)
    # float32 carries ~1e-7 relative error per step on 40 cm; these paths stay
    # clear of switching surfaces, so the gap stays near 1e-5 cm over 150 steps.
    np.testing.assert_allclose(t32[..., :2], t64[..., :2], atol=1e-4)
    np.testing.assert_allclose(t32[..., 2], t64[..., 2], atol=1e-4)


def _traced(caplog) -> list[str]:
    """The programs ``jax.log_compiles`` saw traced or compiled, persistent cache or not."""
    return [
        r.getMessage()
        for r in caplog.records
        if r.getMessage().startswith(("Finished tracing", "Compiling"))
    ]


def test_repeated_calls_do_not_retrace(caplog):
    """New values of every traced input reuse the compiled program (JAX logs each trace)."""
    refs = random_refs(4, N)
    for public, arg in ((w.rollout, refs[0]), (w.batch_rollout, refs), (w.final_poses, refs)):
        public(arg, w.Gains(kr=50.0), steps=STEPS)
        caplog.clear()
        with jax.log_compiles(), caplog.at_level(logging.WARNING):
            public(arg + 1.0, w.Gains(kr=70.0, alpha=0.3), steps=STEPS, dt=0.02, init=(1.0, 0, 0))
            public(arg - 1.0, w.Gains(kr=np.float64(40.0)), steps=STEPS)
        assert _traced(caplog) == [], public.__name__
        # The check can fail: a new static option is traced. A controller
        # equal to the default but for a new command object is new to this
        # process whatever ran before (a new step count may have been seen).
        fresh = dataclasses.replace(SHIM_SUNG, command=functools.partial(SHIM_SUNG.command))
        with jax.log_compiles(), caplog.at_level(logging.WARNING):
            public(arg, w.Gains(kr=50.0), steps=STEPS, controller=fresh)
        assert any(m.startswith("Finished tracing") for m in _traced(caplog)), public.__name__


def test_a_call_with_values_traces_without_remat_and_a_differentiated_one_with_it(monkeypatch):
    """remat only changes what a reverse pass stores: a top-level call, which
    nothing can differentiate, skips it; a call under ``grad`` keeps it."""
    from wmr_jax._src.sim import loops

    checkpointed = []

    def remat(body):
        checkpointed.append(body)
        return jax.checkpoint(body, prevent_cse=False)

    monkeypatch.setattr(loops, "remat", remat)
    refs = random_refs(4, 3)
    steps = STEPS + 3  # a program no other test compiled
    poses = w.batch_rollout(refs, w.Gains(kr=50.0), steps=steps).poses
    assert checkpointed == []

    def last_x(kr):
        return w.batch_rollout(refs, w.Gains(kr=kr), steps=steps).poses[:, -1, 0].sum()

    value, grad = jax.value_and_grad(last_x)(50.0)
    assert len(checkpointed) == 1 and np.isfinite(grad)
    # The same runs either way.
    assert float(value) == pytest.approx(float(np.sum(poses[:, -1, 0])), rel=1e-12)


@pytest.fixture(scope="module")
def grid_arrivals():
    """From (0, 0, 0), k_r = 60: the 7 paper poses, an 8×8×8 grid and one pose out of reach.

    One batch over the docs/model.md §6 horizon (6 s); the last reference is
    1000 cm away, beyond the 750 cm a robot at v_max = 125 cm/s covers in 6 s.
    """
    dist = np.linspace(5.0, 60.0, 8)
    bearing = np.arange(8) * 2 * math.pi / 8
    heading = np.arange(8) * 2 * math.pi / 8 - math.pi
    d, b, h = np.meshgrid(dist, bearing, heading, indexing="ij")
    grid = np.stack([d * np.cos(b), d * np.sin(b), h], axis=-1).reshape(-1, 3)
    refs = np.concatenate([w.paper_refs(), grid, [[1000.0, 0.0, 0.0]]])
    dt = 0.033
    steps = math.ceil(6.0 / dt)  # the docs/model.md §6 horizon; arrival is checked to stay
    traj = w.batch_rollout(refs, w.Gains(kr=60.0), steps=steps, dt=dt)
    return refs, run_metrics(traj, refs, dt)["arrival"]


def test_paper_references_and_grid_arrive_within_5s(grid_arrivals):
    """The 7 paper poses and the 8×8×8 grid arrive (docs/model.md §6)."""
    refs, times = grid_arrivals
    assert times.shape == (len(refs),)
    refs, times = refs[:-1], times[:-1]  # the last one is out of reach
    assert np.all(times <= 5.0), refs[times > 5.0]
    assert w.success_rate(times) == 1.0


def test_arrival_is_reported_infinite_when_horizon_too_short(grid_arrivals):
    refs, times = grid_arrivals
    assert np.isinf(times[-1]) and refs[-1, 0] == 1000.0
    assert w.success_rate(times) == pytest.approx(1 - 1 / len(times))
