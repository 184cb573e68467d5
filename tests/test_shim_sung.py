"""The control law: values, bounds, edge poses and gradients (docs/model.md §2–3)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import wmr_jax as w
from wmr_jax import controllers as law

GAINS = w.Gains()
PHI_M = float(GAINS.phi_m)


def _pose(x, y, th):
    return jnp.array([x, y, th], dtype=jnp.float64)


def _at_polar(r, phi, theta_e):
    """A (pose, ref) pair with the robot at the origin facing +X: r_e, φ_e, θ_e as given."""
    return _pose(0.0, 0.0, 0.0), _pose(r * math.cos(phi), r * math.sin(phi), theta_e)


# Poses that sit exactly on a switch of the law (docs/model.md §3) or a singular point.
EDGE_CASES = {
    "r_e=0": (0.0, 0.0, 0.3),
    "r_e=0,theta=pi": (0.0, 0.0, math.pi),
    "theta_e=pi": (10.0, 0.2, math.pi),
    "theta_e=-pi": (10.0, 0.2, -math.pi),
    "theta_e=pi/2": (10.0, 0.2, math.pi / 2),
    "phi_e=+phi_m": (10.0, PHI_M, 0.1),
    "phi_e=-phi_m": (10.0, -PHI_M, 0.1),
    "phi_e=pi-phi_m": (10.0, math.pi - PHI_M, 0.1),
    "phi_e=-pi+phi_m": (10.0, -math.pi + PHI_M, 0.1),
    "phi_e=pi": (10.0, math.pi, 0.1),
    "phi_e=pi/2": (10.0, math.pi / 2, 0.1),
    "r_e=R_e": (float(GAINS.r_e), 0.2, 0.1),
    "r_e=R_a=R_m": (float(GAINS.r_a), 0.2, 0.1),
}


@pytest.mark.parametrize("case", EDGE_CASES.values(), ids=EDGE_CASES.keys())
def test_edge_poses_have_finite_values_and_gradients(case):
    pose, ref = _at_polar(*case)
    v, omega = w.control(pose, ref, GAINS)
    assert np.isfinite([float(v), float(omega)]).all()

    def speed(pose, ref, gains):
        v, omega = w.control(pose, ref, gains)
        return v + 3.0 * omega

    grads = jax.grad(speed, argnums=(0, 1, 2))(pose, ref, GAINS)
    for leaf in jax.tree.leaves(grads):
        assert np.isfinite(np.asarray(leaf)).all()
    # The relaxed law too: its gradients must be finite at the same points.
    relaxed = jax.grad(lambda p, g: sum(w.control(p, ref, g, temperature=0.05)), argnums=(0, 1))
    for leaf in jax.tree.leaves(relaxed(pose, GAINS)):
        assert np.isfinite(np.asarray(leaf)).all()
    diag = w.controllers.control_diagnostics(pose, ref, GAINS)
    assert all(np.isfinite(np.asarray(x)).all() for x in diag)


def test_edge_poses_match_reference():
    for r, phi, theta_e in EDGE_CASES.values():
        pose, ref = _at_polar(r, phi, theta_e)
        exp = w.studies.reference_diagnostics(np.asarray(pose), np.asarray(ref), GAINS)
        diag = w.controllers.control_diagnostics(pose, ref, GAINS)
        assert int(diag.region) == exp["region"], (r, phi, theta_e)
        # The angle inputs above are rounded to float64, so a few ulps.
        assert float(diag.v) == pytest.approx(exp["v"], abs=1e-12)
        assert float(diag.omega) == pytest.approx(exp["omega"], abs=1e-12)


def test_rollout_gradient_finite_from_goal():
    """Starting exactly at the reference (r_e = 0 at every sample) keeps gradients finite."""
    ref = jnp.array([0.0, 0.0, 0.0])

    def loss(gains):
        traj = w.rollout(ref, gains, steps=10)
        return jnp.sum(traj.poses**2)

    grads = jax.grad(loss)(GAINS)
    assert all(np.isfinite(np.asarray(g)) for g in jax.tree.leaves(grads))


def test_region_labels_follow_spec_order():
    r_e, r_a = float(GAINS.r_e), float(GAINS.r_a)
    cases = [
        ((0.5 * r_e, 0.0, 0.2), 0),
        ((0.5 * r_e, math.radians(90), 0.2), 0),  # Region 0 wins over d = 0
        ((5.0, math.radians(80), 0.2), 3),
        ((5.0, math.radians(20), 0.2), 1),
        ((5.0, math.radians(170), 0.2), 1),  # behind: d = −1, still Region 1
        ((r_a, math.radians(20), 0.2), 2),  # r_e = R_a is Region 2 (r_e < R_a is Region 1)
        ((50.0, math.radians(-60), 0.2), 2),
    ]
    for (r, phi, th), region in cases:
        pose, ref = _at_polar(r, phi, th)
        assert int(w.controllers.control_diagnostics(pose, ref, GAINS).region) == region


def test_direction_and_folding_make_backward_motion():
    pose, ref = _at_polar(30.0, math.pi, 0.0)  # reference straight behind
    v, omega = w.control(pose, ref, GAINS)
    assert float(v) == pytest.approx(-float(GAINS.kr), rel=1e-12)  # r̄_e saturated, cos φ̄ = 1
    assert float(omega) == pytest.approx(0.0, abs=1e-12)


# XLA on the CPU flushes subnormal floats to zero, NumPy does not: keep them out.
finite = st.floats(-200, 200, allow_nan=False, allow_subnormal=False)
angle = st.floats(-4 * math.pi, 4 * math.pi, allow_nan=False, allow_subnormal=False)


@settings(max_examples=300, deadline=None)
@given(x=finite, y=finite, th=angle, xr=finite, yr=finite, thr=angle)
def test_commands_are_bounded_and_match_reference(x, y, th, xr, yr, thr):
    pose, ref = _pose(x, y, th), _pose(xr, yr, thr)
    v, omega = w.control(pose, ref, GAINS)
    # |v| ≤ k_r and |ω| ≤ k_θ by construction (docs/model.md §3), so no wheel asks
    # for more than k_r + L k_θ.
    assert abs(float(v)) <= float(GAINS.kr) * (1 + 1e-12)
    assert abs(float(omega)) <= float(GAINS.k_theta) * (1 + 1e-12)
    rims = w.controllers.wheel_speeds(v, omega, w.Robot())
    assert float(jnp.max(jnp.abs(rims))) <= float(w.controllers.wheel_speed_bound(GAINS)) * (
        1 + 1e-12
    )
    exp = w.studies.reference_diagnostics((x, y, th), (xr, yr, thr), GAINS)
    # Equal up to the reordering of float64 arithmetic (angles of up to 4π) ...
    agree = abs(float(v) - exp["v"]) <= 1e-9 and abs(float(omega) - exp["omega"]) <= 1e-9
    # ... except where the law jumps and rounding decides the side.
    assert agree or _near_switch(exp, GAINS, 1e-9), exp


def _near_switch(exp, gains, tol):
    """Whether the reference's intermediates lie within ``tol`` of a switch of the law."""
    phi, theta = abs(exp["phi_e"]), abs(exp["theta_e"])
    sin_phi_bar = math.sin(phi if phi <= math.pi / 2 else math.pi - phi)
    margins = [
        abs(phi - float(gains.phi_m)),
        abs(phi - (math.pi - float(gains.phi_m))),
        abs(phi - math.pi / 2),  # fold of φ_e
        abs(theta - math.pi / 2),  # fold of θ_e
        min(theta, math.pi - theta),  # Sgn(sin θ̄_e)
        abs(math.sin(exp["theta_e"]) - sin_phi_bar),  # Sgn(sin θ̄_e + sin φ̄_e), up to sign
        abs(math.sin(exp["theta_e"]) + sin_phi_bar),
        abs(exp["r_e"] - float(gains.r_e)),
        abs(exp["r_e"] - float(gains.r_a)),
        exp["r_e"],
    ]
    return min(margins) < tol


