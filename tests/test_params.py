"""Bad input is refused before tracing, with the field, its value and what is allowed."""

import logging
import math
import warnings

import jax
import numpy as np
import pytest

import wmr_jax as w

BAD_GAINS = [
    ({"kr": 0.0}, "gains.kr"),
    ({"kr": -5.0}, "gains.kr"),
    ({"k_theta": -1.0}, "gains.k_theta"),
    ({"phi_m": 0.0}, "gains.phi_m"),
    ({"phi_m": math.pi / 2}, "gains.phi_m"),
    ({"alpha": 0.0}, "gains.alpha"),
    ({"alpha": 0.5}, "gains.alpha"),
    ({"r_e": 0.0}, "gains.r_e"),
    ({"r_e": 25.0}, "gains.r_e"),  # r_e > r_a
    ({"r_a": 30.0}, "gains.r_a"),  # r_a > r_m
    ({"kr": float("nan")}, "gains.kr"),
    ({"kr": float("inf")}, "gains.kr"),
    ({"alpha": np.array([0.1, 0.7])}, "gains.alpha"),  # one bad member of a batch
    ({"kr": np.ones((2, 2))}, "gains.kr"),
]


@pytest.mark.parametrize(("change", "field"), BAD_GAINS)
def test_bad_gains_name_the_field(change, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.") + r".*allowed"):
        w.rollout([10.0, 0.0, 0.0], w.Gains(**change), steps=2)


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"ref": [1.0, float("nan"), 0.0]}, r"ref = \[1\.0, nan, 0\.0\] is not finite"),
        ({"ref": [1.0, 2.0]}, r"ref has shape \(2,\); allowed: \(3,\)"),
        ({"ref": [[1.0, 2.0, 3.0]]}, r"ref has shape \(1, 3\)"),
        ({"ref": "abc"}, r"ref = 'abc' is not allowed; allowed: real numbers"),
        ({"init": [0.0, float("inf"), 0.0]}, r"init = .* is not finite"),
        ({"steps": 0}, r"steps = 0 is not allowed; allowed: an integer >= 1"),
        ({"steps": 2.5}, r"steps = 2\.5"),
        ({"dt": 0.0}, r"dt = 0\.0 is not allowed"),
        ({"dt": -0.1}, r"dt = -0\.1"),
        ({"dt": float("nan")}, r"dt = nan"),
        (
            {"velocity": "perfect"},
            r"velocity = 'perfect' is not allowed; allowed: 'ideal', 'nonideal'$",
        ),
        ({"temperature": -1.0}, r"temperature = -1\.0"),
        ({"controller": "pid"}, r"controller = 'pid' is not known"),
    ],
)
def test_bad_rollout_arguments(kwargs, pattern):
    kwargs = {"ref": [10.0, 0.0, 0.0], **kwargs}
    ref = kwargs.pop("ref")
    with pytest.raises(ValueError, match=pattern):
        w.rollout(ref, **kwargs)


