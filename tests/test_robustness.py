"""Robustness Monte Carlo (docs/model.md §7): reproducible draws; undisturbed, the nominal run."""

import functools
import json
import warnings

import jax
import numpy as np
import pytest
from conftest import assert_metrics_of_runs, run_metrics

import wmr_jax as w
from wmr_jax import studies
from wmr_jax.cli import main

DT = 0.033
# One batch shape for every run here: N poses over the docs/model.md §6 horizon
# (182 periods), so that monte_carlo(n_runs=N) and the command reuse the
# programs compiled for the first tests.
N, STEPS = 23, 182


def quiet(refs, steps, *, delay=0.0):
    """A disturbance that disturbs nothing (one-sample latency if ``delay``)."""
    n = len(refs)
    return studies.Disturbance(refs, np.zeros((n, steps, 3)), np.ones((n, 3)), np.float64(delay))


@functools.cache
def _drawn_refs(seed):
    refs, _, _ = studies.draw_disturbances(jax.random.PRNGKey(seed), N, 1)
    refs.setflags(write=False)
    return refs


def draw_refs(seed, n=N):
    """The references of ``draw_disturbances(PRNGKey(seed), n, 1)``, for ``n ≤ N``.

    The first ``n`` of the draw of ``N``: the same values (poses are drawn one
    by one from the key), from programs compiled once for ``N``.
    """
    assert n <= N
    return _drawn_refs(seed)[:n].copy()


@pytest.mark.parametrize("controller", ["shim-sung", "aicardi", "astolfi-corke"])
def test_zero_disturbance_is_the_nominal_run(controller):
    refs = draw_refs(3)
    m = studies.disturbed_metrics(quiet(refs, STEPS), controller=controller)
    traj = w.batch_rollout(refs, steps=STEPS, controller=controller)
    # The same closed loop and the same arithmetic on the pose.
    want = assert_metrics_of_runs(m, traj, refs, DT)
    ok = want["arrived"]
    first = np.where(ok.any(axis=1), (np.argmax(ok, axis=1) + 1) * DT, np.inf)
    np.testing.assert_allclose(m.first_arrival, first, rtol=1e-12)
    assert np.all(m.first_arrival <= m.arrival) and np.isfinite(m.arrival).any()


def test_zero_disturbance_is_the_nominal_run_nonideal():
    refs = draw_refs(4, 4)
    m = studies.disturbed_metrics(quiet(refs, 20), controller="aicardi", velocity="nonideal")
    traj = w.batch_rollout(refs, steps=20, controller="aicardi", velocity="nonideal")
    np.testing.assert_allclose(m.path, np.asarray(w.studies.path_length(traj)), rtol=1e-10)
    final = np.asarray(traj.poses[:, -1, :2])
    np.testing.assert_allclose(m.final_distance, np.hypot(*(final - refs[:, :2]).T), atol=1e-9)


def test_equal_wheel_factors_scale_the_gains():
    # Both rims s times as fast as commanded: for v = k_ρ ρ, ω = k_α α + k_β β
    # that is the same law with every gain times s.
    refs = draw_refs(3)
    s = 1.05
    spec = quiet(refs, STEPS)._replace(mismatch=np.tile([s, s, 1.0], (N, 1)))
    m = studies.disturbed_metrics(spec, controller="astolfi-corke")
    gains = w.controllers.AstolfiGains(k_rho=3.0 * s, k_alpha=8.0 * s, k_beta=-3.0 * s)
    traj = w.batch_rollout(refs, gains, steps=STEPS, controller="astolfi-corke")
    want = run_metrics(traj, refs, DT)
    np.testing.assert_array_equal(m.arrival, want["arrival"])
    np.testing.assert_allclose(m.path, want["path"], rtol=1e-9)


def test_latency_changes_the_run():
    refs = draw_refs(3)
    prompt = studies.disturbed_metrics(quiet(refs, STEPS), controller="aicardi")
    late = studies.disturbed_metrics(quiet(refs, STEPS, delay=1.0), controller="aicardi")
    # One period at rest first: the late runs are not the prompt ones.
    assert np.all(late.path != prompt.path)


