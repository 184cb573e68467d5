"""The sensed loop (docs/model.md §7, §9): the JAX disturbed loop against the NumPy reference.

The reference (``reference_disturbed_rollout``) is written in angles and
plain floats, independently of the loop's complex arithmetic; it is not
re-exported by ``wmr_jax``, so it is imported from its private module here.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.oracle.reference import reference_disturbed_rollout
from wmr_jax._src.sim.loops import Options
from wmr_jax._src.sim.sensing import loop
from wmr_jax._src.sim.sensing.estimators import EKF, OBSERVER
from wmr_jax._src.studies import conditions, robustness

# One batch shape for every disturbed rollout here, so that each estimator
# compiles one program: N references over the docs/model.md §6 horizon, with
# one latency per run (half of them delayed).
N, STEPS = 6, 182
DELAYS = np.array([0.0, 1.0] * (N // 2))
GAINS = w.Gains(kr=60.0)
# Both implementations do the same float64 arithmetic in a different order
# (angles and atan2 against complex headings, an adjugate against
# np.linalg.inv); measured differences stay below 1e-12 over 182 periods.
# 1e-9 (cm, rad, cm/s, rad/s) is the agreement the project promises.
ATOL = 1e-9

ESTIMATORS = {
    "raw": None,
    "observer": w.studies.ObserverParams(position=0.3, heading=0.4),
    "observer-table": w.studies.ObserverParams(
        position=(0.05, 0.2, 0.5, 0.8), heading=(0.1, 0.3, 0.6, 0.9)
    ),
    "observer-uncompensated": w.studies.ObserverParams(position=0.3, heading=0.4, compensate=False),
    "ekf": w.studies.EKFParams(),
}


@functools.cache
def _draw(seed: int) -> studies.Disturbance:
    """Standard noise (σ_xy 0.5 cm, σ_θ 1°) and ±3 % wheel radii; latency per ``DELAYS``."""
    refs = random_refs(seed, N)
    d = studies.sample_disturbance(
        jax.random.PRNGKey(seed),
        refs,
        STEPS,
        noise_xy=0.5,
        noise_theta=math.radians(1.0),
        radius_mismatch=0.03,
    )
    return studies.Disturbance(refs, np.asarray(d.noise), np.asarray(d.mismatch), DELAYS)


def quiet(seed: int, delay: float) -> studies.Disturbance:
    """The references of ``_draw(seed)``, undisturbed but for every run's latency ``delay``."""
    refs = _draw(seed).ref
    return studies.Disturbance(refs, np.zeros((N, STEPS, 3)), np.ones((N, 3)), np.full(N, delay))


def nominal_poses(seed: int, m: int) -> np.ndarray:
    """The undisturbed runs to ``_draw(seed)``'s references over ``STEPS - m`` periods, poses.

    The first periods of one compiled run over ``STEPS``: a run's poses up
    to a period do not depend on how many periods follow.
    """
    poses = np.asarray(w.batch_rollout(_draw(seed).ref, GAINS, steps=STEPS).poses)
    return poses[:, : STEPS - m + 1]


def reference_runs(spec: studies.Disturbance, estimator) -> list[dict]:
    return [
        reference_disturbed_rollout(
            spec.ref[i],
            GAINS,
            noise=spec.noise[i],
            mismatch=spec.mismatch[i],
            delay=spec.delay[i],
            estimator=estimator,
        )
        for i in range(N)
    ]


# ---------------------------------------------------------------- JAX against the reference


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_disturbed_rollout_matches_the_numpy_reference(name):
    # Noisy, delayed (half the runs) and mismatched runs, raw feedback or an
    # estimator: the same draws given to both implementations.
    spec = _draw(1)
    got = studies.disturbed_rollout(spec, GAINS, estimator=ESTIMATORS[name])
    worst = 0.0
    for i, want in enumerate(reference_runs(spec, ESTIMATORS[name])):
        for field in ("poses", "v", "omega", "estimates"):
            np.testing.assert_allclose(got[field][i], want[field], rtol=0, atol=ATOL)
            worst = max(worst, float(np.abs(got[field][i] - want[field]).max()))
    assert worst < ATOL
    # The runs are disturbed: the applied commands are not the nominal ones.
    nominal = w.reference_rollout(spec.ref[0], GAINS, steps=STEPS)
    assert np.abs(got["v"][0] - nominal["v"]).max() > 1.0


