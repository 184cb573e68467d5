"""Gain tuning: feasibility, gradient correctness, robust gradients, resume, CLI errors."""

import argparse
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wmr_jax import tuning
from wmr_jax.params import Gains, Robot, check_feasible, validate_gains

# One small setting shared by the tests that run the driver, so that they
# compile once: 8 poses, a 1 s horizon (31 steps), no random search.
SMALL = tuning.TuneConfig(
    iters=6,
    poses=8,
    horizon=1.0,
    checkpoint_every=2,
    eval_poses=8,
    random_search=False,
)

# Gains away from every face of the search box and with R_e < R_a < R_m, so
# that every threshold shapes the relaxed law's output.
MIDDLE = Gains(kr=70.0, k_theta=15.0, phi_m=1.2, r_m=8.0, r_a=5.0, r_e=1.5, alpha=0.3)


def _assert_feasible(gains: Gains, robot: Robot | None = None) -> None:
    validate_gains(gains)  # SPEC §3 ranges; raises otherwise
    assert np.all(check_feasible(gains, robot)), tuning._gains_to_dict(gains)


# ---------------------------------------------------------------- feasible set


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_every_point_of_the_cube_maps_to_feasible_gains(dtype):
    rng = np.random.default_rng(0)
    corners = np.array(np.meshgrid(*[[0.0, 1.0]] * 7)).reshape(7, -1).T  # all 128 corners
    u = np.concatenate([corners, rng.uniform(size=(500, 7))]).astype(dtype)
    gains = tuning.gains_from_unit(jnp.asarray(u, dtype))
    _assert_feasible(jax.tree.map(lambda x: np.asarray(x, np.float64), gains))


def test_unit_from_gains_inverts_gains_from_unit():
    u = np.random.default_rng(1).uniform(0.01, 0.99, size=(20, 7))
    for row in u:
        gains = jax.tree.map(float, tuning.gains_from_unit(jnp.asarray(row)))
        # float64 round trip through exp/log: a few ulps.
        np.testing.assert_allclose(tuning.unit_from_gains(gains), row, rtol=1e-10, atol=1e-12)


def test_paper_start_lies_just_inside_the_cube():
    u = tuning.unit_from_gains(tuning.PAPER_FEASIBLE_GAINS)
    assert np.all((u >= 1e-3) & (u <= 1 - 1e-3))
    start = jax.tree.map(float, tuning.gains_from_unit(jnp.asarray(u)))
    # The paper's R_a = R_m sits on a face of the cube: R_a moves in by 0.5 %,
    # and R_e with it (it is stored relative to R_a); the rest stay, to
    # float64 rounding through exp/log.
    paper = tuning._gains_to_dict(tuning.PAPER_FEASIBLE_GAINS)
    for name in ("kr", "k_theta", "phi_m", "r_m", "alpha"):
        np.testing.assert_allclose(getattr(start, name), paper[name], rtol=1e-12)
    for name in ("r_a", "r_e"):
        np.testing.assert_allclose(getattr(start, name), paper[name] * 0.9954, rtol=1e-4)


# ---------------------------------------------------------------- gradients


def test_loss_gradient_matches_central_differences():
    refs = tuning.sample_refs(jax.random.key(3), 6)

    def loss(gains):
        return tuning.tuning_loss(gains, refs, temperature=0.1, horizon=1.0)

    grad = jax.grad(loss)(MIDDLE)
    for name in tuning.GAIN_FIELDS:
        x = float(getattr(MIDDLE, name))
        h = 1e-6 * x
        plus = float(loss(MIDDLE.replace(**{name: x + h})))
        minus = float(loss(MIDDLE.replace(**{name: x - h})))
        # float64, relative step 1e-6: truncation error O(h²) and rounding
        # O(1e-16/h) are both ~1e-9 relative; measured agreement is ≤ 4e-8.
        np.testing.assert_allclose(
            float(getattr(grad, name)), (plus - minus) / (2 * h), rtol=1e-5, atol=1e-9
        )


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