def test_law_gradient_matches_central_differences():
    """Away from switches, d(v, ω)/d(pose) equals float64 central differences."""
    # Each component and its gradient compiled once, for every pose and reference.
    law_of = [jax.jit(lambda p, ref, c=c: w.control(p, ref, GAINS)[c]) for c in (0, 1)]
    grad_of = [jax.jit(jax.grad(f)) for f in law_of]
    rng = np.random.default_rng(0)
    for _ in range(20):
        r = rng.uniform(2.0, 40.0)
        phi = rng.choice([rng.uniform(-1.0, 1.0), rng.uniform(1.3, 1.8), rng.uniform(2.3, 3.0)])
        pose = jnp.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)])
        th = float(pose[2])
        ref = pose + jnp.array([r * math.cos(th + phi), r * math.sin(th + phi), 0.0])
        ref = ref.at[2].set(th + rng.uniform(-1.4, 1.4))
        for f, grad_f in zip(law_of, grad_of, strict=True):
            grad = np.asarray(grad_f(pose, ref))
            step = 1e-6
            fd = np.array(
                [
                    (float(f(pose.at[i].add(step), ref)) - float(f(pose.at[i].add(-step), ref)))
                    / (2 * step)
                    for i in range(3)
                ]
            )
            # Central differences of a smooth float64 function: O(step²) + 1e-10/step.
            np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6)


