"""Property-based fuzzing of robots, estimators and ``evaluate``, with an oracle.

``tests/test_fuzz.py`` asks that every call return finite values or a named
error. Here each generated input is valid or invalid *by construction*, so
each call is judged four ways: a valid input must give the right result
(``correct``), an invalid one a one-line ``ValueError`` naming the field and
the value (``clear``); an invalid input that returns is ``silent``, and any
other exception a ``crash``. Both of the last two fail the test. The
estimator and evaluation calls keep their shapes and static options fixed,
so most valid calls reuse one compiled program. The suite judges 2,400
calls; each test has a ``slow`` copy with ten times its examples
(``pytest -m slow``), 24,000 calls in all.
"""

import collections
import json
import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_fuzz import fuzz_settings

import wmr_jax as w
from wmr_jax import studies
from wmr_jax._src.model.robots import ROBOT_FIELDS

# Examples per test in the suite (the ``slow`` copies run ten times as many).
ROBOT_FILES = 1000
ROS_FILES = 300
ESTIMATORS = 600
EVALUATIONS = 500
SLOW = 10

# What a user may write where a number belongs but none is allowed.
NOT_A_NUMBER = st.sampled_from(
    [None, "abc", "1.5", [1.0, 2.0], {"a": 1}, True, False, math.nan, math.inf, -math.inf]
)
# In range for every positive robot field (so a good value is good for each).
GOOD_POSITIVE = st.floats(min_value=0.5, max_value=40.0)
BAD_POSITIVE = st.one_of(NOT_A_NUMBER, st.floats(max_value=0.0, allow_nan=False), st.just(0))
_FREE = {"com_offset"}  # any sign; bounded by the body instead
# 0: none (no integral action, no acceleration limit; docs/model.md §4).
_NON_NEGATIVE = {"integral_gain", "accel_max", "angular_accel_max"}


def _normal(value):
    """Subnormal floats are refused as unrepresentable: keep the good values normal."""
    return value == 0 or abs(value) > 1e-6


# How each call was judged, per test: "valid" inputs answered (checked by the
# caller), "invalid" ones refused with a clear error.
TALLY = collections.Counter()