@pytest.mark.parametrize("temperature", [0.05, None], ids=["relaxed", "hard"])
def test_gradients_are_finite_at_awkward_poses(temperature):
    refs = np.array(list(AWKWARD.values()))
    # One pose per call: a non-finite gradient must not hide in a batch mean.
    grads = jax.vmap(
        jax.grad(lambda g, ref: tuning.tuning_loss(g, ref[None], temperature=temperature)),
        in_axes=(None, 0),
    )(MIDDLE, jnp.asarray(refs))
    for name in tuning.GAIN_FIELDS:
        bad = [
            k for k, ok in zip(AWKWARD, np.isfinite(getattr(grads, name)), strict=True) if not ok
        ]
        assert not bad, f"d loss / d {name} not finite at {bad}"
    if temperature is None:
        # The hard law: Φ_m, R_a and R_e only move switches, so their gradient
        # is zero even on a switching surface; k_r, k_θ, R_m, α scale commands.
        for name in ("phi_m", "r_a", "r_e"):
            assert np.all(np.asarray(getattr(grads, name)) == 0.0), name
        for name in ("kr", "k_theta", "r_m", "alpha"):
            assert np.any(np.asarray(getattr(grads, name)) != 0.0), name


def test_relaxed_loss_tends_to_the_hard_loss():
    refs = tuning.sample_refs(jax.random.key(5), 6)
    hard = float(tuning.tuning_loss(MIDDLE, refs, temperature=None, horizon=1.0))
    soft = [
        float(tuning.tuning_loss(MIDDLE, refs, temperature=t, horizon=1.0)) for t in (1e-3, 1e-6)
    ]
    # At 1e-6 every switch is resolved unless a sample lies within ~1e-5 of a
    # surface, which these 6 × 31 samples do not: the rollouts coincide.
    np.testing.assert_allclose(soft[1], hard, rtol=1e-6)
    assert abs(soft[0] - hard) < 0.1 * hard  # s; only near switching surfaces


@jax.jit
def _robust(z, refs, pose_clip):
    """The tuner's batch gradient; ``pose_clip = inf`` caps nothing."""
    return tuning._robust_value_and_grad(
        z,
        refs,
        jnp.zeros(3),
        Robot(),
        jnp.asarray(SMALL.dt),
        SMALL.spec(),
        jnp.asarray(0.1),
        pose_clip,
    )


def test_robust_gradient_without_caps_is_the_chain_rule_of_the_loss():
    refs = tuning.sample_refs(jax.random.key(7), 6)
    z = jnp.asarray(tuning._logits(tuning.unit_from_gains(MIDDLE)))
    loss, grad, stats = _robust(z, refs, jnp.inf)

    gains = tuning._gains_from_logits(z, Robot())
    value, by_gain = jax.value_and_grad(
        lambda g: tuning.tuning_loss(g, refs, temperature=0.1, horizon=1.0)
    )(gains)
    jacobian = jax.jacobian(
        lambda z: jnp.stack(
            [getattr(tuning._gains_from_logits(z, Robot()), n) for n in tuning.GAIN_FIELDS]
        )
    )(z)
    expected = jnp.stack([getattr(by_gain, n) for n in tuning.GAIN_FIELDS]) @ jacobian
    # Same arithmetic in another order (per pose, then summed): float64 rounding.
    np.testing.assert_allclose(loss, value, rtol=1e-12)
    np.testing.assert_allclose(grad, expected, rtol=1e-9, atol=1e-12)
    assert float(stats["dropped"]) == 0.0


