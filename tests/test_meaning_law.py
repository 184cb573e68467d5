"""What the law's numbers mean (docs/model.md §2–3, §3.7), each against an independent computation.

Small and fast on purpose: mutation testing (``mutmut``, docs/testing.md)
runs these for every mutant of ``controllers/shim_sung.py``. The hard law,
its regions and its diagnostics are held against the plain-float NumPy
reference (``wmr_jax.studies.reference_diagnostics``) on poses that put every region
and switch to work, ties included; the relaxed law against the formulas of
docs/model.md §3.7, written out here in plain ``math``. Nothing here runs
JAX at import.
"""

import functools
import math
import types
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import controllers as law

# Gains away from the defaults, so that each one matters.
GAINS = w.Gains(kr=48.0, k_theta=3.5, phi_m=math.radians(55.0), alpha=0.3, r_e=0.8, r_a=6.0)
GAINS = GAINS.replace(r_m=9.0)
PHI_M = math.radians(55.0)


def _poses() -> tuple[np.ndarray, np.ndarray]:
    """Robots at the origin facing +x, and references that cover every region and switch."""
    rng = np.random.default_rng(3)
    n = 300
    r = np.concatenate([rng.uniform(0, 1.2, 60), rng.uniform(1, 8, 120), rng.uniform(8, 40, 120)])
    phi = rng.uniform(-math.pi, math.pi, n)
    theta = rng.uniform(-math.pi, math.pi, n)
    # On the switches themselves: |φ_e| = Φ_m and π − Φ_m, r_e = R_e, R_a, R_m,
    # φ_e and θ_e at 0, ±π/2 and π, the goal itself.
    ties = [
        (5.0, PHI_M, 0.4),
        (5.0, -PHI_M, -0.4),
        (5.0, math.pi - PHI_M, 0.2),
        (5.0, -math.pi + PHI_M, 0.2),
        (0.8, 0.3, 1.0),
        (6.0, 0.3, 1.0),
        (9.0, 0.3, 1.0),
        (3.0, math.pi / 2, 0.0),
        (3.0, -math.pi / 2, math.pi / 2),
        (3.0, 0.0, math.pi),
        (3.0, math.pi, -math.pi / 2),
        (0.0, 0.0, 0.7),
        (0.0, 0.0, -2.0),
    ]
    r = np.concatenate([r, [t[0] for t in ties]])
    phi = np.concatenate([phi, [t[1] for t in ties]])
    theta = np.concatenate([theta, [t[2] for t in ties]])
    refs = np.stack([r * np.cos(phi), r * np.sin(phi), theta], axis=-1)
    # The robot somewhere else, turned: the same errors, another frame.
    pose = np.array([7.0, -4.0, 2.2])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    world = np.stack(
        [pose[0] + c * refs[:, 0] - s * refs[:, 1], pose[1] + s * refs[:, 0] + c * refs[:, 1]],
        axis=-1,
    )
    refs = np.column_stack([world, refs[:, 2] + pose[2]])
    return np.broadcast_to(pose, refs.shape).copy(), refs


POSES, REFS = _poses()


def _reference() -> dict[str, np.ndarray]:
    rows = [w.studies.reference_diagnostics(p, q, GAINS) for p, q in zip(POSES, REFS, strict=True)]
    return {k: np.array([row[k] for row in rows]) for k in rows[0]}


WANT = _reference()


def test_the_poses_put_every_region_and_direction_to_work():
    assert set(WANT["region"]) == {0, 1, 2, 3}
    assert set(WANT["d"]) == {-1.0, 0.0, 1.0}
    # Region 1 blends both ways: ε = 0.5 ± α.
    assert {0.5 - 0.3, 0.5 + 0.3} <= set(np.round(WANT["eps"], 12))


def test_the_hard_law_is_the_reference():
    v, omega = w.control(POSES, REFS, GAINS)
    np.testing.assert_allclose(v, WANT["v"], rtol=0, atol=1e-11)
    np.testing.assert_allclose(omega, WANT["omega"], rtol=0, atol=1e-11)