def test_without_disturbance_the_reference_is_the_nominal_reference():
    # An independent check of the reference itself: zero noise, factors 1,
    # no latency is reference_rollout (the rims' round trip v ∓ L ω may
    # round the command by an ulp, hence 1e-12 rather than equality).
    spec = quiet(2, 0.0)
    for estimator in (None, ESTIMATORS["observer"], ESTIMATORS["ekf"]):
        got = reference_disturbed_rollout(
            spec.ref[0], GAINS, noise=spec.noise[0], estimator=estimator
        )
        want = w.reference_rollout(spec.ref[0], GAINS, steps=STEPS)
        np.testing.assert_allclose(got["poses"], want["poses"], rtol=0, atol=1e-12)


# ---------------------------------------------------------------- exact properties


class _Biased(studies.Disturbance):
    """A sensor that reads every position 5 cm too far along x."""

    def measurement(self, pose, noise):
        return studies.Disturbance.measurement(self, pose, noise + jnp.array([5.0, 0.0, 0.0]))


def test_a_subclass_of_disturbance_acts_through_its_own_methods():
    # The runs keep the subclass: raw feedback steers the measured pose onto
    # the reference, so the true pose ends 5 cm short of it along x.
    spec = quiet(2, 0.0)
    target = np.asarray(spec.ref)[:, :2]
    plain = studies.disturbed_rollout(spec, GAINS)["poses"][:, -1, :2]
    biased = studies.disturbed_rollout(_Biased(*spec), GAINS)["poses"][:, -1, :2]
    # Both within the arrival tolerance (1 cm) of where each believes the reference is.
    assert np.hypot(*(plain - target).T).max() < 1.0
    assert np.hypot(*(biased + [5.0, 0.0] - target).T).max() < 1.0


@pytest.mark.parametrize("name", ["observer", "ekf"])
def test_undisturbed_estimate_is_the_true_pose(name):
    # No noise, latency or mismatch: prediction and measurement are the
    # same arc of the same pose, so the correction has nothing to do. 1e-12:
    # the estimate must be the pose at the same sample (a period off is cm).
    got = studies.disturbed_rollout(quiet(2, 0.0), GAINS, estimator=ESTIMATORS[name])
    np.testing.assert_allclose(got["estimates"], got["poses"][:, 1:], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["observer", "ekf"])
def test_compensated_latency_is_the_nominal_run_one_period_late(name):
    # One sample of latency, no noise: the robot rests over period 0, and at
    # each later sample the law sees the estimate rolled over the command in
    # flight, i.e. the pose at which its command will start. So the delayed
    # run's pose after period k + 1 is the nominal run's after period k.
    spec = quiet(2, 1.0)
    got = studies.disturbed_rollout(spec, GAINS, estimator=ESTIMATORS[name])
    nominal = nominal_poses(2, 1)
    np.testing.assert_array_equal(got["poses"][:, 1], got["poses"][:, 0])
    # Same arcs, same law: equal to rounding (1e-12 cm, rad).
    np.testing.assert_allclose(got["poses"][:, 1:], nominal, rtol=0, atol=1e-12)
    # Without compensation the law acts on a stale pose and the run is another.
    stale = studies.disturbed_rollout(spec, GAINS, estimator=ESTIMATORS["observer-uncompensated"])
    assert np.abs(stale["poses"][:, 1:] - nominal).max() > 0.1
    # The reference has the same property (1e-12 as above).
    want = reference_disturbed_rollout(
        spec.ref[0], GAINS, noise=spec.noise[0], delay=1, estimator=ESTIMATORS[name]
    )
    np.testing.assert_allclose(want["poses"][1:], nominal[0], rtol=0, atol=1e-12)


# Latencies of several samples, one per run (0 and 1 among them).
LONG_DELAYS = np.array([2.0, 3.0, 0.0, 1.0, 3.0, 2.0])


@pytest.mark.parametrize("name", ["raw", "observer", "observer-uncompensated", "ekf"])
def test_a_latency_of_several_samples_matches_the_numpy_reference(name):
    # The command of sample k acts from sample k + m; compensated, the law
    # sees the estimate rolled over the m commands in flight, oldest first.
    spec = _draw(1)._replace(delay=LONG_DELAYS)
    got = studies.disturbed_rollout(spec, GAINS, estimator=ESTIMATORS[name])
    for i, want in enumerate(reference_runs(spec, ESTIMATORS[name])):
        for field in ("poses", "v", "omega", "estimates"):
            np.testing.assert_allclose(got[field][i], want[field], rtol=0, atol=ATOL)
    # Zero over the first m periods, then the command computed m samples before.
    for i, m in enumerate(LONG_DELAYS.astype(int)):
        assert np.all(got["v"][i, :m] == 0.0) and np.all(got["omega"][i, :m] == 0.0)
        assert abs(got["v"][i, m]) + abs(got["omega"][i, m]) > 0.0


