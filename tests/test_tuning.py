"""Gain tuning: the feasible set, the loss and its gradients, the robust gradient, bad input."""

import importlib.util
import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import tuning

# Gains away from every face of the search box and with R_e < R_a < R_m, so
# that every threshold shapes the relaxed law's output.
MIDDLE = w.Gains(kr=70.0, k_theta=15.0, phi_m=1.2, r_m=8.0, r_a=5.0, r_e=1.5, alpha=0.3)
# A 1 s horizon (31 steps) shows every property below at a fraction of the cost.
SHORT = {"horizon": 1.0}
EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def assert_feasible(gains: w.Gains) -> None:
    """The docs/model.md §3 ranges (a rollout validates them) and k_r + L k_θ ≤ V_max."""
    gains = jax.tree.map(lambda x: np.asarray(x, np.float64), gains)
    assert np.all(w.controllers.check_feasible(gains)), gains
    for name in ("kr", "k_theta", "r_e", "alpha"):
        assert np.all(np.asarray(getattr(gains, name)) > 0), name
    assert np.all((gains.phi_m > 0) & (gains.phi_m < math.pi / 2))
    assert np.all(gains.alpha < 0.5)
    assert np.all((gains.r_e <= gains.r_a) & (gains.r_a <= gains.r_m))


# ---------------------------------------------------------------- feasible set


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_every_point_of_the_cube_maps_to_feasible_gains(dtype):
    rng = np.random.default_rng(0)
    corners = np.array(np.meshgrid(*[[0.0, 1.0]] * 7)).reshape(7, -1).T  # all 128 corners
    u = np.concatenate([corners, rng.uniform(size=(500, 7))]).astype(dtype)
    assert_feasible(tuning.gains_from_unit(jnp.asarray(u, dtype)))


def test_unit_from_gains_inverts_gains_from_unit():
    u = np.random.default_rng(1).uniform(0.01, 0.99, size=(20, 7))
    gains = tuning.gains_from_unit(jnp.asarray(u))
    for k, row in enumerate(u):
        one = jax.tree.map(lambda leaf, k=k: float(leaf[k]), gains)
        # float64 round trip through exp/log: a few ulps.
        np.testing.assert_allclose(tuning.unit_from_gains(one), row, rtol=1e-10, atol=1e-12)
    # The logits are the same point seen through the sigmoid.
    z = tuning.logits_from_gains(MIDDLE)
    back = tuning.gains_as_dict(tuning.gains_from_logits(jnp.asarray(z)))
    for name, value in tuning.gains_as_dict(MIDDLE).items():
        np.testing.assert_allclose(back[name], value, rtol=1e-10)


def test_paper_start_lies_just_inside_the_cube():
    u = tuning.unit_from_gains(tuning.PAPER_FEASIBLE_GAINS)
    assert np.all((u >= 1e-3) & (u <= 1 - 1e-3))
    start = tuning.gains_as_dict(tuning.gains_from_unit(jnp.asarray(u)))
    # The paper's R_a = R_m sits on a face of the cube: R_a moves in by 0.5 %,
    # and R_e with it (it is stored relative to R_a); the rest stay, to
    # float64 rounding through exp/log.
    paper = tuning.gains_as_dict(tuning.PAPER_FEASIBLE_GAINS)
    assert list(paper) == list(tuning.GAIN_FIELDS)
    for name in ("kr", "k_theta", "phi_m", "r_m", "alpha"):
        np.testing.assert_allclose(start[name], paper[name], rtol=1e-12)
    for name in ("r_a", "r_e"):
        # R_a / R_m = 0.01 ** (1 − u) on a log scale, and u is held 1e-3 inside
        # the face u = 1: R_a moves in by 0.01 ** 1e-3 = 0.99540.
        np.testing.assert_allclose(start[name], paper[name] * 0.01**1e-3, rtol=1e-4)


# ---------------------------------------------------------------- gradients


def _at_polar(r, phi, theta):
    """A reference at distance r, bearing phi, heading theta from the origin facing +X."""
    return [r * math.cos(phi), r * math.sin(phi), theta]


