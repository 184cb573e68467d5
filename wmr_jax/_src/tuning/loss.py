"""The differentiable tuning loss and the robust per-pose batch gradient.

``tuning_loss`` is a relaxed arrival time plus a shaping term, and a
wheel-saturation penalty for the non-ideal loop (``docs/model.md §4, §6``).

Per-pose gradients are heavy-tailed: a run that grazes a switching surface,
or that sits parked on its reference (where the bearing ``φ_e`` is
undefined), can have a sensitivity many orders of magnitude above the
median, growing geometrically with the remaining horizon, and in float32
overflowing. ``robust_gradient`` therefore caps each pose's gradient at a
multiple of the batch median (``pose_clip``) and drops non-finite ones
before averaging; the trainer feeds it to ``optax.chain(clip_by_global_norm,
adam)``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src import loops
from wmr_jax._src import rollout as simulation
from wmr_jax._src.checks import as_float_tree, check_number, float_dtype
from wmr_jax._src.controllers import SHIM_SUNG
from wmr_jax._src.controllers import shim_sung as law
from wmr_jax._src.metrics import DEFAULT_TOL_R, DEFAULT_TOL_THETA
from wmr_jax._src.params import Gains, Robot
from wmr_jax._src.poses import HORIZON_S, horizon_steps
from wmr_jax._src.tuning.parametrisation import (
    GAIN_FIELDS,
    PAPER_FEASIBLE_GAINS,
    gains_from_logits,
)

__all__ = ["LossTerms", "LossWeights", "loss_terms", "robust_gradient", "tuning_loss"]


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Shape and weights of the terms of ``tuning_loss`` (static under ``jit``).

    Attributes:
        arrival_softness: width ``s`` of the relaxed "arrived" test, in units
            of the squared, tolerance-normalised error (see ``tuning_loss``).
        shaping: weight of the integrated log-error term (per second).
        saturation: weight of the wheel-saturation penalty (non-ideal loop).
    """

    arrival_softness: float = 0.1
    shaping: float = 0.05
    saturation: float = 1.0


@dataclasses.dataclass(frozen=True)
class LossSpec:
    """Static part of the loss: horizon, velocity loop, tolerances, weights."""

    steps: int
    velocity: str
    substeps: int
    wheel_limit: str
    tol_r: float
    tol_theta: float
    weights: LossWeights
    remat: bool

    def options(self, temperature: Any = None) -> loops.Options:
        """The rollout options of this loss with the Shim–Sung law at ``temperature``."""
        return loops.Options(
            steps=self.steps,
            velocity=self.velocity,
            controller=SHIM_SUNG,
            temperature=temperature,
            substeps=self.substeps,
            wheel_limit=self.wheel_limit,
        )


class LossTerms(NamedTuple):
    """The per-run terms of ``tuning_loss``, each ``(N,)`` in s.

    Attributes:
        arrival: relaxed arrival time ``T̃``.
        log_error: integrated log-error ``∫ log(1 + q + p) dt``.
        saturation: integrated squared wheel shortfall (zero for the ideal loop).
    """

    arrival: jax.Array
    log_error: jax.Array
    saturation: jax.Array


