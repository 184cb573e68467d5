"""The disturbances of docs/model.md §7, each against an independent computation.

Rim speeds, measured poses and residual angles are recomputed with ``math``
and ``cmath`` from the text of §7 (a wheel of radius ``r (1 + δ)`` moves its
rim ``1 + δ`` times as fast; the controller sees ``p_k + n_k``); the draws are
checked by their sample statistics with NumPy.
"""

import cmath
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax._src.sim import motion
from wmr_jax._src.sim.sensing import disturbances as d

ROBOT = w.Robot(half_track=2.5)


def test_the_standard_conditions_are_those_of_the_text():
    assert d.STANDARD_CONDITIONS == (
        ("nominal", 0.0, 0.0, False),
        ("latency", 0.0, 0.0, True),
        ("noise", 0.5, 1.0, False),
        ("both", 0.5, 1.0, True),
    )
    assert d.STANDARD_MISMATCH == 0.03


def test_realised_velocity_is_that_of_the_scaled_rims():
    rng = np.random.default_rng(0)
    for _ in range(5):
        v, omega = rng.normal(0, 30), rng.normal(0, 3)
        f_left, f_right, f_mass = rng.uniform(0.8, 1.2, 3)
        left, right = f_left * (v - 2.5 * omega), f_right * (v + 2.5 * omega)
        got = d.realised(
            jnp.asarray(complex(v, omega)), jnp.asarray([f_left, f_right, f_mass]), ROBOT
        )
        assert float(got[0]) == pytest.approx((left + right) / 2, rel=1e-12)
        assert float(got[1]) == pytest.approx((right - left) / (2 * 2.5), rel=1e-12)


def test_realised_velocity_with_factors_of_one_is_the_command_bit_for_bit():
    v, omega = 0.1 + 0.2, 1 / 3  # numbers a round trip through the rims would round
    got = d.realised(jnp.asarray(complex(v, omega)), jnp.asarray([1.0, 1.0, 1.3]), ROBOT)
    assert float(got[0]) == v and float(got[1]) == omega


def _split(x, y, theta):
    return motion.SplitPose(
        jnp.asarray(complex(x, y)), jnp.asarray(cmath.exp(1j * theta)), jnp.asarray(theta)
    )


def test_the_measured_pose_is_the_pose_plus_noise():
    x, y, theta = 3.0, -4.0, 2.9
    noise = jnp.asarray([0.25, -0.5, 0.4])
    m = d.measurement(_split(x, y, theta), noise).pose()
    assert complex(m.position) == pytest.approx(complex(3.25, -4.5), abs=1e-12)
    assert complex(m.heading) == pytest.approx(cmath.exp(1j * 3.3), abs=1e-12)
    assert float(m.theta) == pytest.approx(3.3, abs=1e-12)
    meas = d.measurement(_split(x, y, theta), noise)
    assert complex(meas.base) == pytest.approx(cmath.exp(1j * 2.9), abs=1e-12)
    assert float(meas.offset) == 0.4
    assert complex(meas.turned(jnp.asarray(-1.0))) == pytest.approx(cmath.exp(2.3j), abs=1e-12)
    assert complex(meas.turned(jnp.asarray(0.0))) == pytest.approx(cmath.exp(3.3j), abs=1e-12)


def test_with_zero_noise_the_measured_pose_is_the_pose_exactly():
    pose = _split(1 / 3, 2 / 7, 0.1 + 0.2)
    m = d.measurement(pose, jnp.zeros(3)).pose()
    assert complex(m.position) == complex(1 / 3, 2 / 7)
    assert complex(m.heading) == complex(pose.heading)
    assert float(m.theta) == 0.1 + 0.2


@pytest.mark.parametrize(
    "measured_theta, estimate_theta",
    [(0.3, 0.1), (3.0, -3.0), (-3.0, 3.0), (0.5 + 2 * math.pi, 0.2), (-1.0, 2.0)],
)
def test_the_residual_is_the_measured_minus_the_estimated_heading_wrapped(
    measured_theta, estimate_theta
):
    noise = 0.25
    meas = d.measurement(_split(0.0, 0.0, measured_theta - noise), jnp.asarray([0.0, 0.0, noise]))
    got = float(meas.residual(_split(1.0, 1.0, estimate_theta)))
    want = (measured_theta - estimate_theta + math.pi) % (2 * math.pi) - math.pi
    assert got == pytest.approx(want, abs=1e-12)
    assert -math.pi <= got < math.pi