def test_same_seed_same_numbers():
    kwargs = dict(n_runs=N, noise_xy=(0.0, 1.0), noise_deg=(0.0, 2.0), radius_mismatch=0.03)
    a = studies.monte_carlo(jax.random.PRNGKey(11), controller="aicardi", latency=True, **kwargs)
    b = studies.monte_carlo(jax.random.PRNGKey(11), controller="aicardi", latency=True, **kwargs)
    c = studies.monte_carlo(jax.random.PRNGKey(12), controller="aicardi", latency=True, **kwargs)
    assert a == b
    assert a != c
    assert [r["noise xy cm"] for r in a] == [0.0, 1.0]
    assert all(0.0 <= r["success"] <= 1.0 and r["runs"] == N for r in a)


def test_draws_are_evaluation_poses_and_bounded_mismatch():
    refs, unit, mismatch = studies.draw_disturbances(
        jax.random.PRNGKey(0), 400, 10, radius_mismatch=0.03, mass_mismatch=0.2
    )
    dist = np.hypot(refs[:, 0], refs[:, 1])
    assert dist.min() >= 5.0 and dist.max() <= 80.0 and unit.shape == (400, 10, 3)
    assert np.abs(refs[:, 2]).max() <= np.pi
    assert np.abs(mismatch[:, :2] - 1).max() <= 0.03 and np.abs(mismatch[:, 2] - 1).max() <= 0.2
    assert abs(unit.mean()) < 0.05 and abs(unit.std() - 1) < 0.05  # 12000 N(0, 1) draws


def test_draws_do_not_depend_on_the_sessions_dtype():
    # The references are drawn in float32, and the noise in their dtype: a
    # float64 session (these tests) draws the numbers a float32 session does.
    args = (jax.random.PRNGKey(0), 4, 5)
    wide = studies.draw_disturbances(*args, radius_mismatch=0.03, mass_mismatch=0.2)
    with jax.enable_x64(False):
        narrow = studies.draw_disturbances(*args, radius_mismatch=0.03, mass_mismatch=0.2)
    for a, b in zip(wide, narrow, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"delay": np.float64(0.5)}, "disturbance.delay = 0.5 is not allowed; allowed: an int"),
        # Many runs' delays are summarised, not printed whole.
        ({"delay": np.full(4, 2.5)}, "disturbance.delay = array of shape (4,) (4 of 4 elements"),
        ({"delay": np.zeros(3)}, "disturbance.delay has shape (3,); allowed: an integer"),
        ({"mismatch": np.zeros((4, 3))}, "disturbance.mismatch = array of shape (4, 3)"),
        ({"noise": np.zeros((4, 10, 2))}, "disturbance.noise has shape (4, 10, 2)"),
        ({"ref": np.zeros((4, 2))}, "disturbance.ref has shape (4, 2)"),
        # A heading noise of 1e15 rad is no angle, and would become NaN.
        ({"noise": np.full((4, 10, 3), 1e15)}, "heading noise <= 1e+12 rad"),
        # A bool or a string is no latency or noise, though NumPy reads them as numbers.
        ({"delay": True}, "disturbance.delay = True is not allowed"),
        ({"noise": np.full((4, 10, 3), "1.0")}, "array of shape (4, 10, 3) and dtype <U3"),
        ({"ref": np.full((4, 3), np.nan)}, "is not finite"),
    ],
)
def test_bad_disturbances_are_rejected(change, message):
    spec = quiet(np.zeros((4, 3)) + [10.0, 0.0, 0.0], 10)._replace(**change)
    with pytest.raises(ValueError, match="allowed") as info:
        studies.disturbed_metrics(spec)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_runs": 0}, "n_runs = 0"),
        ({"noise_xy": (0.0, -1.0), "noise_deg": (0.0, 1.0)}, "noise_xy[1] = -1.0"),
        ({"noise_xy": (0.0,), "noise_deg": (0.0, 1.0)}, "the same number"),
        ({"radius_mismatch": 1.5}, "radius_mismatch = 1.5"),
        ({"noise_xy": [0.0], "noise_deg": [1e300]}, "noise_deg[0] = 1e+300"),
        ({"noise_xy": 0.5, "noise_deg": 1.0}, "noise_xy = 0.5 is not allowed"),
        ({"latency": "no"}, "latency = 'no' is not allowed"),
        # The ideal loop has no mass: a mass mismatch there would change nothing.
        ({"mass_mismatch": 0.2}, "mass_mismatch = 0.2 is not allowed with velocity = 'ideal'"),
        # The runs' own settings, refused before any disturbance is drawn.
        ({"velocity": "foo"}, "velocity = 'foo' is not allowed"),
        ({"x64": "yes"}, "x64 = 'yes' is not allowed"),
        ({"params": w.Gains(kr=-1.0)}, "gains.kr = -1.0 is not allowed"),
        ({"params": "abc"}, "gains is a str; allowed: a Gains"),
        ({"dt": -1.0}, "dt = -1.0 is not allowed"),
        ({"estimator": "kalman"}, "'kalman'"),
    ],
)
def test_bad_monte_carlo_options(kwargs, message, monkeypatch):
    from wmr_jax._src.studies import robustness

    def drawn(*args, **kwargs):
        raise AssertionError("disturbances drawn before the settings were checked")

    monkeypatch.setattr(robustness, "draw_disturbances", drawn)
    with pytest.raises(ValueError, match="allowed") as info:
        studies.monte_carlo(jax.random.PRNGKey(0), **kwargs)
    assert message in str(info.value)