def test_robust_gradient_caps_outliers_and_drops_non_finite_poses():
    refs = tuning.sample_refs(jax.random.key(8), 6)
    z = jnp.asarray(tuning._logits(tuning.unit_from_gains(MIDDLE)))
    _, uncapped, _ = _robust(z, refs, jnp.inf)
    _, capped, stats = _robust(z, refs, 1.0)
    assert np.all(np.isfinite(capped))
    # Capping at the median leaves at least half the poses as they are.
    assert float(stats["clipped"]) <= 0.5
    assert np.linalg.norm(capped) <= np.linalg.norm(uncapped) * (1 + 1e-12)
    # A pose whose run is not finite contributes nothing, and the rest still count.
    bad = refs.at[0].set(jnp.array([jnp.nan, 0.0, 0.0]))
    loss, grad, stats = _robust(z, bad, 1.0)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(grad))
    np.testing.assert_allclose(float(stats["dropped"]), 1 / 6)


def test_saturation_penalty_is_zero_for_the_ideal_loop():
    spec = SMALL.spec()
    ref = jnp.array([30.0, -20.0, 2.0])
    terms = tuning._pose_loss_terms(
        ref, MIDDLE, jnp.zeros(3), Robot(), jnp.asarray(SMALL.dt), spec, jnp.asarray(0.1)
    )
    assert float(terms[2]) == 0.0
    assert float(terms[0]) > 0.0 and float(terms[1]) > 0.0


def test_nonideal_loss_has_finite_gradients_for_every_gain():
    refs = tuning.sample_refs(jax.random.key(10), 4)
    fast = Gains(kr=100.0, k_theta=13.0, phi_m=1.2, r_m=3.0, r_a=2.0, r_e=0.5, alpha=0.3)
    value, grad = jax.value_and_grad(
        lambda g: tuning.tuning_loss(
            g, refs, temperature=0.05, horizon=0.5, velocity="nonideal", substeps=10
        )
    )(fast)
    assert np.isfinite(float(value))
    for name in tuning.GAIN_FIELDS:
        assert np.isfinite(float(getattr(grad, name))), name
    assert any(float(getattr(grad, name)) != 0.0 for name in tuning.GAIN_FIELDS)


# ---------------------------------------------------------------- the driver


def test_feasible_at_every_step_and_outputs(tmp_path):
    seen = []
    result = tuning.tune(
        tmp_path,
        SMALL,
        progress=False,
        callback=lambda i, loss, gains: seen.append(jax.tree.map(float, gains)),
    )
    assert len(seen) == SMALL.iters
    for gains in seen:
        _assert_feasible(gains)
    for row in result.history["gains"]:
        _assert_feasible(Gains(**dict(zip(tuning.GAIN_FIELDS, row, strict=True))))
    saved = json.loads((tmp_path / "tuned_gains.json").read_text())
    assert list(saved) == list(tuning.GAIN_FIELDS)
    _assert_feasible(Gains(**saved))
    report = json.loads((tmp_path / "evaluation.json").read_text())
    assert set(report["rows"]) == {"paper_feasible", "tuned"}
    assert report["feasible"] is True
    assert (tmp_path / "tuning_curve.png").stat().st_size > 0
    assert np.all(np.isfinite(result.history["loss"]))


class _Stop(Exception):
    pass


def test_resume_after_interruption_gives_the_uninterrupted_result(tmp_path):
    whole = tuning.tune(tmp_path / "whole", SMALL, progress=False)

    def interrupt(iteration, loss, gains):
        if iteration == 2:  # iterations 0–2 done; the last checkpoint holds 0–1
            raise _Stop

    with pytest.raises(_Stop):
        tuning.tune(tmp_path / "cut", SMALL, progress=False, callback=interrupt)
    with np.load(tmp_path / "cut" / tuning.CHECKPOINT_NAME) as data:
        assert int(data["iteration"]) == 2
    assert not (tmp_path / "cut" / "tuned_gains.json").exists()

    resumed = tuning.tune(tmp_path / "cut", SMALL, progress=False, resume=True)
    # The same computation on the same inputs, restored bit for bit.
    for key in ("loss", "temperature", "gains"):
        np.testing.assert_array_equal(resumed.history[key], whole.history[key])
    assert (tmp_path / "cut" / "tuned_gains.json").read_text() == (
        tmp_path / "whole" / "tuned_gains.json"
    ).read_text()


