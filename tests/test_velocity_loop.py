"""The non-ideal velocity loop: Eq. 5 dynamics, wheel limits, its limits (docs/model.md §4)."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import dynamics

ROBOTS = {
    "default": w.Robot(),
    "offset+PI": w.Robot(com_offset=0.8, integral_gain=2000.0),
    "weak motors": w.Robot(torque_max=150.0, speed_gain=60.0, com_offset=-1.0),
}


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("wheel_limit", ["clip", "scale"])
def test_nonideal_rollout_matches_reference(name, wheel_limit):
    robot = ROBOTS[name]
    refs = random_refs(17, 3)  # the scalar reference is slow; 3 × 2 gains × 6 cases
    for kr in (60.0, 120.0):
        gains = w.Gains(kr=kr)
        traj = w.batch_rollout(
            refs, gains, robot=robot, velocity="nonideal", wheel_limit=wheel_limit, steps=120
        )
        traj = jax.tree.map(np.asarray, traj)
        for i in range(len(refs)):
            exp = w.reference_rollout(
                refs[i], gains, robot=robot, velocity="nonideal", wheel_limit=wheel_limit, steps=120
            )
            np.testing.assert_array_equal(np.asarray(traj.region[i]), exp["region"])
            # Same float64 arithmetic in another order: differences stay ~1e-13.
            for field in ("poses", "wheel_speeds", "distance", "v", "omega"):
                np.testing.assert_allclose(
                    np.asarray(getattr(traj, field)[i]), exp[field], rtol=0, atol=1e-9
                )


def test_rim_speeds_never_exceed_v_max():
    rng = np.random.default_rng(5)
    n = 800
    refs = random_refs(5, n, r_min=2.0, r_max=120.0)
    inits = np.concatenate([rng.uniform(-30, 30, (n, 2)), rng.uniform(-4, 4, (n, 1))], 1)
    gains = w.Gains(kr=rng.uniform(20.0, 250.0, n), k_theta=rng.uniform(1.0, 40.0, n))
    for wheel_limit in ("clip", "scale"):
        traj = w.batch_rollout(
            refs, gains, init=inits, velocity="nonideal", wheel_limit=wheel_limit, steps=100
        )
        rims = np.abs(np.asarray(traj.wheel_speeds))
        assert rims.max() <= float(w.Robot().v_max) * (1 + 1e-12)
        assert rims.max() > 0.99 * float(w.Robot().v_max)  # the limit is really reached


def test_zero_torque_keeps_velocity_constant():
    # torque_max must be positive; 1e-300 kg·cm²/s² is zero to float64.
    robot = w.Robot(torque_max=1e-300)
    state = dynamics.initial_state(jnp.array([1.0, 2.0, 0.3]))._replace(
        velocity=jnp.array([50.0, 3.0])
    )
    advance = jax.jit(lambda s: dynamics.advance(s, jnp.array([-80.0, 6.0]), robot, 0.033)[0])
    for _ in range(20):
        state = advance(state)
    np.testing.assert_allclose(np.asarray(state.velocity), [50.0, 3.0], rtol=1e-14)


def test_kinetic_energy_conserved_with_offset_under_zero_torque():
    robot = w.Robot(torque_max=1e-300, com_offset=1.0)
    state = dynamics.initial_state(jnp.zeros(3))._replace(velocity=jnp.array([60.0, 5.0]))
    energy0 = float(dynamics.kinetic_energy(state.velocity, robot))
    advance = jax.jit(lambda s: dynamics.advance(s, jnp.zeros(2), robot, 0.033)[0])
    for _ in range(30):
        state = advance(state)
    energy = float(dynamics.kinetic_energy(state.velocity, robot))
    # The offset really moves energy between v and ω ...
    assert abs(float(state.velocity[1])) < 1.0
    # ... and RK4 at h = 3.3 ms keeps the total to ~1e-8 over 1 s.
    assert energy == pytest.approx(energy0, rel=1e-7)


def _stiff(speed_gain, stiffest):
    """A loop with the given stiffness and no limits, and enough sub-steps for RK4.

    The sub-steps suit the ``stiffest`` loop of the series, so that every loop
    of a series runs one compiled program (the number of sub-steps is static).
    """
    with warnings.catch_warnings():  # no wheel limit on purpose: not a unit slip
        warnings.simplefilter("ignore", w.RobotUnitsWarning)
        robot = w.Robot(speed_gain=float(speed_gain), v_max=1e6, torque_max=1e12)
    return robot, max(10, math.ceil(stiffest * 0.033))


def test_one_period_tends_to_the_exact_arc():
    pose = jnp.array([0.0, 0.0, 0.3])
    ideal = dynamics.arc_step(pose, 80.0, -6.0, 0.033)
    errors = []
    for gain in (100, 400, 1600, 6400):  # lags 10 ms down to 0.16 ms
        robot, substeps = _stiff(gain, 6400)
        state = dynamics.initial_state(pose)._replace(velocity=jnp.array([40.0, 2.0]))
        state, _ = dynamics.advance(state, jnp.array([80.0, -6.0]), robot, 0.033, substeps=substeps)
        errors.append(float(jnp.max(jnp.abs(state.pose - ideal))))
    # A first-order lag 1/k: the error falls about 4× per 4× stiffer loop.
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(ratios > 2.5), errors
    assert errors[-1] < 0.01


def test_rollout_tends_to_ideal_as_loop_stiffens(paper_refs):
    # The hard law is discontinuous, so a sampled closed loop amplifies a tiny
    # perturbation into an O(1 cm) change at a region switch; the relaxed law
    # (temperature 0.3) is continuous and shows the convergence itself.
    gains = w.Gains(kr=60.0)
    ideal = np.asarray(w.batch_rollout(paper_refs, gains, steps=91, temperature=0.3).poses)
    errors = []
    for gain in (25, 100, 400, 1600):  # time constants 40 ms down to 0.6 ms
        robot, substeps = _stiff(gain, 1600)
        traj = w.batch_rollout(
            paper_refs,
            gains,
            steps=91,
            temperature=0.3,
            velocity="nonideal",
            robot=robot,
            substeps=substeps,
        )
        errors.append(float(np.abs(np.asarray(traj.poses) - ideal)[..., :2].max()))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(ratios > 2.5), errors
    assert errors[-1] < 0.1  # 0.05 cm measured at 1600/s, 4× less per 4× stiffer


# The horizon of the single non-ideal runs below, which share one compiled program.
SINGLE_STEPS = 50


def test_velocity_state_carries_over_between_samples():
    traj = w.rollout([30.0, 0.0, 0.0], w.Gains(kr=60.0), velocity="nonideal", steps=SINGLE_STEPS)
    # From rest the robot cannot reach the first command within one period.
    v_actual = 0.5 * np.asarray(traj.wheel_speeds).sum(axis=-1)
    assert 0 < v_actual[0] < float(traj.v[0])
    assert v_actual[1] > v_actual[0]


def test_batch_row_equals_single_nonideal():
    # The batch of test_nonideal_rollout_matches_reference[clip-default], its
    # compiled program: a run's first periods do not depend on how many follow.
    refs = random_refs(17, 3)
    batch = w.batch_rollout(
        refs, w.Gains(kr=60.0), robot=ROBOTS["default"], velocity="nonideal", steps=120
    )
    single = w.rollout(refs[1], w.Gains(kr=60.0), velocity="nonideal", steps=SINGLE_STEPS)
    np.testing.assert_allclose(
        np.asarray(batch.poses[1, : SINGLE_STEPS + 1]), np.asarray(single.poses), atol=1e-12
    )


def test_gradients_wrt_robot_parameters_match_differences():
    ref = jnp.array([25.0, 10.0, 0.4])

    def final_x(mass, speed_gain):
        robot = w.Robot(body_mass=mass, speed_gain=speed_gain)
        traj = w.rollout(
            ref, w.Gains(kr=60.0), robot=robot, velocity="nonideal", steps=15, temperature=0.3
        )
        return traj.poses[-1, 0] + 2.0 * traj.poses[-1, 1]

    # One compiled program gives the gradient and the values the differences need.
    value_and_grad = jax.jit(jax.value_and_grad(final_x, argnums=(0, 1)))
    _, grad = value_and_grad(0.5, 100.0)
    for i, (args_plus, args_minus, step) in enumerate(
        [
            ((0.5 + 1e-6, 100.0), (0.5 - 1e-6, 100.0), 1e-6),
            ((0.5, 100.0 + 1e-4), (0.5, 100.0 - 1e-4), 1e-4),
        ]
    ):
        plus, minus = value_and_grad(*args_plus)[0], value_and_grad(*args_minus)[0]
        fd = (float(plus) - float(minus)) / (2 * step)
        # Central differences in float64; torque clipping makes kinks, hence 1e-4.
        assert float(grad[i]) == pytest.approx(fd, rel=1e-4, abs=1e-7)
        assert np.isfinite(float(grad[i]))


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"body_mass": -0.5}, "robot.body_mass"),
        ({"wheel_radius": 0.0}, "robot.wheel_radius"),
        ({"half_track": -1.0}, "robot.half_track"),
        ({"v_max": 0.0}, "robot.v_max"),
        ({"torque_max": -1.0}, "robot.torque_max"),
        ({"wheel_mass": float("nan")}, "robot.wheel_mass"),
        ({"com_offset": 5.0}, "robot.com_offset"),
        ({"integral_gain": -1.0}, "robot.integral_gain"),
    ],
)
def test_bad_robot_parameters_are_rejected(change, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        w.rollout([10.0, 0.0, 0.0], robot=w.Robot(**change), velocity="nonideal", steps=2)


def test_bad_substeps_are_rejected():
    with pytest.raises(ValueError, match="substeps = 0"):
        w.rollout([10.0, 0.0, 0.0], velocity="nonideal", substeps=0)
    with pytest.raises(ValueError, match="substeps = 1 .*speed_gain"):
        w.rollout(
            [10.0, 0.0, 0.0], velocity="nonideal", substeps=1, robot=w.Robot(speed_gain=500.0)
        )
    with pytest.raises(ValueError, match="wheel_limit"):
        w.rollout([10.0, 0.0, 0.0], velocity="nonideal", wheel_limit="squash")
    # The integral gain stiffens the loop too: k_i = 1e6 s⁻² is a 1000 s⁻¹ mode,
    # which needs 1000 * 0.033 / 2.5 = 13.2, so 14 sub-steps.
    with pytest.raises(ValueError, match=r"substeps = 10 .*integral_gain.*substeps >= 14"):
        w.rollout([10.0, 0.0, 0.0], velocity="nonideal", robot=w.Robot(integral_gain=1e6))
    with pytest.raises(ValueError, match=r"allowed: a smaller speed_gain or integral_gain"):
        w.rollout([10.0, 0.0, 0.0], velocity="nonideal", robot=w.Robot(speed_gain=1e30))