@pytest.mark.parametrize(
    "study",
    [
        lambda refs, gains: studies.standard_conditions({"a": gains}, refs, jax.random.key(0)),
        lambda refs, gains: studies.noise_curve({"a": gains}, refs, jax.random.key(0)),
        lambda refs, gains: studies.evaluate_loop(gains, refs),
    ],
    ids=["standard_conditions", "noise_curve", "evaluate_loop"],
)
def test_the_studies_refuse_a_loops_gains_before_any_draw(study, monkeypatch):
    from wmr_jax._src.studies import conditions

    def drawn(*args, **kwargs):
        raise AssertionError("disturbances drawn before the loops were checked")

    monkeypatch.setattr(conditions, "_unit_draws", drawn)
    refs = np.array([[30.0, 0.0, 0.0], [0.0, 30.0, 1.0]])
    with pytest.raises(ValueError, match=r"gains.kr = -1.0 is not allowed; allowed: kr > 0"):
        study(refs, w.Gains(kr=-1.0))


_REFS = np.array([[30.0, 0.0, 0.0], [0.0, 30.0, 1.0]])


@pytest.mark.parametrize(
    ("study", "message"),
    [
        (lambda: studies.robustness_study(velocity="foo"), "velocity = 'foo' is not allowed"),
        (lambda: studies.robustness_study(n_runs=2**62), "n_runs = 4611686018427387904"),
        (lambda: studies.robustness_study(x64="yes"), "x64 = 'yes' is not allowed"),
        (lambda: studies.robustness_study(estimator="kalman"), "'kalman'"),
        (lambda: studies.evaluate_loop(w.Gains(), _REFS, velocity="foo"), "velocity = 'foo'"),
        (lambda: studies.evaluate_loop(w.Gains(), _REFS, dt=-1.0), "dt = -1.0 is not allowed"),
        (
            lambda: studies.evaluate_loop(w.Gains(), _REFS, identified={"robot": {}}),
            "identified lacks base_robot, wheel_scale, latency_samples, noise; allowed: identify",
        ),
        (
            lambda: studies.standard_conditions({"a": w.Gains()}, _REFS, 7),
            "key = 7 is not allowed; allowed: a jax.random key",
        ),
    ],
)
def test_the_studies_refuse_bad_settings_before_they_make_a_key(study, message, monkeypatch):
    """Nothing is drawn, and no key made, for a study that would be refused."""

    def made(*args, **kwargs):
        raise AssertionError("a key was made or split before the settings were checked")

    for name in ("key", "PRNGKey", "split"):
        monkeypatch.setattr(jax.random, name, made)
    with pytest.raises(ValueError, match="allowed") as info:
        study()
    assert message in str(info.value)