def test_the_diagnostics_are_the_reference():
    got = w.controllers.control_diagnostics(POSES, REFS, GAINS)
    np.testing.assert_array_equal(got.region, WANT["region"])
    assert got.region.dtype == np.int32
    for field in ("v", "omega", "d", "eps", "lyapunov", "r_e"):
        np.testing.assert_allclose(getattr(got, field), WANT[field], rtol=0, atol=1e-11)
    # Angles: the same up to the 2π of a wrap (±π is one angle).
    for field in ("phi_e", "theta_e"):
        gap = np.angle(np.exp(1j * (np.asarray(getattr(got, field)) - WANT[field])))
        np.testing.assert_allclose(gap, 0.0, atol=1e-11)
    # θ_e in [−π, π), φ_e in (−π, π] (docs/model.md §2).
    assert np.all((got.theta_e >= -math.pi) & (got.theta_e < math.pi))
    assert np.all((got.phi_e > -math.pi) & (got.phi_e <= math.pi))


def test_the_diagnostics_inside_a_transformation_are_the_reference():
    # Traced (as inside a user's jit or vmap): the same values, unchecked.
    got = jax.vmap(lambda p, q: law.control_diagnostics(p, q, GAINS))(POSES, REFS)
    np.testing.assert_array_equal(got.region, WANT["region"])
    for field in ("v", "omega", "eps"):
        np.testing.assert_allclose(getattr(got, field), WANT[field], rtol=0, atol=1e-11)


def test_the_regions_of_the_rollouts_are_the_reference():
    # The controller's region function (what the rollouts record) with the
    # pose given as its frame (x, y, cos θ, sin θ), as the loops carry it.
    # The pose itself is not read then (polar_error): None stands for it.
    frame = (POSES[:, 0], POSES[:, 1], np.cos(POSES[:, 2]), np.sin(POSES[:, 2]))
    got = law.SHIM_SUNG.region_of(None, REFS, GAINS, frame=frame)
    np.testing.assert_array_equal(got, WANT["region"])
    v, omega = law.SHIM_SUNG.command(None, REFS, GAINS, frame=frame)
    np.testing.assert_allclose(v, WANT["v"], rtol=0, atol=1e-11)
    np.testing.assert_allclose(omega, WANT["omega"], rtol=0, atol=1e-11)


# ---------------------------------------------------------------- the relaxed law (§3.7)


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))


def _softplus(x: float) -> float:
    return max(x, 0.0) + math.log1p(math.exp(-abs(x)))


def relaxed_command(pose, ref, gains, t: float) -> tuple[float, float]:
    """docs/model.md §3.7 written out in plain floats, from the polar errors."""
    x, y, th = pose
    dx, dy = ref[0] - x, ref[1] - y
    e_x = math.cos(th) * dx + math.sin(th) * dy
    e_y = -math.sin(th) * dx + math.cos(th) * dy
    r = math.hypot(e_x, e_y)
    cos_phi, sin_phi = (e_x / r, e_y / r) if r > 0 else (1.0, 0.0)
    cos_th, sin_th = math.cos(ref[2] - th), math.sin(ref[2] - th)
    b = math.log(1.0 + 1.0 / t)
    cos_m = math.cos(float(gains.phi_m))
    ahead = _sigmoid((cos_phi - cos_m) / t + b)
    behind = _sigmoid((-cos_m - cos_phi) / t - b)
    d = ahead - behind
    flip_phi = math.tanh(cos_phi / t + b)
    flip_th = math.tanh(cos_th / t + b)
    cos_phi_bar, sin_phi_bar = flip_phi * cos_phi, flip_phi * sin_phi
    sin_th_bar = flip_th * sin_th
    r_e, r_a = float(gains.r_e), float(gains.r_a)
    i0 = _sigmoid((r_e - r) / (r_e * t) + b)
    i1 = _sigmoid((r_a - r) / (r_a * t) - b)

    def sgn(value: float) -> float:
        return math.tanh(value / t - b)

    eps_1 = 0.5 - float(gains.alpha) * sgn(sin_th_bar) * sgn(sin_th_bar + sin_phi_bar)
    eps = (1 - i0) * (1 - d * d * i1 * (1 - eps_1))
    ell = math.pi * r / (2 * float(gains.r_m))
    r_bar = ell - t * _softplus((ell - math.pi / 2) / t)
    v = float(gains.kr) * d * math.sin(r_bar) * cos_phi_bar
    omega = float(gains.k_theta) * (eps * sin_phi_bar + (1 - eps) * sin_th_bar)
    return v, omega


@functools.cache
def relaxed_want(t: float) -> np.ndarray:
    """``relaxed_command`` of every test pose, ``(n, 2)``."""
    return np.array([relaxed_command(p, q, GAINS, t) for p, q in zip(POSES, REFS, strict=True)])