def test_compensated_latency_of_m_samples_is_the_nominal_run_m_periods_late():
    # As for one sample: the robot rests over m periods, then each command
    # starts at the pose the law was handed, rolled over the m in flight.
    # One latency per run, m = 0 to 3 (the batch of the test above).
    spec = quiet(2, 0.0)._replace(delay=LONG_DELAYS)
    got = studies.disturbed_rollout(spec, GAINS, estimator=ESTIMATORS["ekf"])
    nominal = nominal_poses(2, 0)
    for i, m in enumerate(LONG_DELAYS.astype(int)):
        for k in range(1, m + 1):
            np.testing.assert_array_equal(got["poses"][i, k], got["poses"][i, 0])
        np.testing.assert_allclose(got["poses"][i, m:], nominal[i, : STEPS - m + 1], atol=1e-12)
    assert set(LONG_DELAYS) >= {2.0, 3.0}


def test_compensation_rolls_the_commands_in_flight_through_the_speed_limiter():
    # Under a speed limiter the commands in flight are rolled as the limiter
    # will let them through: the delayed run is the nominal limited one, late.
    heavy, m = w.Robot(accel_max=100.0, angular_accel_max=20.0), 2
    spec = quiet(2, float(m))
    got = studies.disturbed_rollout(spec, GAINS, estimator="observer", robot=heavy)
    nominal = np.asarray(w.batch_rollout(spec.ref, GAINS, steps=STEPS - m, robot=heavy).poses)
    np.testing.assert_allclose(got["poses"][:, m:], nominal, rtol=0, atol=1e-9)
    free = nominal_poses(2, m)
    assert np.abs(free - nominal).max() > 1.0  # the limiter binds


def test_the_reference_takes_a_latency_of_several_samples():
    # Independent of the JAX loop: without noise or an estimator, m samples
    # of latency shift the nominal run's commands by m periods only at the
    # start; a run that rests over m periods and then runs the nominal
    # commands open loop is the reference's first m + 1 poses.
    ref, m = (30.0, 10.0, 0.5), 3
    got = reference_disturbed_rollout(ref, GAINS, noise=np.zeros((20, 3)), delay=m)
    np.testing.assert_array_equal(got["poses"][: m + 1], np.zeros((m + 1, 3)))
    assert np.all(got["v"][:m] == 0.0)
    nominal = w.reference_rollout(ref, GAINS, steps=1)
    assert got["v"][m] == nominal["v"][0] and got["omega"][m] == nominal["omega"][0]


def test_observer_of_gain_one_is_raw_feedback_bit_for_bit():
    # A gain of 1 hands the law the measurement itself (the blend is written
    # as z + (1 − g)(prediction − z)); uncompensated, nothing else changes.
    spec = _draw(1)
    one = w.studies.ObserverParams(position=1.0, heading=1.0, compensate=False)
    got = studies.disturbed_rollout(spec, GAINS, estimator=one)
    raw = studies.disturbed_rollout(spec, GAINS, estimator=None)
    for field in ("poses", "v", "omega", "estimates"):
        np.testing.assert_array_equal(got[field], raw[field])


# ---------------------------------------------------------------- gradients


GRAD_N, GRAD_STEPS = 3, 60  # about 2 s of motion: the robots are still on their way


@functools.partial(jax.jit, static_argnames="options")
def _grad_of_final_distance(estimate, spec, params, init, robot, dt, options):
    def loss(estimate):
        def one(s):
            final, _, _ = loop.disturbed_run(s, params, init, robot, dt, options, estimate=estimate)
            return jnp.sum((final[:2] - s.ref[:2]) ** 2)

        return jnp.sum(jax.vmap(one)(spec))

    return jax.grad(loss)(estimate)


