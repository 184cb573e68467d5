"""Baseline controllers: Aicardi et al. (1995) and the Astolfi/Corke polar law."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import run_metrics

import wmr_jax as w
from wmr_jax import controllers as baselines
from wmr_jax.controllers import AICARDI, ASTOLFI, AicardiGains, AstolfiGains

STEPS = 182  # the docs/model.md §6 horizon of 6 s at 33 ms


def grid_refs() -> np.ndarray:
    """References on a polar grid: 3 distances × 8 bearings × 4 headings (docs/model.md §6)."""
    rows = []
    for dist in (10.0, 40.0, 75.0):
        for bearing in np.arange(8) * math.pi / 4 - 3 * math.pi / 4:
            for heading in (-math.pi / 2, 0.0, math.pi / 2, math.pi):
                rows.append([dist * math.cos(bearing), dist * math.sin(bearing), heading])
    return np.array(rows)


def test_registered_by_name():
    assert w.get_controller("aicardi") is AICARDI
    assert w.get_controller("astolfi-corke") is ASTOLFI
    assert AICARDI.default_params() == AicardiGains(gamma=3.0, k=6.0, h=1.0, backward=False)
    assert ASTOLFI.default_params() == AstolfiGains(k_rho=3.0, k_alpha=8.0, k_beta=-3.0)


@pytest.mark.parametrize(
    ("controller", "params"),
    [
        ("aicardi", None),
        ("aicardi", AicardiGains(backward=True)),
        ("astolfi-corke", None),
        ("astolfi-corke", AstolfiGains(backward=False)),
    ],
)
def test_reaches_every_grid_reference_within_the_horizon(controller, params):
    refs = grid_refs()
    traj = w.batch_rollout(refs, params, steps=STEPS, controller=controller)
    times = run_metrics(traj, refs)["arrival"]
    assert np.isfinite(times).all(), refs[~np.isfinite(times)]
    # Both laws stabilise the full heading, not only the folded one.
    final = np.asarray(traj.poses[:, -1])
    heading_error = np.angle(np.exp(1j * (final[:, 2] - refs[:, 2])))
    assert np.abs(heading_error).max() < math.radians(5)


def literal_aicardi(pose, ref, g: AicardiGains):
    """Aicardi et al. in their own goal-frame coordinates (forward driving)."""
    c, s = math.cos(ref[2]), math.sin(ref[2])
    dx, dy = pose[0] - ref[0], pose[1] - ref[1]
    x, y = c * dx + s * dy, -s * dx + c * dy  # robot position in the goal frame
    phi = pose[2] - ref[2]  # robot heading in the goal frame
    e = math.hypot(x, y)
    theta = math.atan2(-y, -x)  # direction of the goal as seen from the robot
    alpha = math.atan2(math.sin(theta - phi), math.cos(theta - phi))
    theta = math.atan2(math.sin(theta), math.cos(theta))
    v = g.gamma * e * math.cos(alpha)
    omega = g.k * alpha + g.gamma * math.cos(alpha) * math.sin(alpha) / alpha * (
        alpha + g.h * theta
    )
    return v, omega


def literal_corke(pose, ref, g: AstolfiGains):
    """Corke's moving-to-a-pose law: goal at the origin, β plus the goal heading."""
    x, y = pose[0] - ref[0], pose[1] - ref[1]
    beta = -math.atan2(-y, -x)
    alpha = -pose[2] - beta
    alpha = math.atan2(math.sin(alpha), math.cos(alpha))
    beta = beta + ref[2]
    beta = math.atan2(math.sin(beta), math.cos(beta))
    return g.k_rho * math.hypot(x, y), g.k_alpha * alpha + g.k_beta * beta