@pytest.mark.parametrize("t", [0.03, 0.4])
def test_the_relaxed_law_is_the_documented_one(t):
    v, omega = w.control(POSES, REFS, GAINS, temperature=t)
    want = relaxed_want(t)
    np.testing.assert_allclose(v, want[:, 0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(omega, want[:, 1], rtol=0, atol=1e-10)
    # Not the hard law: the relaxation is on.
    assert np.abs(np.asarray(v) - WANT["v"]).max() > 1e-3


def test_the_law_inside_jit_with_a_traced_temperature_is_the_same_law():
    # As the tuners call it: traced poses and a traced temperature.
    hard = jax.jit(lambda p, q: w.control(p, q, GAINS))(POSES, REFS)
    np.testing.assert_allclose(hard[0], WANT["v"], rtol=0, atol=1e-11)
    relaxed = jax.jit(lambda p, q, t: w.control(p, q, GAINS, temperature=t))(POSES, REFS, 0.4)
    np.testing.assert_allclose(np.stack(relaxed, -1), relaxed_want(0.4), rtol=0, atol=1e-10)
    # The rollouts' call: the pose as its frame, relaxed.
    frame = (POSES[:, 0], POSES[:, 1], np.cos(POSES[:, 2]), np.sin(POSES[:, 2]))
    got = law.SHIM_SUNG.command(None, REFS, GAINS, temperature=0.4, frame=frame)
    np.testing.assert_allclose(np.stack(got, -1), relaxed_want(0.4), rtol=0, atol=1e-10)


def test_a_float32_frame_against_float64_references_is_computed_in_float64():
    # The rollouts may hand a float32 frame with float64 references: every
    # part is promoted to the wider type before the rotation.
    frame64 = (POSES[:, 0], POSES[:, 1], np.cos(POSES[:, 2]), np.sin(POSES[:, 2]))
    frame32 = tuple(np.asarray(part, np.float32) for part in frame64)
    got = law.polar_error(None, REFS, frame=frame32)
    want = law.polar_error(None, REFS, frame=tuple(np.float64(part) for part in frame32))
    for g, w_ in zip(got, want, strict=True):
        assert g.dtype == np.float64
        np.testing.assert_array_equal(g, w_)


def test_a_cold_relaxation_is_the_hard_law_away_from_the_switches():
    # At T = 1e-9 every switch has decided (within ~T of its threshold
    # at most), so the relaxed law is the hard one but at the tie poses.
    v, omega = w.control(POSES[:300], REFS[:300], GAINS, temperature=1e-9)
    np.testing.assert_allclose(v, WANT["v"][:300], rtol=0, atol=1e-6)
    np.testing.assert_allclose(omega, WANT["omega"][:300], rtol=0, atol=1e-6)


# ---------------------------------------------------------------- the pieces, at their edges


def test_the_saturated_distance_is_a_quarter_turn_at_r_m():
    r = np.array([0.0, 4.5, 9.0 * (1 - 1e-12), 9.0, 30.0])
    np.testing.assert_allclose(
        law.saturated_distance(r, 9.0), np.minimum(math.pi * r / 18.0, math.pi / 2), rtol=1e-15
    )
    relaxed = law.saturated_distance(r, 9.0, temperature=0.2)
    ell = math.pi * r / 18.0
    want = [e - 0.2 * _softplus((e - math.pi / 2) / 0.2) for e in ell]
    np.testing.assert_allclose(relaxed, want, rtol=0, atol=1e-14)


def test_sgn_and_fold_decide_their_ties_as_documented():
    np.testing.assert_array_equal(
        law.sgn(np.array([-2.0, -0.0, 0.0, 1e-300, 3.0])), [-1, -1, -1, 1, 1]
    )
    cos_a = np.array([-0.5, 0.0, 0.5, -1.0])
    sin_a = np.array([0.8, 1.0, -0.8, 0.0])
    c, s = law.fold(cos_a, sin_a)
    np.testing.assert_array_equal(c, [0.5, 0.0, 0.5, 1.0])
    np.testing.assert_array_equal(s, [-0.8, 1.0, -0.8, -0.0])
    t = 0.1
    b = math.log(1 + 1 / t)
    np.testing.assert_allclose(
        law.sgn(np.array([0.0, 0.05]), temperature=t),
        [math.tanh(-b), math.tanh(0.05 / t - b)],
        rtol=1e-14,
    )
    c, s = law.fold(cos_a, sin_a, temperature=t)
    flips = np.tanh(cos_a / t + b)
    np.testing.assert_allclose(c, flips * cos_a, rtol=1e-14)
    np.testing.assert_allclose(s, flips * sin_a, rtol=1e-14)


def test_direction_is_loose_ahead_strict_behind_and_relaxes_as_documented():
    phi = np.array([0.0, PHI_M, PHI_M + 1e-9, math.pi - PHI_M, math.pi - PHI_M + 1e-9, math.pi])
    err = law.PolarError(np.full(6, 5.0), np.cos(phi), np.sin(phi), np.ones(6), np.zeros(6))
    np.testing.assert_array_equal(law.direction_flag(err, PHI_M), [1, 1, 0, 0, -1, -1])
    t = 0.05
    b = math.log(1 + 1 / t)
    cos_m = math.cos(PHI_M)
    want = [_sigmoid((c - cos_m) / t + b) - _sigmoid((-cos_m - c) / t - b) for c in np.cos(phi)]
    np.testing.assert_allclose(law.direction_flag(err, PHI_M, temperature=t), want, atol=1e-14)


def test_wheel_speeds_keep_the_batch_axes_first_and_trace():
    robot = w.Robot(half_track=2.0)
    v, omega = np.arange(6.0).reshape(2, 3), np.ones((2, 3))
    got = law.wheel_speeds(v, omega, robot)
    assert got.shape == (2, 3, 2)
    np.testing.assert_array_equal(got, np.stack([v - 2.0, v + 2.0], axis=-1))
    traced = jax.jit(lambda a, b: law.wheel_speeds(a, b, robot))(v, omega)
    np.testing.assert_array_equal(traced, got)


def test_the_controller_warns_of_wheels_it_cannot_drive_and_turns_it_cannot_sample():
    with pytest.warns(w.WheelSpeedWarning, match=r"k_r \+ L\*k_theta = 138.5 cm/s exceeds"):
        law.SHIM_SUNG.check_robot(w.Gains(), w.Robot())
    # The robot's own budget: feasible on a fast robot, not on a narrow slow one.
    fast = w.Robot(v_max=150.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        law.SHIM_SUNG.check_robot(w.Gains(), fast)
    with pytest.warns(w.WheelSpeedWarning, match=r"= 82 cm/s exceeds v_max = 80 cm/s"):
        law.SHIM_SUNG.check_robot(
            w.Gains(kr=60.0, k_theta=4.0), w.Robot(half_track=5.5, v_max=80.0)
        )
    with pytest.warns(w.SamplingWarning, match=r"k_theta\*dt = 2.64"):
        law.SHIM_SUNG.check_sampling(w.Gains(k_theta=80.0), 0.033)


def test_wheel_speeds_and_error_angles():
    robot = w.Robot(half_track=7.5)
    np.testing.assert_array_equal(
        law.wheel_speeds(np.array([10.0, -4.0]), np.array([2.0, 0.5]), robot),
        [[10.0 - 15.0, 10.0 + 15.0], [-4.0 - 3.75, -4.0 + 3.75]],
    )
    err = law.PolarError(
        np.array([1.0, 1.0]), np.array([-1.0, 0.6]), np.array([0.0, -0.8]),
        np.array([-1.0, 0.0]), np.array([0.0, 1.0]),
    )  # fmt: skip
    phi, theta = law.error_angles(err)
    np.testing.assert_allclose(phi, [math.pi, math.atan2(-0.8, 0.6)], rtol=1e-15)
    np.testing.assert_allclose(theta, [-math.pi, math.pi / 2], rtol=1e-15)  # θ_e ∈ [−π, π)
    np.testing.assert_allclose(
        law.wrap_angle(np.array([math.pi, 3 * math.pi / 2])), [-math.pi, -math.pi / 2], rtol=1e-15
    )
    np.testing.assert_allclose(
        law.lyapunov(err), 0.5 + (1 - 1.0) + (1 - 1.0) + np.array([0.0, 0.4 + 1.0]), atol=1e-15
    )


# ---------------------------------------------------------------- checked before tracing


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: w.control([0, 0, 0], [1, 2], GAINS), "ref"),
        (lambda: w.control(np.zeros((2, 3)), np.zeros((3, 3)), GAINS), "batch shape (2,)"),
        (lambda: w.control([0, 0, 0], [1, 2, 0], GAINS, temperature=-1.0), "temperature"),
    ],
)
def test_bad_arguments_are_refused_naming_them(call, message):
    with pytest.raises(ValueError) as err:
        call()
    assert message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_the_pieces_take_any_gains_with_the_region_radii():
    # A schedule's per-state gains are no Gains but carry Φ_m, R_e and R_a.
    err = law.polar_error([0.0, 0.0, 0.0], [3.0, 2.0, 0.5])
    d = law.direction_flag(err, PHI_M)
    fields = {"phi_m": PHI_M, "r_e": 0.8, "r_a": 6.0, "alpha": 0.3}
    np.testing.assert_allclose(
        law.blend(err, d, types.SimpleNamespace(**fields)), law.blend(err, d, GAINS), rtol=0
    )