@pytest.mark.parametrize(
    ("estimator", "params"),
    [
        (OBSERVER, w.studies.ObserverParams(position=0.3, heading=0.4)),
        (EKF, w.studies.EKFParams(wheel_error=0.05, sigma_xy=0.5, sigma_theta=0.02)),
    ],
    ids=["observer", "ekf"],
)
def test_gradients_through_noisy_runs_are_finite(estimator, params):
    d = _draw(3)
    spec = studies.Disturbance(
        jnp.asarray(d.ref[:GRAD_N]),
        jnp.asarray(d.noise[:GRAD_N, :GRAD_STEPS]),
        jnp.asarray(d.mismatch[:GRAD_N]),
        jnp.asarray(d.delay[:GRAD_N]),
    )
    options = Options(steps=GRAD_STEPS, estimator=estimator)
    traced = jax.tree.map(jnp.float64, params)
    grads = _grad_of_final_distance(
        traced, spec, GAINS, jnp.zeros(3), w.Robot(), jnp.float64(0.033), options
    )
    values = np.array([float(g) for g in jax.tree.leaves(grads)])
    assert values.size == len(jax.tree.leaves(params)) and np.all(np.isfinite(values))
    # Every parameter changes where noisy runs end.
    assert np.all(values != 0.0), values


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("estimator", "message"),
    [
        ("kalman", "estimator = 'kalman' is not allowed"),
        (w.studies.ObserverParams(position=1.5), "estimator.position = 1.5 is not allowed"),
        (w.studies.ObserverParams(heading=(0.1, 1.2)), "estimator.heading[1] = 1.2 is not allowed"),
        (w.studies.EKFParams(sigma_xy=-1), "estimator.sigma_xy = -1"),
        (w.studies.EKFParams(wheel_error=0.0), "estimator.wheel_error = 0"),
    ],
)
def test_bad_estimators_are_refused_by_both(estimator, message):
    spec = quiet(2, 0.0)
    with pytest.raises(ValueError, match="allowed") as info:
        studies.disturbed_metrics(spec, estimator=estimator)
    assert message in str(info.value)
    with pytest.raises(ValueError, match="allowed") as info:
        reference_disturbed_rollout(spec.ref[0], noise=spec.noise[0], estimator=estimator)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"noise": np.zeros((5, 2))}, "noise has shape (5, 2)"),
        ({"noise": np.full((5, 3), np.nan)}, "noise holds nan"),
        ({"mismatch": (1.0, 0.0)}, "mismatch = [1.0, 0.0] is not allowed"),
        ({"mismatch": (1.0,)}, "mismatch = [1.0] is not allowed"),
        ({"delay": 0.5}, "delay = 0.5 is not allowed"),
        ({"delay": -1}, "delay = -1 is not allowed"),
        ({"delay": True}, "delay = True is not allowed"),
        (
            {"estimator": w.studies.EKFParams(sigma_xy=np.ones(2))},
            "estimator.sigma_xy has shape (2,)",
        ),
        ({"ref": (1.0, 2.0)}, "ref has shape (2,)"),
    ],
)
def test_reference_refuses_bad_input(kwargs, message):
    args = {"ref": (30.0, 0.0, 0.0), "noise": np.zeros((5, 3)), **kwargs}
    with pytest.raises(ValueError, match="allowed") as info:
        reference_disturbed_rollout(args.pop("ref"), **args)
    assert message in str(info.value)


# ---------------------------------------------------------------- the studies and files


def test_every_controller_and_loop_runs_with_an_estimator():
    # The baselines take an estimator as the law does; with no noise, no
    # latency and no mismatch each gives its nominal run in the ideal loop.
    # The batch of tests/test_robustness.py (23 runs over the 182 periods of
    # docs/model.md §6): the baselines' nominal runs are its compiled programs.
    n, steps = 23, 182
    spec = studies.Disturbance(
        random_refs(5, n), np.zeros((n, steps, 3)), np.ones((n, 3)), np.float64(0.0)
    )
    for controller in ("aicardi", "astolfi-corke", "shim-sung-schedule"):
        nominal = studies.disturbed_metrics(spec, controller=controller)
        assert np.isfinite(nominal.arrival).any()  # arrival times are compared, not only infs
        for estimator in ("observer", "ekf"):
            m = studies.disturbed_metrics(spec, controller=controller, estimator=estimator)
            # Equal to float64 rounding (the estimate is the pose to ~1e-13 cm).
            np.testing.assert_allclose(m.final_distance, nominal.final_distance, atol=1e-9)
            np.testing.assert_array_equal(m.arrival, nominal.arrival)
    # The non-ideal robot is not the estimator's model (docs/model.md §9): the
    # estimate trails its pose even without noise, so the run differs from
    # the nominal one, yet every run still arrives.
    refs = random_refs(5, 3)
    spec = studies.Disturbance(refs, np.zeros((3, 90, 3)), np.ones((3, 3)), np.float64(0.0))
    nominal = studies.disturbed_metrics(spec, velocity="nonideal")
    sensed = studies.disturbed_metrics(spec, velocity="nonideal", estimator="ekf")
    assert np.all(np.isfinite(sensed.arrival)) and np.all(np.isfinite(nominal.arrival))
    assert not np.array_equal(sensed.final_distance, nominal.final_distance)