def test_levels_may_be_arrays_and_keys_must_be_keys():
    key = jax.random.key(0)
    rows = studies.monte_carlo(key, n_runs=2, noise_xy=np.array([0.0]), noise_deg=np.array([1.0]))
    assert len(rows) == 1 and rows[0]["noise theta deg"] == 1.0
    with pytest.raises(ValueError, match=r"key = 0 is not allowed; allowed: a jax.random key"):
        studies.monte_carlo(0, n_runs=2)
    refs = w.sample_poses(0, 3)
    for kwargs, message in (
        ({"radius_mismatch": 5.0}, "radius_mismatch = 5.0 is not allowed"),
        ({"latency": 7.0}, "latency = 7.0 is not allowed"),
        ({"noise_xy": -1.0}, "noise_xy = -1.0 is not allowed"),
    ):
        with pytest.raises(ValueError, match=message):
            studies.sample_disturbance(key, refs, 5, **kwargs)
    with pytest.raises(ValueError, match=r"steps = -1 is not allowed"):
        studies.sample_disturbance(key, refs, -1)
    with pytest.raises(ValueError, match=r"radius_mismatch = 2.0 is not allowed"):
        studies.draw_disturbances(key, 2, 5, radius_mismatch=2.0)
    # A level per run must have one value per reference; bools and NaN poses are refused.
    for kwargs, message in (
        ({"noise_xy": np.ones(2)}, r"noise_xy has shape \(2,\); allowed: a scalar .* or \(3,\)"),
        ({"noise_theta": np.ones((3, 1))}, r"noise_theta has shape \(3, 1\)"),
        ({"latency": True}, r"latency = True is not allowed; allowed: a number >= 0 and <= 1"),
    ):
        with pytest.raises(ValueError, match=message):
            studies.sample_disturbance(key, refs, 5, **kwargs)
    shared = studies.sample_disturbance(key, refs, 5, noise_xy=np.array([0.5]))  # (1,): shared
    np.testing.assert_array_equal(
        shared.noise, studies.sample_disturbance(key, refs, 5, noise_xy=0.5).noise
    )
    with pytest.raises(ValueError, match=r"refs\[1\] = \[nan, 0.0, 0.0\] is not finite"):
        studies.sample_disturbance(key, np.array([[10.0, 0, 0], [np.nan, 0, 0]]), 5)
    with pytest.raises(ValueError, match=r"disturbance = tuple is not allowed"):
        studies.disturbed_metrics(tuple(quiet(refs, 5)))


def test_a_mismatch_float32_cannot_hold_is_refused_there():
    spec = quiet(np.array([[10.0, 0.0, 0.0]]), 5)._replace(mismatch=np.full((1, 3), 1e-300))
    with pytest.raises(ValueError, match=r"below float32's smallest normal number"):
        studies.disturbed_metrics(spec, x64=False)


# Each flag with a value it refuses: one line on stderr, exit status 2.
BAD_FLAGS = {
    "--runs": "0",
    "--controller": "nope",
    "--velocity": "warp",
    "--seed": "-1",
    "--robust-gains": "missing.json",
}


@pytest.mark.parametrize("flag", BAD_FLAGS)
def test_command_rejects_bad_values_in_one_line(tmp_path, capsys, flag):
    assert main(["robustness", "--out", str(tmp_path), flag, BAD_FLAGS[flag]]) == 2
    err = capsys.readouterr().err
    # A missing file is said as every command says it; a bad value names what is allowed.
    said = "cannot be read: there is no such file" if flag == "--robust-gains" else "is not "
    assert err.startswith(f"wmr-jax: error: {flag} '{BAD_FLAGS[flag]}' {said}")
    assert "allowed" in err or flag == "--robust-gains"
    assert err.count("\n") == 1