def test_region_3_turns_in_place_and_phi_bar_shrinks():
    rng = np.random.default_rng(11)
    n = 400
    bearing = rng.uniform(-math.pi, math.pi, n)
    dist = rng.uniform(2.0, 60.0, n)
    refs = np.stack([dist * np.cos(bearing), dist * np.sin(bearing), rng.uniform(-3, 3, n)], -1)
    traj = w.batch_rollout(refs, GAINS, steps=60)

    @jax.jit  # one program, not the error coordinates op by op
    def error_and_fold(poses, refs):
        err = law.polar_error(poses, refs[:, None, :])
        return err, law.fold(err.cos_phi, err.sin_phi)[1]

    err, sin_phi_bar = error_and_fold(traj.poses, jnp.asarray(refs))
    phi_bar = np.abs(np.arcsin(np.clip(np.asarray(sin_phi_bar), -1, 1)))
    region = np.asarray(traj.region)
    in_3 = region == 3
    assert in_3.sum() > 100  # the sample really exercises Region 3
    np.testing.assert_array_equal(np.asarray(traj.v)[in_3], 0.0)
    # Across each Region-3 period, |φ̄_e| strictly decreases (v = 0, ω = k_θ sin φ̄_e).
    assert np.all(phi_bar[:, 1:][in_3] < phi_bar[:, :-1][in_3])
    # ... and r_e does not change while turning in place.
    r = np.asarray(err.r)
    np.testing.assert_allclose(r[:, 1:][in_3], r[:, :-1][in_3], rtol=1e-12)


def test_lyapunov_can_rise_in_region_3():
    """The paper's Case 1 says V̇ = −k_θ sin²φ_e ≤ 0 in Region 3; it drops a term.

    With v = 0 and ε = 1, V̇ = −k_θ sin φ̄_e (sin φ̄_e + sin θ̄_e), positive at
    φ̄_e = 75°, θ̄_e = −89° (docs/model.md §3). Check the sign over a short ideal step.
    """
    pose, ref = _at_polar(10.0, math.radians(75), math.radians(-89))
    diag = w.controllers.control_diagnostics(pose, ref, GAINS)
    assert int(diag.region) == 3 and float(diag.v) == 0.0
    h = 1e-6  # first-order difference: error ~ V̈ h / 2 relative to V̇ ≈ 0.33
    after = w.dynamics.arc_step(pose, diag.v, diag.omega, h)
    v_after = w.controllers.control_diagnostics(after, ref, GAINS).lyapunov
    rate = (float(v_after) - float(diag.lyapunov)) / h
    k_th, phi, th = float(GAINS.k_theta), math.radians(75), math.radians(-89)
    predicted = -k_th * math.sin(phi) * (math.sin(phi) + math.sin(th))
    assert predicted > 0
    assert rate == pytest.approx(predicted, rel=1e-3)


@pytest.mark.parametrize("temperature", [1e-2, 1e-3, 1e-4])
def test_relaxed_law_tends_to_hard_law(temperature):
    rng = np.random.default_rng(5)
    refs = np.concatenate([rng.uniform(-60, 60, (500, 2)), rng.uniform(-3, 3, (500, 1))], 1)
    pose = jnp.zeros(3)
    hard = np.stack(w.control(pose, refs, GAINS))
    soft = np.stack(w.control(pose, refs, GAINS, temperature=temperature))
    diag = w.controllers.control_diagnostics(pose, refs, GAINS)
    # Distance of each pose to the nearest switching surface of the law.
    cos_phi = np.cos(np.asarray(diag.phi_e))
    sin_phi_bar = np.sign(cos_phi + (cos_phi == 0)) * np.sin(np.asarray(diag.phi_e))
    cos_theta = np.cos(np.asarray(diag.theta_e))
    sin_theta_bar = np.sign(cos_theta + (cos_theta == 0)) * np.sin(np.asarray(diag.theta_e))
    folded_sum = np.abs(sin_theta_bar + sin_phi_bar)  # the argument of Region 1's second Sgn
    margin = np.min(
        np.stack(
            [
                np.abs(cos_phi - math.cos(PHI_M)),
                np.abs(cos_phi + math.cos(PHI_M)),
                np.abs(cos_phi),
                np.abs(np.asarray(diag.r_e) - float(GAINS.r_e)) / float(GAINS.r_e),
                np.abs(np.asarray(diag.r_e) - float(GAINS.r_a)) / float(GAINS.r_a),
                np.abs(np.cos(np.asarray(diag.theta_e))),
                np.abs(np.sin(np.asarray(diag.theta_e))),
                folded_sum,
            ]
        ),
        axis=0,
    )
    # The relaxed switches sit log(1 + 1/T)·T beside the hard ones (that is
    # how they decide ties as the hard law does); 10·T beyond that, each
    # relaxed step is within sigmoid(−10) ≈ 5e-5 of the hard one, and the
    # soft minimum of r̄_e within temperature·log 2 rad, which moves v by at
    # most k_r·temperature·log 2.
    clear = margin > (10 + math.log1p(1 / temperature)) * temperature
    assert clear.mean() > 0.5
    np.testing.assert_allclose(soft[:, clear], hard[:, clear], atol=200 * temperature)