def test_resume_refuses_a_checkpoint_of_other_settings(tmp_path):
    def stop_at_once(iteration, loss, gains):
        raise _Stop

    with pytest.raises(_Stop):
        tuning.tune(
            tmp_path, SMALL.replace(checkpoint_every=1), progress=False, callback=stop_at_once
        )
    with pytest.raises(ValueError, match="poses"):
        tuning.tune(tmp_path, SMALL.replace(checkpoint_every=1, poses=9), resume=True)


def test_annealing_the_temperature_does_not_recompile(tmp_path):
    tuning.tune(tmp_path / "a", SMALL, progress=False)
    size = tuning._train_step_jit._cache_size()
    tuning.tune(tmp_path / "b", SMALL.replace(temperature_end=0.02), progress=False)
    assert tuning._train_step_jit._cache_size() == size


def test_float32_robust_gradient_is_finite_and_steps_stay_feasible():
    # The tuner's default precision: the robust gradient must stay finite
    # where a plain float32 mean may overflow.
    with jax.enable_x64(False):
        refs = jnp.concatenate(
            [
                jnp.asarray(list(AWKWARD.values()), jnp.float32),
                tuning.sample_refs(jax.random.key(11), 4),
            ]
        )
        z = jnp.asarray(tuning._logits(tuning.unit_from_gains(MIDDLE)), jnp.float32)
        loss, grad, _ = _robust(z, refs, jnp.float32(1.0))
        assert grad.dtype == jnp.float32
        assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(grad)))
        # A large step in logit space still lands on feasible gains.
        gains = tuning._gains_from_logits(z - 1e3 * jnp.sign(grad), Robot())
        _assert_feasible(jax.tree.map(lambda x: np.asarray(x, np.float64), gains))


def test_random_search_scores_its_start_first():
    refs = tuning.sample_refs(jax.random.key(9), 8)
    # A zero budget still scores one chunk; a chunk of one is the start alone.
    search = tuning.random_search(jax.random.key(0), refs, budget_s=0.0, horizon=1.0, chunk=1)
    assert search.candidates == 1
    _assert_feasible(search.gains)
    start = tuning.gains_from_unit(jnp.asarray(tuning.unit_from_gains(tuning.PAPER_FEASIBLE_GAINS)))
    for name in tuning.GAIN_FIELDS:
        np.testing.assert_allclose(getattr(search.gains, name), getattr(start, name), rtol=1e-12)
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
    ],
)
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        SMALL.replace(**{field: value}).validate()


def test_loss_rejects_bad_input_before_tracing():
    refs = np.zeros((2, 3))
    with pytest.raises(ValueError, match="temperature"):
        tuning.tuning_loss(MIDDLE, refs, temperature=-1.0)
    with pytest.raises(ValueError, match="phi_m"):
        tuning.tuning_loss(MIDDLE.replace(phi_m=2.0), refs, temperature=0.1)
    with pytest.raises(ValueError, match="refs"):
        tuning.tuning_loss(MIDDLE, np.zeros((2, 2)), temperature=0.1)


def _parse(*argv):
    parser = argparse.ArgumentParser()
    tuning.configure_parser(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["--iters", "0"], "--iters"),
        (["--iters", "many"], "--iters"),
        (["--poses", "1.5"], "--poses"),
        (["--seed", "-3"], "--seed"),
        (["--velocity", "warp"], "--velocity"),
    ],
)
def test_bad_flags_give_one_line_errors(tmp_path, argv, flag):
    with pytest.raises(ValueError, match=flag) as info:
        tuning.run_cli(_parse("--out", str(tmp_path), *argv))
    assert "\n" not in str(info.value)
    assert "allowed" in str(info.value)


def test_parser_defaults_are_the_config_defaults(tmp_path):
    args = _parse("--out", str(tmp_path))
    defaults = tuning.TuneConfig()
    assert (args.velocity, int(args.iters), int(args.poses), int(args.seed)) == (
        defaults.velocity,
        defaults.iters,
        defaults.poses,
        defaults.seed,
    )
    assert args.resume is False