def test_command_writes_what_the_study_returns(tmp_path, capsys):
    out = tmp_path / "rob"
    assert main(["robustness", "--out", str(out), "--runs", str(N), "--controller", "aicardi"]) == 0
    assert "| noise + mismatch + latency | aicardi |" in capsys.readouterr().out
    names = ("robustness.png", "robustness.md", "robustness.json", "standard_conditions.md")
    for name in names:
        assert (out / name).stat().st_size > 100
    saved = json.loads((out / "robustness.json").read_text())
    rows = studies.robustness_study(controller_names=["aicardi"], n_runs=N)
    assert len(rows) == 3 * len(studies.DEFAULT_NOISE_XY) == len(saved["rows"])
    assert [r["success"] for r in saved["rows"]] == [r["success"] for r in rows]
    assert [r["condition"] for r in rows[::5]] == [c[0] for c in studies.ROBUSTNESS_CONDITIONS]
    # The ideal loop has no mass: its rows report the mismatch that was applied.
    assert {r["mass mismatch"] for r in rows} == {0.0}
    assert {r["radius mismatch"] for r in rows} == {0.0, 0.03}
    # The output folder is checked before any computation.
    (tmp_path / "file").write_text("")
    assert main(["robustness", "--out", str(tmp_path / "file"), "--runs", "1"]) == 2


def test_command_runs_every_study_over_the_horizon_given(tmp_path, capsys):
    out = tmp_path / "rob"
    argv = ["robustness", "--out", str(out), "--runs", str(N), "--controller", "aicardi"]
    assert main([*argv, "--horizon", "2", "--noise-curve"]) == 0
    assert "horizon 2 s" in capsys.readouterr().out
    for name in ("robustness.json", "standard_conditions.json", "noise_curve.json"):
        rows = json.loads((out / name).read_text())["rows"]
        assert {round(row["horizon s"], 9) for row in rows} == {round(61 * 0.033, 9)}  # periods
    study = studies.robustness_study(controller_names=["aicardi"], n_runs=N, horizon=2.0)
    saved = json.loads((out / "robustness.json").read_text())["rows"]
    assert [r["success"] for r in saved] == [r["success"] for r in study]
    assert main([*argv, "--horizon", "0"]) == 2
    assert "--horizon '0' is not allowed; allowed: a finite number > 0 s" in capsys.readouterr().err


# ---------------------------------------------------------------- the disturbance model (§7)


def test_sample_disturbance_is_reproducible_from_its_key():
    refs = draw_refs(5)  # N poses over STEPS: the shapes the standard conditions draw
    kwargs = dict(noise_xy=0.5, noise_theta=np.radians(1.0), latency=0.5, radius_mismatch=0.03)
    a = studies.sample_disturbance(jax.random.PRNGKey(1), refs, STEPS, **kwargs)
    b = studies.sample_disturbance(jax.random.PRNGKey(1), refs, STEPS, **kwargs)
    c = studies.sample_disturbance(jax.random.PRNGKey(2), refs, STEPS, **kwargs)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert not np.array_equal(np.asarray(a.noise), np.asarray(c.noise))
    assert set(np.unique(np.asarray(a.delay))) <= {0.0, 1.0}


def test_noise_statistics_match_the_standard_condition():
    sxy, sth = 0.5, np.radians(1.0)
    n, steps = 64, 100  # 6400 draws per component
    d = studies.sample_disturbance(
        jax.random.PRNGKey(7),
        np.tile([30.0, 0.0, 0.0], (n, 1)),
        steps,
        noise_xy=sxy,
        noise_theta=sth,
    )
    noise = np.asarray(d.noise, dtype=float).reshape(-1, 3)
    for column, sigma in zip(noise.T, (sxy, sxy, sth), strict=True):
        k = column.size
        # Within 4 standard errors of 0 and of σ (the std's is σ / √(2k)).
        assert abs(column.mean()) < 4 * sigma / np.sqrt(k)
        assert abs(column.std() - sigma) < 4 * sigma / np.sqrt(2 * k)
    # Independent at every sample: lag-one correlation near zero.
    x = np.asarray(d.noise)[:, :, 0]
    assert abs(np.corrcoef(x[:, 1:].ravel(), x[:, :-1].ravel())[0, 1]) < 4 / np.sqrt(x.size)


