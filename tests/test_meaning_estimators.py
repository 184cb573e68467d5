"""What the estimators' numbers mean (docs/model.md §9), each against an independent computation.

Small and fast on purpose: mutation testing (``mutmut``, docs/testing.md)
runs these for every mutant of ``sensing/estimators.py``. The loop is held
against the plain-float NumPy reference (``reference_disturbed_rollout``) on
short runs that come close to their goals, so every knot of a gain table is
crossed, with parameters away from the defaults so that each one matters.
Nothing here runs JAX at import.
"""

import math

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.oracle.reference import reference_disturbed_rollout
from wmr_jax._src.sim.sensing.estimators import (
    EKF,
    OBSERVER,
    OBSERVER_R,
    EKFParams,
    ObserverParams,
    observer_radii,
    resolve_estimator,
    validate_ekf,
    validate_observer,
)

# Close references, so that the runs reach the goal and cross every knot
# (the last knot is at OBSERVER_R = 20 cm) within STEPS periods.
REFS = np.array([[12.0, 5.0, 0.5], [-8.0, 14.0, 2.5], [24.0, -3.0, -1.0], [6.0, -9.0, 3.0]])
STEPS = 60
GAINS = w.Gains(kr=60.0, k_theta=4.0)
ROBOT = w.Robot(half_track=9.0)  # the EKF's process noise reads L
ATOL = 1e-9


def _disturbance(delay: float) -> studies.Disturbance:
    rng = np.random.default_rng(11)
    noise = rng.normal(0.0, 1.0, (len(REFS), STEPS, 3)) * [0.6, 0.6, math.radians(1.5)]
    mismatch = np.column_stack([1.04 - 0.02 * np.arange(4), 0.97 + 0.015 * np.arange(4), [1.0] * 4])
    return studies.Disturbance(REFS, noise, mismatch, np.full(len(REFS), delay))


ESTIMATORS = {
    "observer-constant": ObserverParams(position=0.35, heading=0.6),
    # Tables of different lengths: each is read over its own knots.
    "observer-tables": ObserverParams(
        position=(0.02, 0.3, 0.65, 0.9), heading=(0.9, 0.05, 0.5, 0.2, 0.75)
    ),
    "observer-stale": ObserverParams(position=(0.1, 0.8), heading=0.3, compensate=False),
    "ekf": EKFParams(wheel_error=0.08, sigma_xy=0.9, sigma_theta=0.04),
    "ekf-stale": EKFParams(wheel_error=0.02, sigma_xy=0.3, sigma_theta=0.01, compensate=False),
}


@pytest.mark.parametrize("delay", [0.0, 1.0])
@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_estimated_runs_equal_the_numpy_reference(name, delay):
    spec = _disturbance(delay)
    estimator = ESTIMATORS[name]
    got = studies.disturbed_rollout(spec, GAINS, estimator=estimator, robot=ROBOT)
    for i in range(len(REFS)):
        want = reference_disturbed_rollout(
            REFS[i],
            GAINS,
            noise=spec.noise[i],
            mismatch=spec.mismatch[i],
            delay=int(delay),
            estimator=estimator,
            robot=ROBOT,
        )
        for field in ("poses", "v", "omega", "estimates"):
            np.testing.assert_allclose(got[field][i], want[field], rtol=0, atol=ATOL)
    # The estimate is neither the measurement nor the true pose.
    # (the estimate after period k against the measurement at its end, sample k + 1)
    measured = got["poses"][:, 1:STEPS] + spec.noise[:, 1:]
    assert np.abs(got["estimates"][:, :-1] - measured).max() > 0.05
    assert np.abs(got["estimates"] - got["poses"][:, 1:]).max() > 0.05


def test_the_runs_cross_every_knot():
    # The premise of the comparison above: the estimated distance to the
    # goal passes below the first inner knot and beyond the last.
    got = studies.disturbed_rollout(_disturbance(0.0), GAINS, estimator=ESTIMATORS["ekf"])
    distance = np.hypot(*(got["estimates"][..., :2] - REFS[:, None, :2]).transpose(2, 0, 1))
    assert distance.min() < observer_radii(5)[1] and distance.max() > OBSERVER_R