def _dist(n=2, steps=3, **fields):
    base = {
        "ref": np.zeros((n, 3)),
        "noise": np.zeros((n, steps, 3)),
        "mismatch": np.ones((n, 3)),
        "delay": np.zeros(n),
    }
    base.update(fields)
    return d.Disturbance(**base)


def test_a_valid_disturbance_is_returned_as_float_arrays():
    out = d.checked_disturbance(_dist(delay=np.array([0.0, 1.0])))
    assert [a.shape for a in out] == [(2, 3), (2, 3, 3), (2, 3), (2,)]
    d.checked_disturbance(_dist(delay=1.0))  # one delay shared by the batch


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"ref": np.zeros(3)}, r"^disturbance\.ref has shape \(3,\); allowed: \(N, 3\)$"),
        ({"ref": np.zeros((2, 2))}, r"^disturbance\.ref has shape \(2, 2\)"),
        (
            {"noise": np.zeros((2, 3))},
            r"^disturbance\.noise has shape \(2, 3\); allowed: \(2, steps, 3\)$",
        ),
        ({"noise": np.zeros((3, 3, 3))}, r"^disturbance\.noise has shape \(3, 3, 3\)"),
        ({"noise": np.zeros((2, 3, 2))}, r"^disturbance\.noise has shape \(2, 3, 2\)"),
        ({"noise": np.zeros((2, 0, 3))}, r"^disturbance\.noise has shape \(2, 0, 3\)"),
        (
            {"mismatch": np.ones((2, 2))},
            r"^disturbance\.mismatch has shape \(2, 2\); allowed: \(2, 3\)$",
        ),
        ({"mismatch": np.ones(3)}, r"^disturbance\.mismatch has shape \(3,\)"),
        (
            {"noise": np.full((2, 3, 3), np.nan)},
            r"^disturbance\.noise = .* is not allowed; allowed: finite numbers$",
        ),
        ({"noise": np.full((2, 3, 3), 2e12)}, r"^disturbance\.noise.*heading noise <= 1e\+12 rad"),
        (
            {"mismatch": np.zeros((2, 3))},
            r"^disturbance\.mismatch = .* is not allowed; allowed: finite, > 0$",
        ),
        (
            {"mismatch": np.full((2, 3), np.inf)},
            r"^disturbance\.mismatch = .* is not allowed; allowed: finite, > 0$",
        ),
        (
            {"delay": 0.5},
            r"^disturbance\.delay = 0\.5 is not allowed; allowed: an integer number "
            r"of samples 0 <= m <= 3 \(the steps\), or \(2,\) of them$",
        ),
        (
            {"delay": np.zeros(3)},
            r"^disturbance\.delay has shape \(3,\); allowed: an integer number of samples",
        ),
        ({"delay": np.array([0.0, 4.0])}, r"^disturbance\.delay = .*allowed: an integer"),
        ({"delay": -1.0}, r"^disturbance\.delay = -1\.0 is not allowed; allowed: an"),
        ({"delay": np.nan}, r"^disturbance\.delay = nan is not allowed; allowed: an"),
        (
            {"delay": True},
            r"^disturbance\.delay = True is not allowed; allowed: an integer number of "
            r"samples m >= 0 \(no bools or strings\)$",
        ),
        (
            {"ref": np.array([["a", "b", "c"]] * 2)},
            r"(?s)^disturbance\.ref = .* is not allowed; allowed: real numbers "
            r"\(no bools or strings\)$",
        ),
    ],
)
def test_a_disturbance_out_of_its_ranges_is_refused_naming_the_field(fields, message):
    with pytest.raises(ValueError, match=message):
        d.checked_disturbance(_dist(**fields))


