"""The law's Jacobian derivative (``Options.law_derivative``): same values, same derivatives."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_refs

import wmr_jax as w
from wmr_jax import studies, tuning
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.sensing import loop
from wmr_jax._src.sim.sensing.estimators import ESTIMATORS

STEPS = 40
N = 4
ESTIMATES = {None: None, "ekf": studies.EKFParams()}


def _runs(derivative: str, estimator: str | None, temperature: float | None):
    """``(gains, estimate, refs) -> final poses (N, 3)`` of N noisy runs with latency, float64."""
    refs = random_refs(3, N)
    spec = studies.sample_disturbance(
        jax.random.key(3), refs, STEPS, noise_xy=0.5, noise_theta=math.radians(1.0),
        radius_mismatch=0.03,
    )  # fmt: skip
    spec = studies.Disturbance(spec.ref, spec.noise, spec.mismatch, jnp.asarray([0, 1, 2, 1.0]))
    options = loops.Options(
        steps=STEPS,
        temperature=temperature,
        estimator=None if estimator is None else ESTIMATORS[estimator],
        max_delay=2,
        law_derivative=derivative,
    )
    robot, dt, init = w.Robot(), jnp.asarray(w.DEFAULT_DT), jnp.zeros(3)

    def final(gains, estimate, refs=spec.ref):
        def one(s):
            return loop.disturbed_run(s, gains, init, robot, dt, options, estimate=estimate)[0]

        return jax.vmap(one)(spec._replace(ref=refs))

    return final


def _summed(final):
    return lambda gains, estimate, refs: jnp.sum(final(gains, estimate, refs) ** 2)


# The relaxed law through the EKF (what the rule is for), and the hard law on raw feedback.
@pytest.mark.parametrize(("estimator", "temperature"), [("ekf", 0.05), (None, None)])
def test_the_jacobian_derivative_moves_no_value_and_equals_the_traced_one(estimator, temperature):
    gains, estimate = w.Gains(kr=70.0, k_theta=12.0), ESTIMATES[estimator]
    refs = jnp.asarray(random_refs(3, N))
    got, finals = {}, {}
    for derivative in loops.LAW_DERIVATIVES:
        final = _runs(derivative, estimator, temperature)
        # The Jacobian's rule is in the program only when asked for.
        program = str(jax.make_jaxpr(final)(gains, estimate))
        assert ("name=jacobian_command" in program) == (derivative == "jacobian")
        if estimator is not None:
            finals[derivative] = jax.jit(final)(gains, estimate)
        loss = jax.value_and_grad(_summed(final), (0, 1, 2))
        got[derivative] = jax.jit(loss)(gains, estimate, refs)
    if finals:  # run alone, the runs are the same computation: equal to the bit
        np.testing.assert_array_equal(finals["jacobian"], finals["traced"])
    (value_t, grad_t), (value_j, grad_j) = got["traced"], got["jacobian"]
    assert float(value_j) == pytest.approx(float(value_t), rel=1e-14)
    # The derivative in the gains, the filter's parameters and the references, to rounding.
    for a, b in zip(jax.tree.leaves(grad_t), jax.tree.leaves(grad_j), strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * abs(float(value_t)))
    assert any(float(jnp.abs(g)) > 0 for g in jax.tree.leaves(grad_t))  # the check bites
    if estimator is not None:
        # Forward mode runs through it too: along the gains, the gradient's projection.
        direction = w.Gains(kr=1.0, k_theta=-0.5)
        loss = _summed(_runs("jacobian", estimator, temperature))
        _, along = jax.jit(jax.jvp, static_argnums=0)(
            lambda g: loss(g, estimate, refs), (gains,), (direction,)
        )
        want = sum(
            float(jnp.sum(g * d))
            for g, d in zip(jax.tree.leaves(grad_t[0]), jax.tree.leaves(direction), strict=True)
        )
        assert float(along) == pytest.approx(want, rel=1e-9)


def test_the_robust_loss_refuses_an_unknown_derivative():
    from wmr_jax._src.tuning import robust

    joint = robust.joint_problem(tuning.RobustConfig())
    with pytest.raises(
        ValueError, match="law_derivative = 'Jacobian' is not allowed; allowed: 'tr"
    ):
        robust.RobustLoss(10, joint, False, None, "Jacobian")


def test_the_robust_loss_hands_its_derivative_to_every_run(monkeypatch):
    from wmr_jax._src.tuning import robust

    joint = robust.joint_problem(tuning.RobustConfig())
    refs = jnp.asarray(random_refs(0, 4))
    batches = robust.sample_conditions(
        jax.random.key(0), refs, refs[:1], 10, 0.1, joint, False, None, "jacobian"
    )
    assert [options.law_derivative for _, options in batches] == ["jacobian", "jacobian"]
    seen = []

    def sample(*args):
        seen.append(args[-1])
        raise StopIteration  # what the runs would compute is not needed here

    monkeypatch.setattr(robust, "sample_conditions", sample)
    for derivative in loops.LAW_DERIVATIVES:
        loss = robust.RobustLoss(10, joint, False, None, derivative)
        with pytest.raises(StopIteration):
            loss(
                jnp.zeros(joint.dim),
                (jax.random.key(0), refs, refs[:1]),
                0.1,
                (w.Robot(), jnp.asarray(0.033)),
            )
    assert seen == ["traced", "jacobian"]
    assert robust.RobustLoss(10, joint, False, None).law_derivative == "traced"