def test_noise_curve_gives_one_row_per_loop_and_level_on_common_draws():
    refs = random_refs(7, 64)  # the draw of the studies' tests below: one compiled raw loop
    loops = {
        "raw": w.Gains(kr=60.0),
        "ekf": studies.ClosedLoop("shim-sung", w.Gains(kr=60.0), "ekf"),
    }
    rows = studies.noise_curve(loops, refs, jax.random.PRNGKey(0), noise_xy=(0.0, 1.0))
    assert [(r["gains"], r["noise xy cm"]) for r in rows] == [
        ("raw", 0.0), ("raw", 1.0), ("ekf", 0.0), ("ekf", 1.0)
    ]  # fmt: skip
    assert [r["feedback"] for r in rows] == ["raw", "raw", "ekf", "ekf"]
    # σ_θ follows σ_xy at 2° per cm (1° with the standard 0.5 cm).
    assert rows[1]["noise theta deg"] == 2.0 and rows[0]["noise theta deg"] == 0.0
    # With the wheel mismatch the filter's estimate is not the measurement even
    # without noise; on the model robot it is, to rounding.
    exact = studies.noise_curve(loops, refs, jax.random.PRNGKey(0), noise_xy=(0.0,), mismatch=0.0)
    assert exact[0]["mean arrival s"] == pytest.approx(exact[1]["mean arrival s"], abs=1e-9)
    assert rows[0]["mean arrival s"] != rows[2]["mean arrival s"]
    # The same draws as standard_conditions' nominal condition at σ = 0.
    table = studies.standard_conditions({"raw": w.Gains(kr=60.0)}, refs, jax.random.PRNGKey(0))
    nominal = next(r for r in table if r["condition"] == "nominal")
    assert nominal["mean arrival s"] == rows[0]["mean arrival s"]


def test_monte_carlo_rows_name_their_feedback():
    rows = studies.monte_carlo(
        jax.random.PRNGKey(1), n_runs=4, noise_xy=(0.5,), noise_deg=(1.0,), estimator="ekf"
    )
    assert rows[0]["feedback"] == "ekf"
    with pytest.raises(ValueError, match="estimator = 'kalman' is not allowed"):
        studies.robustness_study(n_runs=2, estimator="kalman")


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("ekf", "estimator = 'ekf' is not allowed; allowed: null or an object"),
        ({"kind": "kalman"}, "estimator kind = 'kalman' is not allowed"),
        ({"kind": "ekf", "q": 1.0}, "estimator key 'q' is not allowed"),
        ({"kind": "ekf", "sigma_xy": -1.0}, "estimator.sigma_xy"),
        ({"kind": "ekf", "sigma_xy": True}, "estimator sigma_xy = True is not allowed"),
        ({"kind": "observer", "position": [0.5, 2.0]}, r"estimator.position\[1\]"),
        ({"kind": "observer", "compensate": "yes"}, "compensate = 'yes' is not allowed"),
    ],
)
def test_a_saved_estimator_is_checked_by_name(tmp_path, entry, message):
    import json

    path = tmp_path / "tuned_gains.json"
    path.write_text(json.dumps({"controller": "shim-sung", "kind": "fixed", "estimator": entry}))
    with pytest.raises(ValueError, match=message):
        w.load_tuned(path)


def test_a_saved_estimator_reads_back_whole(tmp_path):
    import json

    from wmr_jax import tuning

    for estimator in (
        w.studies.EKFParams(sigma_xy=0.3),
        w.studies.ObserverParams(position=(0.1, 0.5, 0.9)),
    ):
        path = tmp_path / "tuned_gains.json"
        path.write_text(json.dumps(tuning.tuned_json(w.Gains(kr=50.0), estimator)))
        loop = w.load_tuned(path)
        assert loop.estimator == estimator and loop.params.kr == 50.0