def test_poses_are_checked_in_full():
    with pytest.raises(ValueError) as err:
        w.control(np.zeros((2, 3)), np.zeros((3, 3)), GAINS)
    assert (
        str(err.value) == "pose has batch shape (2,) and ref (3,); allowed: shapes that broadcast"
    )
    with pytest.raises(ValueError) as err:
        w.controllers.control_diagnostics(np.zeros((2, 4, 3)), np.zeros((3, 4, 3)), GAINS)
    assert str(err.value) == (
        "pose has batch shape (2, 4) and ref (3, 4); allowed: shapes that broadcast"
    )
    for call, name in (
        (lambda: w.control("abc", [1.0, 2.0, 0.0], GAINS), "pose"),
        (lambda: w.control([0.0, 0.0, 0.0], [1.0, "b", 0.0], GAINS), "ref"),
    ):
        with pytest.raises(ValueError, match=rf"^{name}\b"):
            call()


def test_the_saturation_is_linear_up_to_r_m():
    np.testing.assert_allclose(law.saturated_distance(0.25, 0.5), math.pi / 4, rtol=1e-15)
    np.testing.assert_allclose(law.saturated_distance(0.1, 0.5), math.pi / 10, rtol=1e-15)
    assert float(law.saturated_distance(7.0, 0.5)) == pytest.approx(math.pi / 2, rel=1e-7)