def test_bad_batch_arguments():
    with pytest.raises(ValueError, match=r"refs\[1\] = .* is not finite"):
        w.batch_rollout(np.array([[1.0, 2.0, 0.0], [np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="batch sizes differ"):
        w.final_poses(np.zeros((4, 3)), init=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="nothing else is batched"):
        w.final_poses(np.zeros(3))
    with pytest.raises(ValueError, match=r"refs has shape \(0, 3\)"):
        w.final_poses(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="gains is a Robot"):
        w.final_poses(np.ones((2, 3)), w.Robot())


def test_a_tuned_loop_or_another_laws_parameters_say_how_they_run():
    from wmr_jax._src.model.controllers.schedule import ScheduleParams

    loop = w.ClosedLoop(params=w.Gains(kr=60.0), controller="shim-sung")
    with pytest.raises(ValueError) as err:
        w.rollout([30.0, 30.0, 0.0], loop)
    assert str(err.value) == (
        "gains is a ClosedLoop; allowed: a Gains for controller 'shim-sung' (a ClosedLoop runs "
        "as gains=loop.params, controller='shim-sung' and the robot it was tuned for, "
        "robot=loop.robot; with its estimator through wmr_jax.studies.evaluate_loop)"
    )
    schedule = w.get_controller("shim-sung-schedule").default_params()
    assert isinstance(schedule, ScheduleParams)
    with pytest.raises(ValueError, match=r"\(the parameters of 'shim-sung-schedule': pass contr"):
        w.final_poses(np.ones((2, 3)), schedule)
    # The tuning loss has no controller= to pass: it says whose law it tunes.
    with pytest.raises(ValueError) as err:
        w.tuning.tuning_loss(w.controllers.AicardiGains(), np.ones((2, 3)), temperature=None)
    assert str(err.value) == (
        "gains is a AicardiGains; allowed: a Gains or a ScheduleParams (the tuning loss is "
        "Shim–Sung's, fixed or scheduled; docs/custom_controller.md)"
    )


def test_errors_come_before_tracing(caplog):
    """A bad gain is refused before anything is compiled (JAX logs each compile)."""
    steps = 7777  # a length no other test uses: running it would compile
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        with pytest.raises(ValueError, match="gains.alpha"):
            w.rollout([10.0, 0.0, 0.0], w.Gains(alpha=0.9), steps=steps)
    assert not [r for r in caplog.records if "Compiling" in r.getMessage()]
    # The check can fail: the same call with good gains does compile.
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        w.rollout([10.0, 0.0, 0.0], w.Gains(alpha=0.3), steps=steps)
    assert [r for r in caplog.records if "Compiling" in r.getMessage()]


def test_infeasible_gains_warn_but_run():
    with pytest.warns(w.WheelSpeedWarning, match=r"138\.5 cm/s exceeds v_max = 125"):
        w.rollout([10.0, 0.0, 0.0], w.Gains(kr=120.0), steps=2)
    assert w.controllers.check_feasible(w.Gains(kr=60.0))
    assert not w.controllers.check_feasible(w.Gains(kr=120.0))
    bound = w.controllers.wheel_speed_bound(w.Gains(kr=60.0), w.Robot())
    assert float(bound) == pytest.approx(60.0 + 1.85 * 10.0)
    batch = w.controllers.check_feasible(w.Gains(kr=np.array([60.0, 120.0])))
    np.testing.assert_array_equal(batch, [True, False])
    # At the bound, k_r + L k_θ = 106.5 + 1.85 * 10 = 125 (in float32, 125.0000002): allowed.
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("error", w.WheelSpeedWarning)
        w.rollout([10.0, 0.0, 0.0], w.Gains(kr=106.5, k_theta=10.0), steps=2)
        assert w.controllers.check_feasible(w.Gains(kr=106.5, k_theta=10.0))
    assert not w.controllers.check_feasible(w.Gains(kr=106.51, k_theta=10.0))


def test_tracers_skip_validation_inside_user_transforms():
    """Inside a user's jit/grad the values are unknown; the call still works."""

    def loss(kr):
        return w.rollout([20.0, 5.0, 0.0], w.Gains(kr=kr), steps=5).poses[-1, 0]

    assert np.isfinite(float(jax.jit(jax.grad(loss))(60.0)))


def test_batch_sizes_underflow_and_sampling_checks_name_the_field():
    with pytest.raises(ValueError, match=r"batch sizes differ \(gains.kr: 4, gains.k_theta: 5\)"):
        w.controllers.control_diagnostics(
            [0.0, 0.0, 0.0], [30.0, 30.0, 0.0], w.Gains(kr=[10.0, 20, 30, 40], k_theta=[1.0] * 5)
        )
    with pytest.raises(ValueError, match=r"batch sizes differ \(gains.kr: 3, robot.v_max: 2\)"):
        w.controllers.check_feasible(w.Gains(kr=[10.0, 20, 30]), w.Robot(v_max=[100.0, 200]))
    # 1e-46 cm is 0 in float32: refused as such, not found as NaN after the run.
    with jax.enable_x64(False), pytest.raises(ValueError, match=r"gains.r_m = 1e-46 is below"):
        w.control([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], w.Gains(r_m=1e-46, r_a=1e-46, r_e=1e-46))
    for dt in (-1.0, 0, True):
        with pytest.raises(ValueError, match=f"dt = {dt!r} is not allowed"):
            w.controllers.check_sampling(w.Gains(), dt)
    with pytest.raises(ValueError, match="gains.kr = -1.0"):
        w.controllers.check_sampling(w.Gains(kr=-1.0), 0.033)