AWKWARD = {
    "r_e=0": [0.0, 0.0, 0.0],
    "r_e=0,theta=pi": [0.0, 0.0, math.pi],
    "r_e=0,theta=pi/2": [0.0, 0.0, math.pi / 2],
    "r_e=R_e": _at_polar(MIDDLE.r_e, 0.3, 0.2),
    "r_e=R_a": _at_polar(MIDDLE.r_a, 0.3, 0.2),
    "r_e=R_m": _at_polar(MIDDLE.r_m, 0.3, 0.2),
    "phi_e=+phi_m": _at_polar(10.0, MIDDLE.phi_m, 0.2),
    "phi_e=-phi_m": _at_polar(10.0, -MIDDLE.phi_m, 0.2),
    "phi_e=pi-phi_m": _at_polar(10.0, math.pi - MIDDLE.phi_m, 0.2),
    "phi_e=pi": _at_polar(10.0, math.pi, 0.2),
    "theta_e=pi/2": _at_polar(10.0, 0.3, math.pi / 2),
    "far (500 cm)": _at_polar(500.0, 2.0, -1.0),
}
# Every batch below has as many poses as AWKWARD, so that each function
# compiles once for all of them.
N = len(AWKWARD)
Z_MIDDLE = jnp.asarray(tuning.logits_from_gains(MIDDLE))
# A cap that caps nothing, in the same compiled program as the real cap.
NO_CAP = 1e30


@jax.jit
def _hard_value_and_grad(gains, refs):
    return jax.value_and_grad(lambda g: tuning.tuning_loss(g, refs, temperature=None, **SHORT))(
        gains
    )


def test_robust_gradient_without_cap_matches_central_differences_of_the_loss():
    refs = jnp.asarray(random_refs(3, N))
    loss, grad, stats = tuning.robust_gradient(
        Z_MIDDLE, refs, temperature=0.1, pose_clip=NO_CAP, **SHORT
    )
    assert float(stats["dropped"]) == 0.0 and float(stats["clipped"]) == 0.0

    def loss_at(z):
        return float(
            tuning.tuning_loss(tuning.gains_from_logits(z), refs, temperature=0.1, **SHORT)
        )

    # The mean loss, and its gradient through gains_from_logits, per logit.
    np.testing.assert_allclose(float(loss), loss_at(Z_MIDDLE), rtol=1e-12)
    h = 1e-6
    for k in range(7):
        step = jnp.zeros(7).at[k].set(h)
        central = (loss_at(Z_MIDDLE + step) - loss_at(Z_MIDDLE - step)) / (2 * h)
        # float64, step 1e-6: truncation error O(h²) and rounding O(1e-16/h)
        # are both ~1e-9 relative.
        np.testing.assert_allclose(float(grad[k]), central, rtol=1e-5, atol=1e-9)


def test_remat_changes_what_the_gradient_stores_not_what_it_is():
    refs = jnp.asarray(random_refs(4, N))

    def grad(remat):
        def loss(gains):
            return tuning.tuning_loss(gains, refs, temperature=0.1, remat=remat, **SHORT)

        return jax.grad(loss)(MIDDLE)

    with_remat, without = grad(True), grad(False)
    for a, b in zip(jax.tree.leaves(with_remat), jax.tree.leaves(without), strict=True):
        np.testing.assert_allclose(float(a), float(b), rtol=1e-9, atol=1e-12)
    # Compile-time sizes, not timings: storing the steps' intermediates
    # needs several times the buffers of recomputing them.
    # (experiments/gradient_cost.py, whose compiled programs these are.)
    spec = importlib.util.spec_from_file_location("gradient_cost", EXPERIMENTS / "gradient_cost.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    peak = {r: script.peak_bytes(script.programs(64, 20, r)[0]["gradient"]) for r in (True, False)}
    assert peak[False] > 3 * peak[True]


def test_gradients_are_finite_at_awkward_poses():
    refs = jnp.asarray(list(AWKWARD.values()))
    # The smooth law: the tuner's gradient drops no pose, so every pose's
    # loss and gradient are finite (a dropped one would be counted).
    _, grad, stats = tuning.robust_gradient(
        Z_MIDDLE, refs, temperature=0.05, pose_clip=NO_CAP, **SHORT
    )
    assert float(stats["dropped"]) == 0.0 and np.all(np.isfinite(grad))
    # The hard law (a non-finite pose would make the mean non-finite).
    value, grads = _hard_value_and_grad(MIDDLE, refs)
    assert np.isfinite(float(value))
    for name in tuning.GAIN_FIELDS:
        assert np.isfinite(float(getattr(grads, name))), f"d loss / d {name} not finite"
    # Φ_m, R_a and R_e only move switches, so their gradient is zero even on a
    # switching surface; k_r, k_θ, R_m, α scale commands.
    for name in ("phi_m", "r_a", "r_e"):
        assert float(getattr(grads, name)) == 0.0, name
    for name in ("kr", "k_theta", "r_m", "alpha"):
        assert float(getattr(grads, name)) != 0.0, name


def test_relaxed_loss_tends_to_the_hard_loss():
    refs = jnp.asarray(random_refs(5, N))
    hard = float(_hard_value_and_grad(MIDDLE, refs)[0])
    soft = [float(tuning.tuning_loss(MIDDLE, refs, temperature=t, **SHORT)) for t in (1e-3, 1e-6)]
    # At 1e-6 every switch is resolved unless a sample lies within ~1e-5 of a
    # surface, which these 12 × 31 samples do not: the rollouts coincide.
    np.testing.assert_allclose(soft[1], hard, rtol=1e-6)
    assert abs(soft[0] - hard) < 0.1 * hard  # s; only near switching surfaces


def test_hard_arrival_term_is_the_arrival_time_of_docs_model_6():
    # With the law hard and the "arrived" test sharp, T̃ is the §6 arrival
    # time, from metrics on the recorded runs, or the horizon's cap,
    # dt (steps + 1), for a run that has not settled by its end.
    refs = random_refs(5, 64)
    sharp = tuning.LossWeights(arrival_softness=1e-9)
    terms = tuning.loss_terms(MIDDLE, refs, temperature=None, weights=sharp, horizon=1.5)
    steps = 46  # periods of 0.033 s that cover 1.5 s
    arrival = np.asarray(w.arrival_time(w.batch_rollout(refs, MIDDLE, steps=steps), refs, dt=0.033))
    settled = np.isfinite(arrival)
    assert 0.2 < settled.mean() < 0.8  # both kinds of run are here
    np.testing.assert_allclose(np.asarray(terms.arrival)[settled], arrival[settled], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(terms.arrival)[~settled], 0.033 * (steps + 1))


def test_robust_gradient_caps_outliers_and_drops_non_finite_runs():
    refs = jnp.asarray(random_refs(8, N))
    _, uncapped, _ = tuning.robust_gradient(
        Z_MIDDLE, refs, temperature=0.1, pose_clip=NO_CAP, **SHORT
    )
    _, capped, stats = tuning.robust_gradient(Z_MIDDLE, refs, temperature=0.1, **SHORT)
    assert np.all(np.isfinite(capped))
    # Capping at the median leaves at least half the poses as they are.
    assert 0.0 < float(stats["clipped"]) <= 0.5
    assert np.linalg.norm(capped) < np.linalg.norm(uncapped)
    # A run whose loss overflows contributes nothing, and the rest still count:
    # at 1e152 cm with tol_r = 1e-3 cm, (r_e / tol_r)² is inf in float64.
    far = refs.at[0].set(jnp.array([1e152, 0.0, 0.0]))
    loss, grad, stats = tuning.robust_gradient(Z_MIDDLE, far, temperature=0.1, tol_r=1e-3, **SHORT)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(grad)) and np.any(grad != 0)
    np.testing.assert_allclose(float(stats["dropped"]), 1 / N)