def test_laws_equal_their_published_coordinates():
    # Compiled, as rollouts run them: one program each instead of op by op.
    aicardi_control = jax.jit(baselines.aicardi_control)
    astolfi_control = jax.jit(baselines.astolfi_control)
    rng = np.random.default_rng(7)
    g_a, g_c = AicardiGains(), AstolfiGains(backward=False)
    checked = 0
    for _ in range(200):
        pose = rng.uniform([-50, -50, -math.pi], [50, 50, math.pi])
        ref = rng.uniform([-50, -50, -math.pi], [50, 50, math.pi])
        v_a, w_a = literal_aicardi(pose, ref, g_a)
        v_c, w_c = literal_corke(pose, ref, g_c)
        bearing = math.atan2(ref[1] - pose[1], ref[0] - pose[0]) - pose[2]
        alpha = math.atan2(math.sin(bearing), math.cos(bearing))
        theta_a = alpha - (ref[2] - pose[2])
        # Away from the wraps at ±π, where either side is the law, and from
        # Corke's clipping of α at ±π/2 (not in the literal form above).
        if (
            min(abs(abs(alpha) - math.pi), abs(abs(math.remainder(theta_a, 2 * math.pi)) - math.pi))
            < 1e-3
        ):
            continue
        # Within float64 rounding of a few trigonometric evaluations.
        got = aicardi_control(jnp.asarray(pose), jnp.asarray(ref), g_a)
        np.testing.assert_allclose(np.asarray(got), [v_a, w_a], rtol=1e-9, atol=1e-9)
        if abs(alpha) < math.pi / 2:
            got = astolfi_control(jnp.asarray(pose), jnp.asarray(ref), g_c)
            np.testing.assert_allclose(np.asarray(got), [v_c, w_c], rtol=1e-9, atol=1e-9)
        checked += 1
    assert checked > 150


@pytest.mark.parametrize(
    ("command", "gains"),
    [
        (w.control, w.Gains(kr=np.array([60.0, 70.0, 80.0]))),
        (w.controllers.control_diagnostics, w.Gains(kr=np.array([60.0, 70.0, 80.0]))),
        (baselines.aicardi_control, AicardiGains(gamma=np.array([1.0, 2.0, 3.0]))),
    ],
)
def test_gains_for_another_number_of_poses_are_named(command, gains):
    poses, refs = np.zeros((2, 3)), np.full((2, 3), 10.0)
    with pytest.raises(ValueError, match=r"gains have batch shape \(3,\) and the poses \(2,\)"):
        command(poses, refs, gains)
    one = jax.tree.map(lambda leaf: leaf[:1] if np.ndim(leaf) else leaf, gains)
    assert np.shape(command(poses, refs, one)[0]) == (2,)  # one gain for all poses broadcasts


def test_the_gain_that_does_not_broadcast_is_the_one_named():
    gains = w.Gains(kr=np.array([60.0, 70.0]), r_m=np.array([20.0]))  # (1,) is shared
    with pytest.raises(ValueError, match=r"gains have batch shape \(2,\) and the poses \(3,\)"):
        w.control(np.zeros((3, 3)), np.full(3, 10.0), gains)


@pytest.mark.parametrize(
    ("command", "gains"),
    [
        (baselines.aicardi_control, AicardiGains()),
        (baselines.aicardi_control, AicardiGains(backward=True)),
        (baselines.astolfi_control, AstolfiGains()),
        (baselines.astolfi_control, AstolfiGains(backward=False)),
    ],
)
@pytest.mark.parametrize("heading", [0.0, 0.7, -2.5, math.pi])
def test_finite_values_and_gradients_at_rho_zero(command, gains, heading):
    pose = jnp.array([12.0, -3.0, 0.4])
    ref = pose.at[2].set(heading)

    def total(pose, ref, gains):
        v, omega = command(pose, ref, gains)
        return v + omega

    v, omega = command(pose, ref, gains)
    assert float(v) == 0.0 and np.isfinite(float(omega))
    grads = jax.grad(total, argnums=(0, 1, 2))(pose, ref, gains)
    for leaf in jax.tree.leaves(grads):
        assert np.isfinite(np.asarray(leaf)).all()


# The single runs' horizon (3 s): the tests below share their compiled programs.
SINGLE_STEPS = 90


def test_rollout_started_on_the_reference_stays_finite():
    for controller in ("aicardi", "astolfi-corke"):
        traj = w.rollout(
            [5.0, 5.0, 1.0], init=[5.0, 5.0, 1.0], steps=SINGLE_STEPS, controller=controller
        )
        assert np.isfinite(np.asarray(traj.poses)).all()