@pytest.mark.parametrize("r", [20.0, 20.0 * (1 + 1e-9), 20.0 * (1 - 1e-9), 5.0, 200.0])
def test_relaxed_saturation_slope_is_the_logistic_one(r):
    # r̄ = ℓ − T softplus((ℓ − π/2)/T) with ℓ = π r / (2 R_m), so dr̄/dr is
    # (π / 2 R_m)(1 − σ((ℓ − π/2)/T)): at r = R_m exactly (ℓ = π/2 with no
    # rounding, since R_m = 20 and π/2 / 20 * 20 == π/2 in float64) it is half
    # the linear slope, and the slope is continuous through that point.
    r_m, t = 20.0, 0.05
    assert (math.pi / 2) / r_m * r_m == math.pi / 2
    slope = jax.grad(lambda x: law.saturated_distance(x, r_m, temperature=t))(r)
    excess = (r * ((math.pi / 2) / r_m) - math.pi / 2) / t
    want = (math.pi / 2) / r_m * (1.0 - 1.0 / (1.0 + math.exp(-excess)))
    np.testing.assert_allclose(float(slope), want, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("x64", [False, True])
def test_relaxed_saturation_holds_for_far_references(x64):
    # π r / (2 R_m) far above π/2: the soft minimum must not cancel to noise
    # (it gave v = -20 cm/s at 3e8 cm in float32, 118 cm/s > k_r at 1e17).
    gains = w.Gains(kr=60.0)
    with jax.enable_x64(x64):
        for x in (1e7, 3e8, 1e9, 1e17):
            v, _ = w.control([0.0, 0.0, 0.0], [x, 0.0, 0.0], gains, temperature=0.01)
            assert float(v) == pytest.approx(60.0, rel=1e-6), x


def test_the_elementwise_helpers_give_nan_for_nan_as_numpy_does():
    # One convention (docs/model.md §3): NaN in, NaN out, never a sign or a
    # folded angle made up for it; every number keeps its value.
    from wmr_jax import controllers, dynamics

    nan = float("nan")
    x = jnp.array([nan, -0.0, 0.0, 2.0, -jnp.inf, jnp.inf])
    np.testing.assert_array_equal(controllers.sgn(x), [nan, -1.0, -1.0, 1.0, -1.0, 1.0])
    assert np.isnan(controllers.sgn(nan, temperature=0.1))
    cos_bar, sin_bar = controllers.fold(jnp.array([nan, -1.0]), jnp.array([0.5, nan]))
    assert np.isnan(cos_bar[0]) and np.isnan(sin_bar[0])  # no angle is folded from a NaN
    assert np.isnan(sin_bar[1]) and cos_bar[1] == 1.0
    cos_bar, sin_bar = controllers.fold(jnp.array([nan]), jnp.array([0.5]), temperature=0.1)
    assert np.isnan(cos_bar[0]) and np.isnan(sin_bar[0])
    assert np.isnan(controllers.wrap_angle(nan)) and np.isnan(dynamics.sinc(nan))
    rims = w.controllers.wheel_speeds(jnp.array(nan), jnp.array(1.0), w.Robot())
    assert np.all(np.isnan(rims))


def test_the_law_reads_sgn_of_zero_as_minus_one():
    # From (0, 0, 0) toward (10, 5, 0): θ_e = 0 exactly, Region 1 (r_e < R_a).
    # With Sgn(0) = −1 (docs/model.md §3) ε = 0.5 + α = 0.75 and
    # ω = k_θ ε sin φ_e, sin φ_e = 5/√125; Sgn(0) = +1 would give ε = 0.25.
    gains = w.Gains()
    _, omega = w.control(jnp.array([0.0, 0.0, 0.0]), jnp.array([10.0, 5.0, 0.0]), gains)
    expected = gains.k_theta * (0.5 + gains.alpha) * 5.0 / math.sqrt(125.0)
    assert float(omega) == pytest.approx(expected, rel=1e-6)  # float32 rounding
