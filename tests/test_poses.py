"""Reference poses: the one sampler of the evaluation set, the paper's poses, the horizon."""

import math

import jax
import numpy as np
import pytest

import wmr_jax as w


def test_samples_lie_in_the_evaluation_set():
    poses = np.asarray(w.sample_poses(0, 5000))
    dist = np.hypot(poses[:, 0], poses[:, 1])
    # Drawn in float32, so the bounds hold to float32 rounding.
    assert dist.min() >= 5.0 - 1e-4 and dist.max() <= 80.0 + 1e-4
    assert np.abs(poses[:, 2]).max() <= math.pi + 1e-6
    # Uniform in distance: its mean is (5 + 80) / 2 within a few standard errors.
    assert abs(dist.mean() - 42.5) < 4 * 75 / math.sqrt(12 * 5000)


def test_same_seed_same_poses_in_any_precision():
    a = np.asarray(w.sample_poses(3, 10, dtype=np.float64))
    b = np.asarray(w.sample_poses(jax.random.key(3), 10, dtype=np.float32))
    np.testing.assert_array_equal(a, b.astype(np.float64))
    assert not np.array_equal(a, np.asarray(w.sample_poses(4, 10, dtype=np.float64)))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"key": -1, "n": 3}, "seed = -1"),
        ({"key": 0, "n": 2.5}, "n = 2.5"),
        ({"key": 0, "n": 3, "r_min": -1.0}, "r_min = -1.0"),
        ({"key": 0, "n": 3, "r_min": 10.0, "r_max": 5.0}, "r_max = 5.0"),
    ],
)
def test_bad_arguments_name_themselves(kwargs, message):
    with pytest.raises(ValueError, match=message):
        w.sample_poses(**kwargs)


def test_inside_jit_a_key_draws_and_a_traced_seed_is_refused_in_one_line():
    key = jax.random.key(3)
    np.testing.assert_array_equal(
        jax.jit(lambda k: w.sample_poses(k, 4))(key), w.sample_poses(key, 4)
    )
    raw = jax.random.PRNGKey(3)  # a raw uint32 key works too
    np.testing.assert_array_equal(
        jax.jit(lambda k: w.sample_poses(k, 4))(raw), w.sample_poses(3, 4)
    )
    with pytest.raises(ValueError, match=r"^key = an array of shape \(\) and dtype int"):
        jax.jit(lambda seed: w.sample_poses(seed, 4))(3)


def test_paper_references_and_horizon():
    refs = w.paper_refs()
    assert refs.shape == (7, 3)
    np.testing.assert_allclose(refs[0], [40.0, 0.0, math.radians(-45.0)])
    assert w.studies.horizon_steps(0.033) == 182  # 6 s / 33 ms = 181.8 periods
    assert w.studies.horizon_steps(0.1, 1.0) == 10


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"r_max": 1e39}, r"r_max = 1e\+39 is not allowed; allowed: a distance <= 1e\+18 cm"),
        ({"dtype": "int32"}, "dtype = 'int32' is not allowed; allowed: float32 or float64"),
        ({"dtype": bool}, "allowed: float32 or float64"),
    ],
)
def test_sampler_refuses_what_it_cannot_draw(kwargs, message):
    with pytest.raises(ValueError, match=message):
        w.sample_poses(0, 2, **kwargs)


def test_sampler_refuses_float64_while_jax_computes_in_float32():
    # JAX would cast the float64 result back to float32 without a word.
    with jax.enable_x64(False), pytest.raises(ValueError, match="dtype = float64 is not allowed"):
        w.sample_poses(0, 2, dtype=np.float64)
    with jax.enable_x64(False):
        assert w.sample_poses(0, 2, dtype="float32").dtype == np.float32