def test_ideal_loop_has_no_saturation_and_nonideal_gradients_are_finite():
    refs = jnp.array([[30.0, -20.0, 2.0]])
    fast = w.Gains(kr=100.0, k_theta=13.0, phi_m=1.2, r_m=3.0, r_a=2.0, r_e=0.5, alpha=0.3)
    ideal = tuning.loss_terms(fast, refs, temperature=0.1, horizon=0.5)
    assert float(ideal.saturation[0]) == 0.0
    assert float(ideal.arrival[0]) > 0.0 and float(ideal.log_error[0]) > 0.0
    # The non-ideal loop: finite gradients for every gain.
    nonideal = {"horizon": 0.5, "velocity": "nonideal", "substeps": 10}
    value, grad = jax.jit(  # one program for the loss and its gradient, as the tuner runs it
        jax.value_and_grad(lambda g: tuning.tuning_loss(g, refs, temperature=0.05, **nonideal))
    )(fast)
    assert np.isfinite(float(value))
    for name in tuning.GAIN_FIELDS:
        assert np.isfinite(float(getattr(grad, name))), name
    assert any(float(getattr(grad, name)) != 0.0 for name in tuning.GAIN_FIELDS)


def test_float32_robust_gradient_is_finite_and_steps_stay_feasible():
    # The tuner's default precision: the robust gradient must stay finite
    # where a plain float32 mean may overflow.
    with jax.enable_x64(False):
        refs = jnp.concatenate(
            [
                jnp.asarray(list(AWKWARD.values()), jnp.float32),
                jnp.asarray(random_refs(11, 4), jnp.float32),
            ]
        )
        z = jnp.asarray(tuning.logits_from_gains(MIDDLE), jnp.float32)
        loss, grad, _ = tuning.robust_gradient(z, refs, temperature=0.1, **SHORT)
        assert grad.dtype == jnp.float32
        assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(grad)))
        # A large step in logit space still lands on feasible gains.
        assert_feasible(tuning.gains_from_logits(z - 1e3 * jnp.sign(grad)))