def test_the_noise_limits_are_per_component():
    limit = 1e153  # checks.position_limit() in float64: 1e153 cm
    d.checked_disturbance(_dist(noise=np.broadcast_to([1e150, -1e150, 1e12], (2, 3, 3))))
    with pytest.raises(ValueError, match=r"\|x\|, \|y\| noise <= 1e\+153 cm"):
        d.checked_disturbance(_dist(noise=np.broadcast_to([0.0, 2 * limit, 0.0], (2, 3, 3))))


def test_one_step_noise_at_its_limits_and_tiny_noise_are_allowed_tiny_factors_not():
    d.checked_disturbance(_dist(steps=1, noise=np.broadcast_to([1e153, -1e153, 1e12], (2, 1, 3))))
    d.checked_disturbance(_dist(noise=np.full((2, 3, 3), 1e-320)))  # data: a tiny noise is 0
    with pytest.raises(ValueError, match=r"^disturbance\.mismatch"):
        d.checked_disturbance(_dist(mismatch=np.full((2, 3), 1e-320)))  # a factor of ~0


def test_a_draw_refuses_no_key_and_no_steps():
    with pytest.raises(ValueError, match=r"^key "):
        d.sample_disturbance(3, np.zeros((2, 3)), 2)
    with pytest.raises(ValueError, match=r"^steps "):
        d.sample_disturbance(jax.random.key(0), np.zeros((2, 3)), 0)
    with pytest.raises(ValueError, match=r"^refs "):
        d.sample_disturbance(jax.random.key(0), np.zeros((2, 2)), 2)


def test_checked_disturbance_refuses_what_is_no_disturbance():
    with pytest.raises(
        ValueError,
        match=r"^disturbance = tuple is not allowed; allowed: a "
        r"Disturbance \(sample_disturbance returns one\)$",
    ):
        d.checked_disturbance(tuple(_dist()))


def test_drawn_noise_is_gaussian_with_the_given_sigmas_per_component():
    refs = jnp.zeros((400, 3))
    dist = d.sample_disturbance(jax.random.key(0), refs, 50, noise_xy=2.0, noise_theta=0.1)
    noise = np.asarray(dist.noise).reshape(-1, 3)
    np.testing.assert_allclose(noise.std(axis=0), [2.0, 2.0, 0.1], rtol=0.02)
    assert (np.abs(noise.mean(axis=0)) < 0.05 * np.array([2.0, 2.0, 0.1])).all()  # ~3.5 σ
    # Independent components and samples: correlations near zero.
    assert abs(np.corrcoef(noise[:, 0], noise[:, 1])[0, 1]) < 0.02
    assert abs(np.corrcoef(noise[:-1, 0], noise[1:, 0])[0, 1]) < 0.02
    np.testing.assert_array_equal(np.asarray(dist.ref), 0.0)
    np.testing.assert_array_equal(np.asarray(dist.mismatch), 1.0)  # no mismatch asked
    np.testing.assert_array_equal(np.asarray(dist.delay), 0.0)


def test_drawn_mismatch_is_uniform_within_its_bounds_per_wheel_and_mass():
    dist = d.sample_disturbance(
        jax.random.key(1), jnp.zeros((20000, 3)), 1, radius_mismatch=0.1, mass_mismatch=0.3
    )
    mis = np.asarray(dist.mismatch)
    for col, m in ((0, 0.1), (1, 0.1), (2, 0.3)):
        assert 1 - m <= mis[:, col].min() < 1 - 0.99 * m
        assert 1 + 0.99 * m < mis[:, col].max() <= 1 + m
        assert mis[:, col].mean() == pytest.approx(1.0, abs=0.01 * m)
        assert mis[:, col].std() == pytest.approx(m / math.sqrt(3), rel=0.02)  # U(−m, m)
    assert abs(np.corrcoef(mis[:, 0], mis[:, 1])[0, 1]) < 0.03  # each wheel its own δ