def test_knots_lie_on_the_documented_squares():
    # docs/model.md §9: knot k of K at OBSERVER_R (k / (K − 1))² cm, 20 cm last.
    assert OBSERVER_R == 20.0
    np.testing.assert_allclose(observer_radii(2), [0.0, 20.0], rtol=0, atol=0)
    np.testing.assert_allclose(observer_radii(5), [0.0, 1.25, 5.0, 11.25, 20.0], rtol=1e-15)


# ---------------------------------------------------------------- which estimator


def test_names_and_parameters_resolve_to_their_estimator():
    assert resolve_estimator(None) == (None, None)
    assert resolve_estimator("observer") == (OBSERVER, ObserverParams())
    assert resolve_estimator("ekf") == (EKF, EKFParams())
    params = EKFParams(sigma_xy=2.0)
    estimator, checked = resolve_estimator(params)
    assert estimator is EKF and checked is params
    estimator, checked = resolve_estimator(ESTIMATORS["observer-tables"])
    assert estimator is OBSERVER and checked is ESTIMATORS["observer-tables"]
    assert OBSERVER.name == "observer" and EKF.name == "ekf"
    assert OBSERVER.default_params() == ObserverParams()


@pytest.mark.parametrize("value", ["kalman", "", 3, w.Gains(), ObserverParams])
def test_anything_else_is_refused_naming_what_is_allowed(value):
    with pytest.raises(ValueError) as err:
        resolve_estimator(value)
    message = str(err.value)
    assert message.startswith("estimator = ") and "is not allowed" in message
    for allowed in ("None (raw feedback)", "'observer' or 'ekf'", "ObserverParams", "EKFParams"):
        assert allowed in message


def test_the_defaults_are_the_documented_ones():
    # docs/model.md §9: tables from 0.05 at the goal to 0.7 beyond ~7 cm;
    # the filter believes ±3 % odometry and the standard noise.
    observer = ObserverParams()
    assert [float(g) for g in observer.position] == [0.05, 0.1, 0.4, 0.7, 0.7, 0.7]
    assert [float(g) for g in observer.heading] == [0.05, 0.1, 0.4, 0.7, 0.7, 0.7]
    assert observer.compensate is True
    ekf = EKFParams()
    assert (ekf.wheel_error, ekf.sigma_xy) == (0.03, 0.5)
    assert ekf.sigma_theta == pytest.approx(math.radians(1.0), rel=1e-15)
    assert ekf.compensate is True


# ---------------------------------------------------------------- checked before tracing


@pytest.mark.parametrize(
    "params, field, allowed",
    [
        (ObserverParams(position=1.0 + 1e-9), "estimator.position", "0 <= g <= 1"),
        (ObserverParams(heading=-1e-9), "estimator.heading", "0 <= g <= 1"),
        (ObserverParams(position=(0.1, math.nan)), "estimator.position[1]", "0 <= g <= 1"),
        (ObserverParams(heading=(0.1, 0.2, 1.5)), "estimator.heading[2]", "0 <= g <= 1"),
        (ObserverParams(position=(0.5,)), "estimator.position has 1 knots", "2 to 50 knots"),
        (ObserverParams(heading=(0.5,) * 51), "estimator.heading has 51 knots", "2 to 50 knots"),
        (ObserverParams(position="0.5"), "estimator.position", "0 <= g <= 1"),
        (ObserverParams(position=None), "estimator.position", "0 <= g <= 1"),
        (ObserverParams(position=True), "estimator.position", "0 <= g <= 1"),
        (ObserverParams(heading=np.full((2, 2), 0.5)), "estimator.heading has shape", "scalar"),
        (ObserverParams(compensate=1), "estimator.compensate", "True or False"),
        (
            ObserverParams(position=np.full(3, 0.5), heading=np.full(4, 0.5)),
            "batch",
            "",
        ),
        (EKFParams(wheel_error=0.0), "estimator.wheel_error", "0 < wheel_error <= 1e6"),
        (EKFParams(sigma_xy=-0.1), "estimator.sigma_xy", "0 < sigma_xy <= 1e6 cm"),
        (EKFParams(sigma_theta=1e6 * (1 + 1e-12)), "estimator.sigma_theta", "<= 1e6 rad"),
        (EKFParams(sigma_xy=math.inf), "estimator.sigma_xy", "0 < sigma_xy"),
        (EKFParams(wheel_error="x"), "estimator.wheel_error", "0 < wheel_error"),
        (EKFParams(compensate="yes"), "estimator.compensate", "True or False"),
        (EKFParams(sigma_xy=np.full(2, 0.5), sigma_theta=np.full(3, 0.01)), "batch", ""),
    ],
)
def test_bad_estimator_parameters_are_refused_naming_the_field(params, field, allowed):
    validate = validate_ekf if isinstance(params, EKFParams) else validate_observer
    with pytest.raises(ValueError) as err:
        validate(params)
    message = str(err.value)
    assert field in message and allowed in message, message
    assert "\n" not in message