def test_backward_flag_picks_the_driving_direction():
    behind = np.array([-40.0, 5.0, 0.0])  # in the rear half-plane of (0, 0, 0)
    steps = SINGLE_STEPS
    runs = {
        "aicardi fwd": w.rollout(behind, AicardiGains(), steps=steps, controller="aicardi"),
        "aicardi bwd": w.rollout(
            behind, AicardiGains(backward=True), steps=steps, controller="aicardi"
        ),
        "corke fwd": w.rollout(
            behind, AstolfiGains(backward=False), steps=steps, controller=ASTOLFI
        ),
        "corke bwd": w.rollout(behind, AstolfiGains(), steps=steps, controller=ASTOLFI),
    }
    travelled = {k: float(np.sum(np.asarray(t.v)) * 0.033) for k, t in runs.items()}
    # Net signed distance: forwards turns round and drives ahead, backwards reverses.
    assert travelled["aicardi fwd"] > 0 and travelled["corke fwd"] > 0
    assert travelled["aicardi bwd"] < -30 and travelled["corke bwd"] < -30
    assert float(runs["corke fwd"].v.min()) >= 0.0


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (AicardiGains(gamma=0.0), "gains.gamma = 0.0"),
        (AicardiGains(k=-1.0), "gains.k = -1.0"),
        (AicardiGains(h=float("nan")), "gains.h = nan"),
        (AicardiGains(backward=1), "gains.backward = 1"),
        (AstolfiGains(k_rho=-3.0), "gains.k_rho = -3.0"),
        (AstolfiGains(k_beta=1.0), "gains.k_beta = 1.0"),
        (AstolfiGains(k_alpha=2.0), "gains.k_alpha = 2.0"),
        (
            AstolfiGains(k_alpha=np.array([9.0, 1.0])),
            "gains.k_alpha = array of shape (2,) (element [1] = 1.0)",
        ),
    ],
)
def test_bad_gains_are_rejected_before_tracing(params, message):
    controller = "aicardi" if isinstance(params, AicardiGains) else "astolfi-corke"
    with pytest.raises(ValueError, match="allowed") as info:
        w.rollout([10.0, 0.0, 0.0], params, steps=5, controller=controller)
    assert message in str(info.value)


def test_wrong_params_type_and_temperature_are_rejected():
    with pytest.raises(ValueError, match="AicardiGains"):
        w.rollout([10.0, 0.0, 0.0], AstolfiGains(), steps=5, controller="aicardi")
    with pytest.raises(ValueError, match="temperature"):
        w.rollout([10.0, 0.0, 0.0], steps=5, controller="aicardi", temperature=0.1)


def test_batched_gains():
    refs = grid_refs()[:6]
    gains = AstolfiGains(k_rho=np.full(6, 3.0), k_alpha=np.full(6, 8.0), k_beta=np.full(6, -3.0))
    batched = w.final_poses(refs, gains, steps=40, controller="astolfi-corke")
    shared = w.final_poses(refs, steps=40, controller="astolfi-corke")
    # The same program up to the batching of the gains: equal to rounding.
    np.testing.assert_allclose(np.asarray(batched), np.asarray(shared), rtol=0, atol=1e-10)