def test_drawn_latency_is_a_bernoulli_per_run_and_levels_may_be_per_run():
    refs = jnp.zeros((4000, 3))
    delay = np.asarray(d.sample_disturbance(jax.random.key(2), refs, 1, latency=0.25).delay)
    assert set(np.unique(delay)) == {0.0, 1.0}
    assert delay.mean() == pytest.approx(0.25, abs=0.03)
    assert np.asarray(d.sample_disturbance(jax.random.key(2), refs, 1, latency=1.0).delay).all()
    per_run = d.sample_disturbance(
        jax.random.key(3), jnp.zeros((2, 3)), 5, noise_xy=[0.0, 1.0], latency=np.array([1.0, 0.0])
    )
    noise = np.asarray(per_run.noise)
    assert (noise[0, :, :2] == 0).all() and (noise[1, :, :2] != 0).all()
    np.testing.assert_array_equal(np.asarray(per_run.delay), [1.0, 0.0])


def test_draws_follow_the_dtype_of_float_references():
    refs = np.zeros((2, 3), np.float32)
    dist = d.sample_disturbance(jax.random.key(4), refs, 2, noise_xy=1.0)
    assert dist.noise.dtype == jnp.float32 and dist.mismatch.dtype == jnp.float32
    dist = d.sample_disturbance(jax.random.key(4), [[1, 2, 3]], 2)  # ints: the default float
    assert dist.ref.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(dist.ref), [[1.0, 2.0, 3.0]])


@pytest.mark.parametrize(
    "level, value, message",
    [
        ("noise_xy", 1e6 + 1, r"^noise_xy .*a number >= 0 and <= 1e\+06$"),
        ("noise_theta", 6.3, r"^noise_theta .*a number >= 0 and <= 6\.28319$"),
        ("latency", 1.01, r"^latency .*a number >= 0 and <= 1$"),
        ("radius_mismatch", 1.0, r"^radius_mismatch .*a number >= 0 and < 1$"),
        ("mass_mismatch", -0.1, r"^mass_mismatch .*a number >= 0 and < 1$"),
        ("noise_xy", math.nan, r"^noise_xy"),
        (
            "noise_xy",
            [0.1, 0.2],
            r"^noise_xy has shape \(2,\); allowed: a scalar \(or \(1,\)\) "
            r"shared by every run, or \(3,\), one per run$",
        ),
        ("latency", np.zeros((3, 1)), r"^latency has shape \(3, 1\)"),
    ],
)
def test_levels_out_of_range_are_refused(level, value, message):
    with pytest.raises(ValueError, match=message):
        d.sample_disturbance(jax.random.key(0), np.zeros((3, 3)), 2, **{level: value})


def test_levels_at_their_closed_ends_are_allowed():
    d.sample_disturbance(
        jax.random.key(0),
        np.zeros((3, 3)),
        1,
        noise_xy=1e6,
        noise_theta=2 * math.pi,
        latency=np.array([1.0]),
        radius_mismatch=0.0,
        mass_mismatch=np.zeros(3),
    )


def test_draw_disturbances_gives_evaluation_references_unit_noise_and_mismatch():
    refs, noise, mismatch = d.draw_disturbances(jax.random.key(5), 300, 40, radius_mismatch=0.05)
    assert refs.dtype == noise.dtype == mismatch.dtype == np.float64
    assert refs.shape == (300, 3) and noise.shape == (300, 40, 3) and mismatch.shape == (300, 3)
    dist = np.hypot(refs[:, 0], refs[:, 1])
    assert 5.0 <= dist.min() and dist.max() <= 80.0
    np.testing.assert_allclose(noise.reshape(-1, 3).std(axis=0), 1.0, rtol=0.02)
    assert np.abs(mismatch[:, :2] - 1).max() <= 0.05 and np.abs(mismatch[:, :2] - 1).max() > 0.049
    np.testing.assert_array_equal(mismatch[:, 2], 1.0)
    with pytest.raises(ValueError, match=r"^n "):
        d.draw_disturbances(jax.random.key(5), 0, 4)
    with pytest.raises(ValueError, match=r"^steps "):
        d.draw_disturbances(jax.random.key(5), 2, 0)
    with pytest.raises(ValueError, match=r"^mass_mismatch "):
        d.draw_disturbances(jax.random.key(5), 2, 2, mass_mismatch=1.5)