def test_random_search_scores_its_start_first():
    refs = jnp.asarray(random_refs(9, 8))
    # A zero budget still scores one chunk; a chunk of one is the start alone.
    search = tuning.random_search(jax.random.key(0), refs, budget_s=0.0, chunk=1, **SHORT)
    assert search.candidates == 1
    assert_feasible(search.gains)
    u = tuning.unit_from_gains(tuning.PAPER_FEASIBLE_GAINS)
    start = tuning.gains_as_dict(tuning.gains_from_unit(jnp.asarray(u)))
    for name, value in tuning.gains_as_dict(search.gains).items():
        np.testing.assert_allclose(value, start[name], rtol=1e-12)
    assert math.isfinite(search.score) and search.score > 0


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("iters", 0),
        ("poses", -1),
        ("seed", 2**40),
        ("velocity", "fast"),
        ("learning_rate", 0.0),
        ("temperature_end", float("nan")),
        ("horizon", -1.0),
        ("random_search", "yes"),
        ("temperature_start", 1e6),
        ("eval_poses", 10**12),
        ("horizon", 1e-12),
    ],
)
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        tuning.TuneConfig(**{field: value}).validate()


def test_the_annealing_never_softens_the_law():
    # An end temperature above the start would relax the law as the tuning goes on.
    message = r"temperature_end = 0.2 is not allowed; allowed: at most temperature_start \(0.1\)"
    for kind in (tuning.TuneConfig, tuning.RobustConfig):
        with pytest.raises(ValueError, match=message):
            kind(temperature_start=0.1, temperature_end=0.2).validate()
        kind(temperature_start=0.1, temperature_end=0.1).validate()  # a constant one is fine


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda refs: tuning.tuning_loss(MIDDLE, refs, temperature=-1.0), "temperature"),
        (
            lambda refs: tuning.tuning_loss(MIDDLE.replace(phi_m=2.0), refs, temperature=0.1),
            "phi_m",
        ),
        (lambda refs: tuning.tuning_loss(MIDDLE, refs[:, :2], temperature=0.1), "refs"),
        (lambda refs: tuning.loss_terms(MIDDLE, refs, temperature=0.1, horizn=1.0), "horizn"),
        (lambda refs: tuning.robust_gradient(np.zeros(7), refs, temperature=0.1, tol_r=0), "tol_r"),
        (
            lambda refs: tuning.robust_gradient(np.zeros(7), refs, temperature=0.1, pose_clip=0),
            "pose_clip",
        ),
    ],
)
def test_loss_rejects_bad_input_before_tracing(call, name):
    with pytest.raises(ValueError, match=name):
        call(np.zeros((2, 3)))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        # The temperatures the rollouts allow, no others.
        ({"temperature": 1e-38}, r"temperature = 1e-38 is not allowed; allowed: a number >= 1e-12"),
        ({"temperature": 1000.0}, r"temperature = 1000.0 is not allowed"),
        # The loss divides by tol_r² and sin²(tol_θ).
        ({"tol_r": 1e-50}, r"tol_r = 1e-50 is too small for float32"),
        ({"tol_theta": 1e-50}, r"tol_theta = 1e-50 is too small for float32"),
        ({"weights": tuning.LossWeights(shaping=1e39)}, r"weights.shaping = 1e\+39 is beyond"),
        (
            {"horizon": 1e-12},
            r"horizon = 1e-12 s is shorter than one control period \(dt = 0.033 s\)",
        ),
    ],
)
def test_loss_options_that_would_give_nan_or_inf_are_refused(options, message):
    options = {"temperature": 0.05, **options}
    with jax.enable_x64(False), pytest.raises(ValueError, match=message):
        tuning.tuning_loss(MIDDLE, random_refs(0, 4), **options)


def test_robust_gradient_refuses_non_finite_logits_and_warns_only_about_its_own_gains():
    # N poses over the short horizon: the compiled gradient of the tests above.
    refs = random_refs(0, N)
    with pytest.raises(ValueError, match=r"z = .*nan.* allowed: finite logits"):
        tuning.robust_gradient(np.full(7, np.nan), refs, temperature=0.05, **SHORT)
    # Every z maps to feasible gains: no WheelSpeedWarning about others.
    with warnings.catch_warnings():
        warnings.simplefilter("error", w.WheelSpeedWarning)
        loss, grad, _ = tuning.robust_gradient(np.zeros(7), refs, temperature=0.05, **SHORT)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(grad)))
    # The logits become gains through one robot, not one per pose.
    robots = w.Robot(v_max=[100.0, 125.0, 110.0, 120.0])
    with pytest.raises(ValueError, match=r"robot.v_max has shape \(4,\); allowed: one robot"):
        tuning.robust_gradient(np.zeros(7), refs, temperature=0.05, robot=robots)
    with pytest.raises(ValueError, match=r"robot.v_max has shape \(4,\); allowed: one robot"):
        tuning.init_state(robot=robots)