def test_a_new_controller_needs_no_special_case():
    """A user's controller runs through every entry point by declaring what it supports."""

    def proportional(pose, ref, params, *, temperature=None, frame=None):
        err = w.controllers.polar_error(pose, ref, frame=frame)
        return 3.0 * err.r * err.cos_phi, 4.0 * err.sin_phi

    custom = w.Controller(
        name="test-proportional",
        command=proportional,
        params_type=w.Gains,
        validate=lambda gains: gains,
    )
    refs = np.array([[20.0, 5.0, 0.0], [-10.0, 15.0, 1.0]])
    traj = w.batch_rollout(refs, controller=custom, steps=150)
    assert np.all(np.asarray(traj.region) == -1)  # it declared no regions
    final = np.asarray(w.final_poses(refs, controller=custom, steps=150))
    np.testing.assert_allclose(final, np.asarray(traj.poses[:, -1]), atol=1e-9)
    assert np.hypot(*(final[:, :2] - refs[:, :2]).T).max() < 0.1  # it drove there
    with pytest.raises(ValueError, match="temperature"):
        w.rollout(refs[0], controller=custom, temperature=0.1)
    w.register_controller(custom)
    assert "test-proportional" in w.controllers.registered_names()
    assert w.get_controller("test-proportional") is custom
    # A built-in name is not taken over by accident, and a name must be a CLI word.
    with pytest.raises(ValueError, match="'shim-sung' is registered already"):
        w.register_controller(dataclasses.replace(custom, name="shim-sung"))
    assert w.get_controller("shim-sung") is w.controllers.SHIM_SUNG
    for bad in ("../evil", 7, "Two Words"):
        with pytest.raises(ValueError, match=r"controller.name = .* is not allowed"):
            w.register_controller(dataclasses.replace(custom, name=bad))
    with pytest.raises(ValueError, match=r"controller.command = 42 is not allowed"):
        w.register_controller(dataclasses.replace(custom, name="test-bad", command=42))
    with pytest.raises(ValueError, match="allowed: a wmr_jax.Controller"):
        w.register_controller(lambda pose, ref, params: (0.0, 0.0))
    # Flags are True or False: "no" is a non-empty string, which Python reads as true.
    with pytest.raises(ValueError, match="replace = 'no' is not allowed; allowed: True or False"):
        w.register_controller(dataclasses.replace(custom, name="shim-sung"), replace="no")
    with pytest.raises(ValueError, match="controller.smooth = 'no' is not allowed"):
        dataclasses.replace(custom, smooth="no")
    # Checked where it is built, registered or not (they failed at the first rollout).
    for changes, message in (
        ({"validate": None}, r"controller.validate = None is not allowed; allowed: a function "
         r"validate\(params\) -> params"),
        ({"region": 5}, r"controller.region = 5 is not allowed; allowed: a function, or None"),
        ({"region": np.zeros((2, 2))}, r"controller.region = array\(\[\[0., 0.\], \[0., 0.\]\]\)"),
        ({"params_type": w.Gains()}, r"controller.params_type = Gains\(.* allowed: a class"),
        ({"name": None}, r"^controller.name = None is not allowed; allowed: a non-empty str"),
        ({"name": " "}, r"^controller.name = ' ' is not allowed"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=message):
            dataclasses.replace(custom, **changes)
    assert dataclasses.replace(custom, region=None, check_robot=None).region is None
    # Its validate lets anything through; a bool or a string is still no gain (NumPy
    # would run them as 1.0 and 3.0).
    flag = (jnp.array(True), r"Array\(True, dtype=bool\)")  # on the device: its dtype says
    for bad, shown in ((True, "True"), ("3", "'3'"), flag):
        with pytest.raises(ValueError, match=rf"controller 'test-proportional': params.kr = "
                           rf"{shown} is not allowed; allowed: real numbers"):  # fmt: skip
            w.rollout(refs[0], w.Gains(kr=bad), controller=custom, steps=3)
    with pytest.raises(ValueError, match="backward = 'no' is not allowed"):
        baselines.driving_error(np.zeros(3), refs[0], backward="no")
    with pytest.raises(ValueError, match="warn = 'no' is not allowed"):
        w.controllers.check_feasible(w.Gains(kr=200.0), warn="no")


@pytest.mark.parametrize("law", ["aicardi_control", "astolfi_control"])
def test_the_baselines_refuse_a_temperature_they_would_ignore(law):
    from wmr_jax import controllers

    params = (
        w.controllers.AicardiGains() if law == "aicardi_control" else w.controllers.AstolfiGains()
    )
    with pytest.raises(ValueError, match="temperature = 0.5 is not allowed; allowed: None"):
        getattr(controllers, law)(
            jnp.zeros(3), jnp.array([30.0, 30.0, 0.0]), params, temperature=0.5
        )