def _expect(call, valid, names):
    """Judge one call: a valid input's result, or ``"clear"``; fail on ``silent`` or ``crash``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # legal but warned settings are fine here
        try:
            result = call()
        except ValueError as err:
            message = str(err)
            assert not valid, f"a valid input was refused: {message}"
            assert "\n" not in message.strip(), message
            assert any(name in message for name in names), (names, message)
            TALLY["invalid, clear error"] += 1
            return "clear"
    assert valid, f"silent: an invalid input returned {result!r:.200}"
    TALLY["valid, answered"] += 1
    return result


def fuzz_pair(examples, **strategies):
    """A test of ``examples`` generated calls, and its ``slow`` copy with ``SLOW`` times more."""

    def make(body):
        fast = fuzz_settings(examples)(given(**strategies)(body))
        slow = fuzz_settings(SLOW * examples)(given(**strategies)(body))
        return fast, pytest.mark.slow(slow)

    return make


_FOLDER: Path | None = None  # the module's folder for the files it writes (``_folder``)


@pytest.fixture(scope="module", autouse=True)
def _folder(tmp_path_factory):
    """A folder of pytest's, which it removes with its old runs' (not one per import)."""
    global _FOLDER
    _FOLDER = tmp_path_factory.mktemp("fuzz-files")


def _robot_fields():
    good = st.fixed_dictionaries(
        {},
        optional={
            name: (
                # Inside any generated body (a diameter of 0.5 cm or more).
                st.floats(min_value=-0.2, max_value=0.2).filter(_normal)
                if name in _FREE
                else st.floats(min_value=0.0, max_value=5.0).filter(_normal)
                if name in _NON_NEGATIVE
                else GOOD_POSITIVE
            )
            for name in ROBOT_FIELDS
        },
    )
    return good


def _robot_json_file(fields, bad_field, bad_value, spoil):
    content = dict(fields)
    valid = spoil == "none"
    names = [str(_FOLDER)]
    if spoil == "value":
        if (
            bad_field in _FREE
            and isinstance(bad_value, (int, float))
            and not isinstance(bad_value, bool)
        ):
            bad_value = math.nan if math.isfinite(bad_value) else bad_value
        if bad_field in _NON_NEGATIVE and bad_value == 0:
            bad_value = -1.0
        content[bad_field] = bad_value
        names = [bad_field or "''", "key"]
    path = _FOLDER / "robot.json"
    if spoil == "top-level":
        path.write_text(json.dumps([content]))
    elif spoil == "text":
        path.write_text(json.dumps(content)[:-1])  # cut short
    else:
        path.write_text(json.dumps(content))
    robot = _expect(lambda: w.load_robot(str(path)), valid, names)
    if valid:
        for name in ROBOT_FIELDS:
            want = content.get(name, getattr(w.Robot(), name))
            assert float(getattr(robot, name)) == pytest.approx(want, rel=1e-12, abs=0), name


test_robot_json_files, test_robot_json_files_slow = fuzz_pair(
    ROBOT_FILES,
    fields=_robot_fields(),
    bad_field=st.sampled_from([*ROBOT_FIELDS, "wheel_base", "V_max", ""]),
    bad_value=BAD_POSITIVE,
    spoil=st.sampled_from(["none", "value", "top-level", "text"]),
)(_robot_json_file)


def _robot_ros_file(separation, radius, speed):
    def good(value, low, high):
        return isinstance(value, float) and not isinstance(value, bool) and low <= value <= high

    # A speed limit of .nan is "no limit" (ros2_controllers), a size of .nan is refused.
    no_limit = isinstance(speed, float) and math.isnan(speed)
    valid = good(separation, 0.05, 1.0) and good(radius, 0.01, 0.3)
    valid = valid and (no_limit or good(speed, 0.05, 3.0))
    block = {"wheel_separation": separation, "wheel_radius": radius}
    block["linear"] = {"x": {"max_velocity": speed}}
    import yaml

    path = _FOLDER / "robot.yaml"
    path.write_text(yaml.safe_dump({"diff_drive": {"ros__parameters": block}}))
    names = ["wheel_separation", "wheel_radius", "max_velocity"]
    robot = _expect(lambda: w.load_robot(str(path)), valid, names)
    if valid:
        assert float(robot.half_track) == pytest.approx(100 * separation / 2, rel=1e-12)
        assert float(robot.wheel_radius) == pytest.approx(100 * radius, rel=1e-12)


test_robot_ros_files, test_robot_ros_files_slow = fuzz_pair(
    ROS_FILES,
    separation=st.one_of(st.floats(min_value=0.05, max_value=1.0), BAD_POSITIVE),
    radius=st.one_of(st.floats(min_value=0.01, max_value=0.3), BAD_POSITIVE),
    speed=st.one_of(st.floats(min_value=0.05, max_value=3.0), BAD_POSITIVE),
)(_robot_ros_file)


_REFS = np.array([[30.0, 20.0, 1.0], [-20.0, 15.0, 3.0]])
_DISTURBANCE = None


def _disturbance():
    global _DISTURBANCE
    if _DISTURBANCE is None:
        import jax

        _DISTURBANCE = studies.sample_disturbance(
            jax.random.key(1), _REFS, 20, noise_xy=0.5, noise_theta=0.02
        )
    return _DISTURBANCE


def _is_zero(value):
    return isinstance(value, float) and value == 0.0


def _estimator_parameters(kind, field, good, bad, use_bad):
    ekf_fields = ("wheel_error", "sigma_xy", "sigma_theta")
    if (kind == "ekf") != (field in ekf_fields):
        field = ekf_fields[0] if kind == "ekf" else "position"
    value = bad if use_bad else good
    # 2.5 is a fine EKF spread but no observer gain (0 <= g <= 1); an observer's
    # list is a table of gains over the distance (3 knots), an EKF's one per run.
    valid = not use_bad or (kind == "ekf" and bad == 2.5)
    # A gain of 0 is an observer that ignores the measurement: allowed.
    valid = valid or (kind == "observer" and (bad == [0.5, 0.5, 0.5] or _is_zero(bad)))
    params = (w.studies.EKFParams if kind == "ekf" else w.studies.ObserverParams)(**{field: value})
    result = _expect(
        lambda: studies.disturbed_metrics(_disturbance(), estimator=params),
        valid,
        [f"estimator.{field}", "batch size"],
    )
    if valid:
        assert np.all((np.asarray(result.success) >= 0) & (np.asarray(result.success) <= 1))
        assert np.all(np.isfinite(np.asarray(result.final_distance)))


test_estimator_parameters, test_estimator_parameters_slow = fuzz_pair(
    ESTIMATORS,
    kind=st.sampled_from(["ekf", "observer"]),
    field=st.sampled_from(["wheel_error", "sigma_xy", "sigma_theta", "position", "heading"]),
    good=st.floats(min_value=0.01, max_value=1.0),
    # An EKF's list is one value per run (two runs here): three values are not.
    bad=st.one_of(
        NOT_A_NUMBER.filter(lambda v: not isinstance(v, list)),
        st.just([0.5, 0.5, 0.5]),
        st.floats(max_value=0.0, allow_nan=False),
        st.just(2.5),
    ),
    use_bad=st.booleans(),
)(_estimator_parameters)


_LOOP = None


def _loop():
    global _LOOP
    if _LOOP is None:
        _LOOP = w.ClosedLoop("shim-sung", w.Gains(kr=60.0, k_theta=4.0), "ekf")
    return _LOOP


def _evaluate(condition, mismatch, seed, ref_value):
    refs = _REFS.copy().tolist()
    refs[0][0] = ref_value
    number = isinstance(mismatch, (int, float)) and not isinstance(mismatch, bool)
    good_mismatch = number and 0 <= mismatch < 1
    good_seed = isinstance(seed, int) and seed >= 0
    good_ref = isinstance(ref_value, float) and math.isfinite(ref_value)
    valid = condition in ("nominal", "noise") and good_mismatch and good_seed and good_ref
    result = _expect(
        lambda: studies.evaluate_loop(
            _loop(), refs, condition=condition, mismatch=mismatch, seed=seed, horizon=0.66
        ),
        valid,
        ["condition", "mismatch", "seed", "refs"],
    )
    if valid:
        assert 0.0 <= result["success"] <= 1.0


test_evaluate, test_evaluate_slow = fuzz_pair(
    EVALUATIONS,
    condition=st.one_of(
        st.sampled_from(["nominal", "noise"]), st.sampled_from(["noisy", "", 3, None])
    ),
    mismatch=st.one_of(st.sampled_from([0.0, 0.03]), BAD_POSITIVE, st.just(1.5)),
    seed=st.one_of(st.integers(min_value=0, max_value=2**31), st.sampled_from([-1, "0", 1.5])),
    ref_value=st.one_of(st.floats(min_value=-60, max_value=60), NOT_A_NUMBER),
)(_evaluate)


def test_every_generated_call_was_judged():
    """The tests above ran (in this order, in one process) and judged every call they made.

    ``WMR_FUZZ_TALLY=FILE`` writes the tally as JSON (silent and crashing
    calls fail their test instead of being counted).
    """
    if os.environ.get("WMR_FUZZ_TALLY"):
        Path(os.environ["WMR_FUZZ_TALLY"]).write_text(json.dumps(dict(TALLY), indent=1))
    if sum(TALLY.values()) == 0:
        pytest.skip("run with the rest of this file")
    # Hypothesis may run an example twice (shrinking, replay): at least one call per example.
    assert sum(TALLY.values()) >= ROBOT_FILES + ROS_FILES + ESTIMATORS + EVALUATIONS, TALLY
    assert TALLY["invalid, clear error"] > 500 and TALLY["valid, answered"] > 500, TALLY