def _recorded_noise(monkeypatch, run, module):
    """The noise of every disturbance ``module``'s studies hand to the loop while ``run()`` runs."""
    seen = []
    real = module.disturbed_metrics

    def recording(spec, *args, **kwargs):
        seen.append(np.asarray(spec.noise))
        return real(spec, *args, **kwargs)

    monkeypatch.setattr(module, "disturbed_metrics", recording)
    run()
    return seen


@pytest.mark.parametrize("study", ["standard_conditions", "noise_curve", "evaluate_loop"])
def test_the_studies_draw_the_standard_noise_in_its_units(monkeypatch, study):
    # docs/model.md §7: σ_xy = 0.5 cm and σ_θ = 1° (0.01745 rad). Read as
    # radians, σ_θ would be 57× larger; read as cm, σ_xy the same.
    refs = random_refs(7, 64)
    key = jax.random.PRNGKey(2)
    runs = {
        "standard_conditions": lambda: studies.standard_conditions({"a": GAINS}, refs, key),
        "noise_curve": lambda: studies.noise_curve({"a": GAINS}, refs, key, noise_xy=(0.5,)),
        "evaluate_loop": lambda: studies.evaluate_loop(GAINS, refs, condition="noise"),
    }
    seen = _recorded_noise(monkeypatch, runs[study], conditions)
    noisy = [n for n in seen if np.any(n)]
    assert noisy
    for noise in noisy:  # 64 runs × 182 samples: σ within 2 % at 3 standard errors
        np.testing.assert_allclose(noise[..., :2].std(), 0.5, rtol=0.02)
        np.testing.assert_allclose(noise[..., 2].std(), math.radians(1.0), rtol=0.02)


def test_the_monte_carlo_draws_its_levels_in_their_units(monkeypatch):
    seen = _recorded_noise(
        monkeypatch,
        lambda: studies.monte_carlo(
            jax.random.PRNGKey(1), n_runs=64, noise_xy=(0.5,), noise_deg=(1.0,)
        ),
        robustness,
    )
    (noise,) = seen
    np.testing.assert_allclose(noise[..., :2].std(), 0.5, rtol=0.02)
    np.testing.assert_allclose(noise[..., 2].std(), math.radians(1.0), rtol=0.02)


def test_the_robust_tuner_draws_the_standard_noise_in_its_units():
    # Levels ~ U(0, 2) per run scale both σ alike: their ratio is the standard
    # one, 1° per 0.5 cm, whatever the levels.
    from wmr_jax._src.tuning import robust

    refs = jnp.asarray(random_refs(8, 256))
    joint = robust.joint_problem(robust.RobustConfig())
    batches = robust.sample_conditions(jax.random.PRNGKey(0), refs, refs[:0], 182, 0.1, joint)
    noise = np.asarray(batches[0][0].noise).reshape(4, 256, 182, 3)  # the 4 conditions
    for condition, (label, sxy, sdeg, _) in zip(noise, studies.STANDARD_CONDITIONS, strict=True):
        if sxy == 0:
            assert not np.any(condition), label
            continue
        ratio = condition[..., 2].std() / condition[..., :2].std()
        np.testing.assert_allclose(ratio, math.radians(sdeg) / sxy, rtol=0.05)
        # E[level²] = 4/3 for U(0, 2): σ_xy sqrt(4/3) overall.
        np.testing.assert_allclose(condition[..., :2].std(), sxy * math.sqrt(4 / 3), rtol=0.1)


def test_estimator_parameters_per_run_must_match_the_runs():
    """One value per run, or one for all (an axis of 1 too); another count is one clear error."""
    refs = np.array([[30.0, 20.0, 1.0], [-20.0, 15.0, 3.0]])
    spec = studies.sample_disturbance(jax.random.key(1), refs, 20, noise_xy=0.5, noise_theta=0.02)
    one = studies.disturbed_metrics(spec, estimator=w.studies.EKFParams(wheel_error=0.5))
    same = studies.disturbed_metrics(spec, estimator=w.studies.EKFParams(wheel_error=[0.5]))
    np.testing.assert_array_equal(one.final_distance, same.final_distance)
    each = studies.disturbed_metrics(spec, estimator=w.studies.EKFParams(wheel_error=[0.5, 0.5]))
    np.testing.assert_array_equal(one.final_distance, each.final_distance)
    message = r"batch sizes differ \(disturbance.ref: 2, estimator.position\[1\]: 3\)"
    with pytest.raises(ValueError, match=message):
        studies.disturbed_metrics(
            spec, estimator=w.studies.ObserverParams(position=(0.5, [0.1] * 3))
        )