@pytest.mark.parametrize("velocity", ["ideal", "nonideal"])
def test_latency_applies_the_previous_samples_command(velocity):
    refs = draw_refs(6, 4)
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.5, (4, 12, 3)) * [1.0, 1.0, 0.02]
    spec = studies.Disturbance(refs, noise, np.ones((4, 3)), np.float64(1.0))
    late = studies.disturbed_rollout(spec, velocity=velocity)
    prompt = studies.disturbed_rollout(spec._replace(delay=np.float64(0.0)), velocity=velocity)
    gains = w.Gains()
    # The first period: no command, the robot stays at rest where it started.
    np.testing.assert_array_equal(late["v"][:, 0], 0.0)
    np.testing.assert_array_equal(late["omega"][:, 0], 0.0)
    np.testing.assert_allclose(late["poses"][:, 1], 0.0, atol=1e-12)
    for i in range(4):
        v0, w0 = w.control(noise[i, 0], refs[i], gains)  # measured at sample 0
        # Without latency it is applied over period 0, with latency over period 1.
        assert prompt["v"][i, 0] == pytest.approx(float(v0), abs=1e-9)
        assert late["v"][i, 1] == pytest.approx(float(v0), abs=1e-9)
        assert late["omega"][i, 1] == pytest.approx(float(w0), abs=1e-9)
        # Period k + 1 applies the command measured at sample k.
        measured = late["poses"][i, 3] + noise[i, 3]
        v3, _ = w.control(measured, refs[i], gains)
        assert late["v"][i, 4] == pytest.approx(float(v3), abs=1e-9)


def test_standard_conditions_compare_gain_sets_on_the_same_draws():
    refs = draw_refs(8)
    sets = {"paper": w.Gains(kr=60.0), "paper again": w.Gains(kr=60.0)}
    rows = studies.standard_conditions(sets, refs, jax.random.PRNGKey(3))
    conditions = ["model robot", *(c[0] for c in studies.STANDARD_CONDITIONS)]
    assert [r["condition"] for r in rows[::2]] == conditions
    # The same gains under the same draws: the same numbers, condition by condition.
    for a, b in zip(rows[::2], rows[1::2], strict=True):
        assert a["success"] == b["success"] and a["gains"] == "paper"
        assert a["mean arrival s"] == b["mean arrival s"] and a["feedback"] == "raw"
    model, nominal = rows[0], rows[2]
    assert model["success"] == 1.0 and model["mean arrival s"] < 6.0
    assert model["mismatch"] == 0.0 and nominal["mismatch"] == studies.STANDARD_MISMATCH
    # The model robot's row is the nominal rollout: no noise, no mismatch.
    steps = w.studies.horizon_steps(w.DEFAULT_DT)
    traj = w.batch_rollout(refs, w.Gains(kr=60.0), steps=steps)
    arrival = np.asarray(w.arrival_time(traj, refs, dt=w.DEFAULT_DT))
    assert model["mean arrival s"] == pytest.approx(arrival[np.isfinite(arrival)].mean(), abs=1e-9)
    # The wheel mismatch moves the nominal condition off the model robot's numbers.
    assert nominal["mean arrival s"] != model["mean arrival s"]
    with pytest.raises(ValueError, match=r"params_by_name = \{\} is not allowed"):
        studies.standard_conditions({}, refs, jax.random.PRNGKey(3))  # no rows at all