def make_spec(
    *,
    horizon: Any,
    dt: Any,
    velocity: Any,
    substeps: Any,
    wheel_limit: Any,
    tol_r: Any,
    tol_theta: Any,
    weights: Any,
    remat: bool,
) -> LossSpec:
    """Check the loss options (before tracing) and return them as a static spec.

    Raises:
        ValueError: naming the option, its value and what is allowed.
    """
    options = simulation.make_options(
        steps=horizon_steps(dt, horizon),
        velocity=velocity,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    if not isinstance(weights, LossWeights):
        raise ValueError(f"weights = {weights!r} is not allowed; allowed: a LossWeights")
    check_number("weights.arrival_softness", weights.arrival_softness)
    check_number("weights.shaping", weights.shaping, closed=True)
    check_number("weights.saturation", weights.saturation, closed=True)
    return LossSpec(
        steps=options.steps,
        velocity=options.velocity,
        substeps=options.substeps,
        wheel_limit=options.wheel_limit,
        tol_r=check_number("tol_r", tol_r, unit="cm"),
        tol_theta=check_number("tol_theta", tol_theta, high=math.pi / 2, unit="rad"),
        weights=weights,
        remat=bool(remat),
    )


# ---------------------------------------------------------------- one run


def _pose_loss_terms(ref, gains, init, robot, dt, spec: LossSpec, temperature):
    """Return ``(relaxed arrival s, integrated log-error s, saturation s)`` of one run.

    ``ref``, ``init``: ``(3,)``; ``gains``, ``robot``: scalar leaves;
    ``temperature``: traced scalar, or ``None`` for the hard law.
    """
    # The temperature is a traced value rather than a static option so that
    # annealing it does not recompile; Options is therefore built in the trace.
    options = spec.options(temperature)
    sin_tol_sq = math.sin(spec.tol_theta) ** 2
    softness = spec.weights.arrival_softness

    def body(state, _):
        new_state, out = loops.closed_loop_step(state, ref, gains, robot, dt, options)
        err = law.polar_error(new_state.pose, ref)
        # Squared, tolerance-normalised errors; arrived ⇔ both ≤ 1 (docs/model.md §6),
        # since |θ̄_e| ≤ tol ⇔ sin²θ_e ≤ sin²tol when |θ̄_e| ≤ π/2.
        dist = err.r**2 / spec.tol_r**2
        head = err.sin_theta**2 / sin_tol_sq
        log_arrived = jax.nn.log_sigmoid((1.0 - dist) / softness) + jax.nn.log_sigmoid(
            (1.0 - head) / softness
        )
        log_error = jnp.log1p(dist + head)
        # Ideal loop: the rims follow the command exactly, so this is zero.
        commanded = law.wheel_speeds(out.v, out.omega, robot)
        shortfall = jnp.sum((commanded - out.wheel_speeds) ** 2) / robot.v_max**2
        return new_state, (log_arrived, log_error, shortfall)

    if spec.remat:
        # Store only the carry (pose, velocity, integral: 7 numbers) per step
        # for the backward pass and recompute the law from it: the law's
        # intermediates would otherwise dominate the gradient's memory.
        body = jax.checkpoint(body)
    _, (log_arrived, log_error, shortfall) = jax.lax.scan(
        body, loops.initial_state(init), None, length=spec.steps
    )
    # Π_{j≥k} a_j (arrived at every sample from k on) by a reversed cumulative
    # sum of logs; its complement, summed over k, counts the samples before
    # the final settled run, as the hard arrival time does (docs/model.md §6).
    settled = jnp.exp(jnp.cumsum(log_arrived[::-1])[::-1])
    soft_arrival = dt * (1.0 + jnp.sum(1.0 - settled))
    return soft_arrival, dt * jnp.sum(log_error), dt * jnp.sum(shortfall)


def _pose_objective(ref, gains, init, robot, dt, spec: LossSpec, temperature):
    """Return the loss of one run, s (the per-pose term of ``tuning_loss``)."""
    arrival, log_error, shortfall = _pose_loss_terms(ref, gains, init, robot, dt, spec, temperature)
    total = arrival + spec.weights.shaping * log_error
    if spec.velocity == "nonideal":
        total = total + spec.weights.saturation * shortfall
    return total


def _per_pose(function: Callable, spec: LossSpec, temperature) -> Callable:
    """Lift ``function(ref, gains, init, robot, dt, spec, temperature)`` over a batch."""

    def single(ref, gains, init, robot, dt, _options):
        return function(ref, gains, init, robot, dt, spec, temperature)

    return loops.batched(single)


def batch_loss(refs, gains, init, robot, dt, spec: LossSpec, temperature):
    """Mean of the per-run loss over a prepared batch (traceable core of ``tuning_loss``)."""
    values = _per_pose(_pose_objective, spec, temperature)(refs, gains, init, robot, dt, None)
    return jnp.mean(values)


def _batch_terms(refs, gains, init, robot, dt, spec: LossSpec, temperature):
    return LossTerms(
        *_per_pose(_pose_loss_terms, spec, temperature)(refs, gains, init, robot, dt, None)
    )


_batch_loss_jit = jax.jit(batch_loss, static_argnames=("spec",))
_batch_terms_jit = jax.jit(_batch_terms, static_argnames=("spec",))


# ---------------------------------------------------------------- robust gradient


def robust_value_and_grad(z, refs, init, robot, dt, spec: LossSpec, temperature, pose_clip):
    """Return ``(mean loss, gradient (7,) w.r.t. the logits, stats)`` over a prepared batch.

    Each pose's gradient is capped at ``pose_clip`` times the batch median
    norm (``None``: no cap) and non-finite ones are dropped, then averaged.
    """

    def gain_vector(z):
        gains = gains_from_logits(z, robot)
        return jnp.stack([getattr(gains, name) for name in GAIN_FIELDS])

    single = jax.value_and_grad(_pose_objective, argnums=1)
    gains = gains_from_logits(z, robot)
    values, gain_grads = _per_pose(single, spec, temperature)(refs, gains, init, robot, dt, None)
    # Chain rule to the logits for all poses at once: the per-pose gradients
    # (N, 7), in field order, times the Jacobian ∂gains/∂z (7, 7).
    grads = jnp.stack([getattr(gain_grads, name) for name in GAIN_FIELDS], axis=-1)
    grads = grads @ jax.jacobian(gain_vector)(z)
    norms = jnp.linalg.norm(grads, axis=-1)
    finite = jnp.isfinite(norms) & jnp.isfinite(values)
    if pose_clip is None:
        scale = jnp.ones_like(norms)
    else:
        cap = pose_clip * jnp.nanmedian(jnp.where(finite, norms, jnp.nan))
        scale = jnp.minimum(1.0, cap / jnp.where(norms > 0, norms, 1.0))
    weight = jnp.where(finite, scale, 0.0)
    grad = jnp.sum(jnp.where(finite[:, None], grads, 0.0) * weight[:, None], axis=0)
    grad = jnp.where(jnp.all(jnp.isfinite(grad)), grad, 0.0) / refs.shape[0]
    kept = jnp.maximum(jnp.sum(finite), 1)
    loss = jnp.sum(jnp.where(finite, values, 0.0)) / kept
    stats = {
        "dropped": jnp.mean((~finite).astype(norms.dtype)),
        "clipped": jnp.mean((finite & (scale < 1.0)).astype(norms.dtype)),
    }
    return loss, grad, stats


_robust_jit = jax.jit(robust_value_and_grad, static_argnames=("spec",))


# ---------------------------------------------------------------- public entry points

_OPTION_DEFAULTS = {
    "init": (0.0, 0.0, 0.0),
    "robot": None,
    "dt": simulation.DEFAULT_DT,
    "horizon": HORIZON_S,
    "velocity": "ideal",
    "substeps": loops.DEFAULT_SUBSTEPS,
    "wheel_limit": "clip",
    "tol_r": DEFAULT_TOL_R,
    "tol_theta": DEFAULT_TOL_THETA,
    "weights": LossWeights(),
    "remat": True,
}
_STATIC_OPTIONS = tuple(name for name in _OPTION_DEFAULTS if name not in ("init", "robot"))


def _prepared(gains: Any, refs: Any, temperature: Any, options: dict[str, Any]) -> tuple:
    """Check every argument (before tracing); return ``(spec, temperature, prepared args)``.

    ``gains`` ``None`` (``robust_gradient``, which has logits instead) checks
    the rest against the paper's feasible gains.
    """
    unknown = sorted(set(options) - set(_OPTION_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown option {unknown[0]!r}; allowed: {', '.join(_OPTION_DEFAULTS)}")
    o = {**_OPTION_DEFAULTS, **options}
    gains = PAPER_FEASIBLE_GAINS if gains is None else gains
    if temperature is not None:
        temperature = check_number("temperature", temperature)
    spec = make_spec(**{name: o[name] for name in _STATIC_OPTIONS})
    args = simulation.prepare(
        refs, gains, o["init"], o["robot"], o["dt"], spec.options(), batch=True
    )
    if temperature is not None:
        temperature = jnp.asarray(temperature, float_dtype())
    return spec, temperature, args


def tuning_loss(
    gains: Gains,
    refs: Any,
    *,
    temperature: float | None,
    init: Any = (0.0, 0.0, 0.0),
    robot: Robot | None = None,
    dt: float = simulation.DEFAULT_DT,
    horizon: float = HORIZON_S,
    velocity: str = "ideal",
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
    weights: LossWeights = LossWeights(),  # noqa: B008 (frozen, so safe to share)
    remat: bool = True,
) -> jax.Array:
    """Return the differentiable tuning loss of ``gains`` over a batch of references, s.

    Per run, averaged over the batch::

        T̃  +  w_shape · ∫ log(1 + q + p) dt  [ + w_sat · ∫ |v_wheel* − v_wheel|² / V_max² dt ]

    * ``T̃`` is the ``docs/model.md §6`` arrival time with its indicator
      relaxed. With ``q = (r_e / tol_r)²`` and ``p = (sin θ_e / sin tol_θ)²``
      at a sample, the robot is arrived exactly when ``q ≤ 1`` and ``p ≤ 1``.
      The relaxed test ``a = σ((1 − q)/s) σ((1 − p)/s)``
      (``s = weights.arrival_softness``) gives
      ``T̃ = dt (1 + Σ_k (1 − Π_{j≥k} a_j))``, which *is* the arrival time,
      capped at the horizon, wherever ``a`` is 0 or 1. That is why the loss
      tracks arrival time; the width ``s`` makes it ask for a small margin
      inside the tolerances.
    * ``∫ log(1 + q + p) dt`` integrates the log of the tolerance-normalised
      error in the Lyapunov quantities ``r_e`` and ``θ̄_e``. ``T̃`` has no
      gradient while a run is far from its reference or never arrives; this
      term has one everywhere. For an exponential approach at rate λ from
      ``q₀ ≫ 1`` it is about ``log²(q₀) / (4λ)``, so it too shrinks as the
      arrival gets earlier.
    * Non-ideal loop only (``docs/model.md §4``): the wheel-saturation
      penalty integrates the squared shortfall of the rim speeds behind their
      commands at each sample, normalised by ``V_max``: small while the wheel
      loop tracks, large when its torque or ``±V_max`` limits saturate. With
      the ideal loop the rims follow the commands exactly and it is zero.

    The controller is the law's smooth relaxation at ``temperature``
    (``docs/model.md §3``), so the gradient reaches all seven gains, the
    switching thresholds included. ``None`` is the hard law, whose gradient
    with respect to the switching thresholds ``Φ_m``, ``R_a`` and ``R_e`` is
    zero almost everywhere (``k_r``, ``k_θ``, ``R_m`` and ``α`` scale
    commands and keep theirs).

    Args:
        gains: the gains (differentiate with respect to this argument).
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        init: ``(3,)`` or ``(N, 3)`` initial pose(s).
        robot: robot parameters; default ``Robot()``.
        dt: control period, s.
        horizon: simulated time per run, s (``docs/model.md §6``: 6 s).
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (``docs/model.md §4``).
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        tol_r: arrival distance tolerance, cm.
        tol_theta: arrival heading tolerance, rad.
        weights: the terms' weights and the relaxed test's width.
        remat: recompute the law in the backward pass (``jax.checkpoint`` on
            the scan body) instead of storing it: same values, less memory.

    Returns:
        Scalar loss, s.

    Raises:
        ValueError: for out-of-range gains, poses or options, naming the value.
    """
    options = {name: value for name, value in locals().items() if name in _OPTION_DEFAULTS}
    spec, temperature, args = _prepared(gains, refs, temperature, options)
    return _batch_loss_jit(*args, spec=spec, temperature=temperature)


def loss_terms(gains: Gains, refs: Any, *, temperature: float | None, **options: Any) -> LossTerms:
    """Return the per-run terms of ``tuning_loss`` (before weighting and averaging).

    Args:
        gains: the gains.
        refs: ``(N, 3)`` reference poses.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        **options: ``init``, ``robot``, ``dt``, ``horizon``, ``velocity``,
            ``substeps``, ``wheel_limit``, ``tol_r``, ``tol_theta``,
            ``weights``, ``remat``: as for ``tuning_loss``.

    Returns:
        ``LossTerms`` of ``(N,)`` arrays, s.
    """
    spec, temperature, args = _prepared(gains, refs, temperature, options)
    return _batch_terms_jit(*args, spec=spec, temperature=temperature)


def robust_gradient(
    z: Any,
    refs: Any,
    *,
    temperature: float | None,
    pose_clip: float | None = 1.0,
    **options: Any,
) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
    """Return the tuner's robust batch gradient with respect to the logits ``z``.

    The gains are ``gains_from_logits(z, robot)``. Each pose's gradient of the
    ``tuning_loss`` term is capped at ``pose_clip`` times the batch median
    norm and non-finite ones are dropped before averaging; the loss is the
    mean over the finite runs.

    Args:
        z: ``(7,)`` logits.
        refs: ``(N, 3)`` reference poses.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        pose_clip: cap in multiples of the batch median norm; ``None`` caps
            nothing.
        **options: as for ``loss_terms``.

    Returns:
        ``(loss s, gradient (7,), stats)`` where ``stats`` holds the fractions
        of the poses ``"dropped"`` (non-finite) and ``"clipped"``.
    """
    spec, temperature, (refs, _, init, robot, dt) = _prepared(None, refs, temperature, options)
    z = as_float_tree(jnp.asarray(z))
    if pose_clip is not None:
        pose_clip = jnp.asarray(check_number("pose_clip", pose_clip), float_dtype())
    return _robust_jit(z, refs, init, robot, dt, spec, temperature, pose_clip)