def test_refusals_say_what_is_allowed_in_full():
    for params, message in (
        (
            ObserverParams(heading=1 + 2j),
            "estimator.heading = (1+2j) is not allowed; allowed: a gain 0 <= g <= 1",
        ),
        (
            ObserverParams(position=(0.2, 1.5)),
            "estimator.position[1] = 1.5 is not allowed; allowed: a gain 0 <= g <= 1",
        ),
        (
            EKFParams(wheel_error=-1.0),
            "estimator.wheel_error = -1.0 is not allowed; allowed: 0 < wheel_error <= 1e6",
        ),
        (
            EKFParams(sigma_xy=1j),
            "estimator.sigma_xy = 1j is not allowed; allowed: 0 < sigma_xy <= 1e6 cm",
        ),
    ):
        validate = validate_ekf if isinstance(params, EKFParams) else validate_observer
        with pytest.raises(ValueError) as err:
            validate(params)
        assert str(err.value) == message


def test_a_list_of_gains_is_a_table():
    # A list reads as a tuple of knots (as a JSON file gives them).
    params = ObserverParams(position=[0.1, 0.5, 0.9], heading=[1, 0])
    assert isinstance(params.position, tuple) and isinstance(params.heading, tuple)
    assert [float(g) for g in params.position] == [0.1, 0.5, 0.9]
    assert [float(g) for g in params.heading] == [1.0, 0.0]
    assert validate_observer(params) is params


def test_an_array_of_gains_is_one_constant_per_run_not_a_table():
    gains = np.array([0.2, 0.5, 0.7, 0.9])  # as many values as runs: nothing refuses it
    spec = _disturbance(0.0)
    kw = {"init": (0.0, 0.0, 0.0), "robot": ROBOT}
    per_run = studies.disturbed_rollout(spec, GAINS, estimator=ObserverParams(position=gains), **kw)
    for i, g in enumerate(gains):
        alone = studies.disturbed_rollout(spec, GAINS, estimator=ObserverParams(position=g), **kw)
        np.testing.assert_allclose(per_run["poses"][i], alone["poses"][i], atol=ATOL)
    table = studies.disturbed_rollout(
        spec, GAINS, estimator=ObserverParams(position=tuple(gains)), **kw
    )
    assert np.abs(np.asarray(table["poses"]) - np.asarray(per_run["poses"])).max() > 1e-3


def test_each_validator_refuses_the_other_kind():
    with pytest.raises(
        ValueError, match="estimator is a EKFParams; allowed: a wmr_jax.studies.ObserverParams$"
    ):
        validate_observer(EKFParams())
    with pytest.raises(
        ValueError, match="estimator is a ObserverParams; allowed: a wmr_jax.studies.EKFParams$"
    ):
        validate_ekf(ObserverParams())
    with pytest.raises(ValueError, match="^loop.estimator.position"):
        validate_observer(ObserverParams(position=2.0), prefix="loop.estimator")


def test_the_bounds_themselves_are_allowed():
    # Gains 0 (dead reckoning) and 1 (the measurement), 2 and 50 knots, and
    # spreads up to 1e6 are all valid; per-run batches of one size too.
    for params in (
        ObserverParams(position=0.0, heading=1.0),
        ObserverParams(position=1e-310, heading=(1e-310, 0.5)),  # below float64's normal range
        ObserverParams(position=(0.0, 1.0), heading=(1.0,) * 50),
        ObserverParams(position=np.array([0.0, 0.5, 1.0]), heading=np.array([1.0, 0.5, 0.0])),
    ):
        assert validate_observer(params) is params
    for params in (
        EKFParams(wheel_error=1e6, sigma_xy=1e-3, sigma_theta=1e6),
        EKFParams(wheel_error=1e-310),
        EKFParams(sigma_xy=np.full(3, 0.5), sigma_theta=np.full(3, 0.01)),
    ):
        assert validate_ekf(params) is params