def test_checked_calls_refuse_what_traced_ones_never_see():
    with pytest.raises(ValueError, match=r"^pose"):
        w.control([math.nan, 0.0, 0.0], [1.0, 2.0, 0.0], GAINS)
    with pytest.raises(ValueError, match=r"^temperature = -1.0 is not allowed"):
        w.control([0.0, 0.0, 0.0], [1.0, 2.0, 0.0], GAINS, temperature=-1.0)
    with pytest.raises(ValueError, match=r"^pose"):
        w.controllers.control_diagnostics([math.nan, 0.0, 0.0], [1.0, 2.0, 0.0], GAINS)


def test_the_entry_points_are_one_program_called_with_values_or_traced():
    """``control`` and ``control_diagnostics`` give the same bits eagerly and inside ``jit``."""
    # Everything an argument of the caller's jit: values it closes over, XLA
    # may fold into constants, rounding them otherwise.
    eager = w.control(POSES, REFS, GAINS)
    traced = jax.jit(w.control)(POSES, REFS, GAINS)
    for e, t in zip(eager, traced, strict=True):
        np.testing.assert_array_equal(np.asarray(e), np.asarray(t))
    relaxed = w.control(POSES, REFS, GAINS, temperature=0.4)
    traced = jax.jit(lambda p, q, g, t: w.control(p, q, g, temperature=t))(POSES, REFS, GAINS, 0.4)
    for e, t in zip(relaxed, traced, strict=True):
        np.testing.assert_array_equal(np.asarray(e), np.asarray(t))
    eager = w.controllers.control_diagnostics(POSES, REFS, GAINS)
    traced = jax.jit(w.controllers.control_diagnostics)(POSES, REFS, GAINS)
    for field in eager._fields:
        np.testing.assert_array_equal(getattr(eager, field), getattr(traced, field), err_msg=field)


def test_the_building_blocks_check_nothing():
    """Pure: a NaN distance gives NaN, not a region or an error (the entry points check)."""
    err = law.PolarError(np.float64(np.nan), 1.0, 0.0, 1.0, 0.0)
    assert np.isnan(float(law.lyapunov(err)))
    assert np.isnan(float(law.saturated_distance(err.r, 20.0)))
    assert np.isnan(float(law.commands(err, GAINS)[0]))


def test_fold_keeps_float32_in_a_float64_session():
    # The flip is made of Python numbers (float64 here): it must not promote.
    for temperature in (None, 0.1):
        cos_bar, sin_bar = law.fold(jnp.float32(-0.6), jnp.float32(0.8), temperature=temperature)
        assert cos_bar.dtype == sin_bar.dtype == jnp.float32, temperature
    cos_bar, sin_bar = law.fold(jnp.float32(-0.6), jnp.float32(0.8))
    assert (float(cos_bar), float(sin_bar)) == (np.float32(0.6), np.float32(-0.8))