def test_a_studys_warning_names_the_loop_it_is_about_once():
    # The Fig. 7 gains exceed the wheel bound; the second set's R_m is too small
    # for the sampled law to settle (k_r π dt / (2 R_m) = 100 π 0.033 / 1 > 2).
    refs = draw_refs(8)
    fast = w.Gains(kr=100.0, r_m=0.5, r_a=0.4, r_e=0.1)
    sets = {"paper": w.Gains(), "fast": fast, "feasible": w.Gains(kr=60.0)}
    for study in (studies.standard_conditions, studies.noise_curve):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            study(sets, refs, jax.random.PRNGKey(3))
        said = sorted((r.category.__name__, str(r.message)) for r in caught)
        assert len(said) == 2, said  # once each, over every condition or noise level
        assert said[0][0] == "SamplingWarning"
        assert said[0][1].startswith("gains 'fast': k_theta*dt = 0.33 and k_r*pi*dt/(2*R_m) = 10.4")
        assert said[1][0] == "WheelSpeedWarning"
        assert said[1][1].startswith("gains 'paper': k_r + L*k_theta = 138.5 cm/s exceeds")
        assert {r.filename for r in caught} == {__file__}  # at the study's caller
    # The Monte Carlo of several controllers names the one whose defaults (Fig. 7) warn.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        studies.robustness_study(controller_names=["aicardi", "shim-sung"], n_runs=N)
    assert [(r.category, r.filename) for r in caught] == [(w.WheelSpeedWarning, __file__)]
    assert str(caught[0].message).startswith("gains 'shim-sung': k_r + L*k_theta = 138.5 cm/s")
    # One loop: nothing to tell apart, the warning as the runs give it.
    with pytest.warns(w.SamplingWarning, match=r"^k_theta\*dt = 0.33 and"):
        studies.standard_conditions({"fast": fast}, refs, jax.random.PRNGKey(3))


def test_only_gain_warnings_are_named_and_an_error_leaves_the_filters_as_they_were():
    from wmr_jax._src.studies.robustness import named_warnings

    said = set()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with named_warnings("a", said):
            warnings.warn("something else", RuntimeWarning, stacklevel=1)
            warnings.warn("too fast", w.SamplingWarning, stacklevel=1)
    assert [(r.category, str(r.message)) for r in caught] == [
        (RuntimeWarning, "something else"),
        (w.SamplingWarning, "gains 'a': too fast"),
    ]
    assert said == {"gains 'a': too fast"}
    filters = list(warnings.filters)
    with warnings.catch_warnings(record=True) as caught:
        with pytest.raises(ValueError, match="a run failed"):
            with named_warnings("a", set()):
                warnings.warn("too fast", w.SamplingWarning, stacklevel=1)
                raise ValueError("a run failed")
    assert warnings.filters == filters and caught == []  # the error, not the warning


def test_standard_conditions_keep_float64_poses_in_a_float32_session():
    refs = draw_refs(8, n=2) + np.array([[1e20, 0.0, 0.0], [0.0, 0.0, 0.0]])  # beyond float32's
    with jax.enable_x64(False):
        rows = studies.standard_conditions({"a": w.Gains(kr=60.0)}, refs, jax.random.PRNGKey(3))
    assert [r["runs"] for r in rows] == [2] * (len(studies.STANDARD_CONDITIONS) + 1)
    assert rows[0]["condition"] == "model robot" and rows[0]["success"] == 0.5
    # The far pose is not reached in 6 s: its distance, 1e20 cm, is in every mean.
    assert all(r["mean final distance cm"] == pytest.approx(5e19) for r in rows)


def test_a_disturbed_run_that_leaves_the_range_is_an_error_not_nans():
    # γ dt = 33: the sampled Aicardi law diverges, past float32 within 300 periods
    # (at γ dt = 3.3 it may wander near 1e15 cm instead, as rounding decides).
    spec = studies.sample_disturbance(jax.random.key(0), np.array([[30.0, 30.0, 0.0]]), 300)
    with pytest.raises(ValueError, match=r"1 run\(s\), e.g. run 0, left the range of float32"):
        studies.disturbed_metrics(
            spec, w.controllers.AicardiGains(gamma=1000.0), controller="aicardi", x64=False
        )
