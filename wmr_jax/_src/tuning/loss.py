"""The differentiable tuning loss (``docs/model.md §4, §6``) and the robust batch gradient.

Per-pose gradients are heavy-tailed (a run that grazes a switching surface, or
sits parked on its reference where ``φ_e`` is undefined, can overflow in
float32), so ``robust_gradient`` caps each and drops non-finite ones.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    as_float_tree,
    check_bool,
    check_number,
    float_dtype,
    real_array,
    require,
    require_representable,
)
from wmr_jax._src.model.controllers import SHIM_SUNG
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.controllers.base import Controller
from wmr_jax._src.model.controllers.schedule import SCHEDULE, ScheduleParams
from wmr_jax._src.model.dynamics import sin_cos
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R, DEFAULT_TOL_THETA
from wmr_jax._src.sim.poses import HORIZON_S, horizon_steps
from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS
from wmr_jax._src.tuning.problems import FIXED, Problem, get_problem


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
    """Static part of the loss: horizon, velocity loop, tolerances, weights, speed limiter."""

    steps: int
    velocity: str
    substeps: int
    wheel_limit: str
    tol_r: float
    tol_theta: float
    weights: LossWeights
    remat: bool
    controller: Controller = SHIM_SUNG
    accel_limit: bool = False

    def options(self, temperature: Any = None) -> loops.Options:
        """The rollout options of this loss (its fields but the loss's own) at ``temperature``."""
        loss_only = ("tol_r", "tol_theta", "weights")
        fields = [f.name for f in dataclasses.fields(self) if f.name not in loss_only]
        return loops.Options(**{f: getattr(self, f) for f in fields}, temperature=temperature)

    def for_robot(self, robot: Robot, dt: Any) -> LossSpec:
        """This spec with the speed limiter as ``loops.for_robot`` sets it (before tracing).

        So that the loss tunes the loop the evaluation judges (docs/model.md §4.2.2).
        """
        fitted = loops.for_robot(self.options(), robot, dt)
        return dataclasses.replace(self, accel_limit=fitted.accel_limit)


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


def make_spec(*, controller: Any = SHIM_SUNG, **given: Any) -> LossSpec:
    """Check the static options of ``tuning_loss`` (before tracing); return them as a spec.

    ``given``: its keyword options but ``init`` and ``robot``; the others keep
    their defaults. ``ValueError`` names a bad option, its value and what is allowed.
    """
    o = {**_OPTION_DEFAULTS, **given}
    options = simulation.make_options(
        steps=horizon_steps(o["dt"], o["horizon"]),
        velocity=o["velocity"],
        substeps=o["substeps"],
        wheel_limit=o["wheel_limit"],
        controller=controller,
    )
    weights = o["weights"]
    if not isinstance(weights, LossWeights):
        raise ValueError(f"weights = {weights!r} is not allowed; allowed: a LossWeights")
    for name, closed in (("arrival_softness", False), ("shaping", True), ("saturation", True)):
        value = check_number(f"weights.{name}", getattr(weights, name), closed=closed)
        require_representable(f"weights.{name}", np.asarray(value))
    tol_r = check_number("tol_r", o["tol_r"], unit="cm")
    tol_theta = check_number("tol_theta", o["tol_theta"], high=math.pi / 2, unit="rad")
    # The loss divides by tol_r² and sin²(tol_θ): both must stay finite.
    largest = float(np.finfo(np.dtype(float_dtype())).max)
    smallest = largest**-0.5
    for name, value, scale, unit in (
        ("tol_r", tol_r, tol_r, "cm"),
        ("tol_theta", tol_theta, math.sin(tol_theta), "rad"),
    ):
        if scale < smallest:
            raise ValueError(
                f"{name} = {value!r} is too small for {np.dtype(float_dtype()).name}, whose "
                f"1 / {name}² overflows; allowed: a number >= {smallest:.3g} {unit}"
            )
    return LossSpec(
        steps=options.steps,
        velocity=options.velocity,
        substeps=options.substeps,
        wheel_limit=options.wheel_limit,
        tol_r=tol_r,
        tol_theta=tol_theta,
        weights=weights,
        remat=check_bool("remat", o["remat"]),
        controller=options.controller,
    )


def arrival_terms(dist: jax.Array, head: jax.Array, softness: Any) -> tuple[jax.Array, jax.Array]:
    """``(a, log(1 + q + p))`` of one sample, ``a = σ((1 − q)/s) σ((1 − p)/s)`` the relaxed test.

    ``dist``: ``q = (r_e / tol_r)²``; ``head``: ``p = (sin θ_e / sin tol_θ)²``;
    ``softness``: ``s``.
    """
    arrived = jax.nn.sigmoid((1.0 - dist) / softness) * jax.nn.sigmoid((1.0 - head) / softness)
    # log, not log1p (several times slower on XLA:CPU): 1 + q + p ≥ 1, so the
    # absolute error is at most half an ulp of the sum.
    return arrived, jnp.log(1.0 + (dist + head))


# choice: the hard test (docs/model.md §6) counts a run that stays just inside
# the tolerance in full. A relaxed test half-passed at the tolerance and a
# log-error that keeps pulling inside it reward settling deep inside, which
# under sensor noise costs arrival time (docs/robustness.md, "Which tuner to
# use"); the robust loss centres its test this far beyond the tolerance, in
# squared normalised error, and shapes only the error beyond the tolerance.
ROBUST_SLACK = 0.3


def recorded_arrival(poses: jax.Array, ref: jax.Array, dt: jax.Array) -> jax.Array:
    """The robust loss's per-run term of one recorded run ``poses (steps, 3)``, s.

    The relaxed arrival time of ``tuning_loss`` with its test centred
    ``ROBUST_SLACK`` beyond the tolerance, plus the log-error shaping of
    the error beyond the tolerance only (default weights).
    """
    weights = LossWeights()
    err = law.polar_error(poses, ref)
    dist = err.r**2 / DEFAULT_TOL_R**2
    head = err.sin_theta**2 / math.sin(DEFAULT_TOL_THETA) ** 2
    arrived, _ = arrival_terms(dist - ROBUST_SLACK, head - ROBUST_SLACK, weights.arrival_softness)
    beyond = jnp.log(1.0 + jax.nn.relu(dist - 1.0) + jax.nn.relu(head - 1.0))
    # Σ_k Π_{j≥k} a_j: the runs of arrived samples that last to the end.
    settled = jnp.sum(jnp.cumprod(arrived[::-1]))
    soft = dt * (1.0 + arrived.shape[0] - settled)
    return soft + weights.shaping * dt * jnp.sum(beyond)


def _pose_loss_terms(ref, gains, init, robot, dt, spec: LossSpec, temperature):
    """Return ``(relaxed arrival s, integrated log-error s, saturation s)`` of one run, streamed."""
    # Built in the trace: the temperature is traced, so annealing does not recompile.
    options = spec.options(temperature)
    sin_tol_sq = math.sin(spec.tol_theta) ** 2
    inv_tol_r_sq = 1.0 / spec.tol_r**2
    softness = spec.weights.arrival_softness
    cos_r, sin_r = sin_cos(ref[2])

    nonideal = spec.velocity == "nonideal"

    def fold(acc, pose, out):
        # The pose as the loop carries it: position and heading as complex numbers.
        dx, dy = ref[0] - pose.position.real, ref[1] - pose.position.imag
        cos_c, sin_c = pose.heading.real, pose.heading.imag
        sin_theta = sin_r * cos_c - cos_r * sin_c
        # Squared, tolerance-normalised errors; arrived ⇔ both ≤ 1 (docs/model.md §6),
        # since |θ̄_e| ≤ tol ⇔ sin²θ_e ≤ sin²tol when |θ̄_e| ≤ π/2.
        dist = (dx * dx + dy * dy) * inv_tol_r_sq
        head = sin_theta * sin_theta / sin_tol_sq
        arrived, log_error = arrival_terms(dist, head, softness)
        # Σ_k Π_{j≥k} a_j so far, by S ← a (S + 1), riding with the log-error as
        # one complex number: one output per step is cheaper on XLA:CPU.
        sums = acc[0]
        sums = jax.lax.complex(arrived * (sums.real + 1.0), sums.imag + log_error)
        if not nonideal:
            return (sums,)
        # Ideal loop: the rims follow the command exactly, so this is zero.
        commanded = law.wheel_speeds(out.v, out.omega, robot)
        return sums, acc[1] + jnp.sum((commanded - out.wheel_speeds) ** 2) / robot.v_max**2

    zero = jnp.zeros((), init.dtype)
    acc = (jax.lax.complex(zero, zero), zero) if nonideal else (jax.lax.complex(zero, zero),)
    _, acc, _ = loops.scan_closed_loop(ref, gains, init, robot, dt, options, fold=fold, acc=acc)
    settled, log_error = acc[0].real, acc[0].imag
    shortfall = acc[1] if nonideal else zero
    # 1 + Σ_k (1 − settled_k) counts the samples before the final settled run,
    # as the hard arrival time does (docs/model.md §6).
    soft_arrival = dt * (1.0 + spec.steps - settled)
    return soft_arrival, dt * log_error, dt * shortfall


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


def robust_value_and_grad(
    z, refs, init, robot, dt, spec: LossSpec, temperature, pose_clip, problem: Problem = FIXED
):
    """Return ``(mean loss, gradient (dim,) w.r.t. the logits, stats)`` over a prepared batch.

    Each pose's gradient capped and non-finite ones dropped (``capped_mean``).
    """

    def single(ref, z):
        params = problem.from_logits(z, robot)
        return _pose_objective(ref, params, init, robot, dt, spec, temperature)

    # The logits are shared: each pose's gradient is (dim,).
    values, grads = jax.vmap(jax.value_and_grad(single, argnums=1), in_axes=(0, None))(refs, z)
    loss, grad, finite, scale = capped_mean(values, grads, pose_clip)
    grad = jnp.where(jnp.all(jnp.isfinite(grad)), grad, 0.0) / refs.shape[0]
    stats = {
        "dropped": jnp.mean((~finite).astype(grad.dtype)),
        "clipped": jnp.mean((finite & (scale < 1.0)).astype(grad.dtype)),
    }
    return loss, grad, stats


def capped_mean(values, grads, pose_clip=1.0):
    """Mean loss and capped gradient sum of per-run ``values (N,)`` and ``grads (N, dim)``.

    Each run's gradient is capped at ``pose_clip`` times the batch median
    norm (``None``: no cap); runs whose value or gradient is not finite are dropped.

    Returns:
        ``(mean loss over the kept runs, Σ capped gradients (dim,), kept (N,),
        scale (N,))``: the caller divides the sum by ``N`` (its own guard on a
        non-finite sum first).
    """
    norms = jnp.linalg.norm(grads, axis=-1)
    finite = jnp.isfinite(norms) & jnp.isfinite(values)
    if pose_clip is None:
        scale = jnp.ones_like(norms)
    else:
        cap = pose_clip * jnp.nanmedian(jnp.where(finite, norms, jnp.nan))
        scale = jnp.minimum(1.0, cap / jnp.where(norms > 0, norms, 1.0))
    weight = jnp.where(finite, scale, 0.0)
    grad = jnp.sum(jnp.where(finite[:, None], grads, 0.0) * weight[:, None], axis=0)
    kept = jnp.maximum(jnp.sum(finite), 1)
    loss = jnp.sum(jnp.where(finite, values, 0.0)) / kept
    return loss, grad, finite, scale


_robust_jit = loops.jit_top_level(robust_value_and_grad, static_argnames=("spec", "problem"))


def _prepared(gains: Any, refs: Any, temperature: Any, options: dict[str, Any]) -> tuple:
    """Check every argument (before tracing); return ``(spec, temperature, prepared args)``.

    ``gains``: ``None`` is the paper's feasible gains; a ``ScheduleParams``, the schedule.
    """
    unknown = sorted(set(options) - set(_OPTION_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown option {unknown[0]!r}; allowed: {', '.join(_OPTION_DEFAULTS)}")
    o = {**_OPTION_DEFAULTS, **options}
    gains = PAPER_FEASIBLE_GAINS if gains is None else gains
    if not isinstance(gains, Gains | ScheduleParams):
        raise ValueError(
            f"gains is a {type(gains).__name__}; allowed: a Gains or a ScheduleParams (the "
            "tuning loss is Shim–Sung's, fixed or scheduled; docs/custom_controller.md)"
        )
    controller = SCHEDULE if isinstance(gains, ScheduleParams) else SHIM_SUNG
    if temperature is not None:
        temperature = simulation.check_temperature("temperature", temperature)
        temperature = jnp.asarray(temperature, float_dtype())
    spec = make_spec(**{name: o[name] for name in _STATIC_OPTIONS}, controller=controller)
    args = simulation.prepare(
        refs, gains, o["init"], o["robot"], o["dt"], spec.options(), batch=True
    )
    spec = spec.for_robot(args[3], args[4])
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
      relaxed: with ``q = (r_e / tol_r)²`` and ``p = (sin θ_e / sin tol_θ)²``
      the robot is arrived exactly when ``q, p ≤ 1``; the relaxed test
      ``a = σ((1 − q)/s) σ((1 − p)/s)`` (``s = weights.arrival_softness``)
      gives ``T̃ = dt (1 + Σ_k (1 − Π_{j≥k} a_j))``, the arrival time wherever
      ``a`` is 0 or 1. The width ``s`` asks for a small margin inside the
      tolerances.
    * ``∫ log(1 + q + p) dt`` has a gradient everywhere, where ``T̃`` has none
      (a run far from its reference, or that never arrives), and shrinks as
      the arrival gets earlier.
    * Non-ideal loop only (``docs/model.md §4``): the squared shortfall of the
      rim speeds behind their commands, normalised by ``V_max``: large when the
      wheel loop's torque or ``±V_max`` limits saturate.

    The controller is the law's smooth relaxation at ``temperature``
    (``docs/model.md §3``), so the gradient reaches all seven gains. ``None``
    is the hard law, whose gradient with respect to the switching thresholds
    ``Φ_m``, ``R_a`` and ``R_e`` is zero almost everywhere.

    Args:
        gains: the gains (differentiate with respect to this argument).
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        init: ``(3,)`` or ``(N, 3)`` initial pose(s).
        robot: robot parameters; default ``Robot()``. Its ``accel_max`` and
            ``angular_accel_max``, where above 0, limit how fast the ideal
            loop's commands change, as in the rollouts (docs/model.md §4.2.2).
        dt: control period, s.
        horizon: simulated time per run, s (``docs/model.md §6``: 6 s).
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (``docs/model.md §4``).
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        tol_r: arrival distance tolerance, cm.
        tol_theta: arrival heading tolerance, rad.
        weights: the terms' weights and the relaxed test's width.
        remat: recompute each step of the rollout in the backward pass
            (``jax.checkpoint`` on the scan body) instead of storing its
            intermediates (no effect on the value).

    Returns:
        Scalar loss, s.

    Raises:
        ValueError: for out-of-range gains, poses or options, naming the value.
    """
    options = {name: value for name, value in locals().items() if name in _OPTION_DEFAULTS}
    spec, temperature, args = _prepared(gains, refs, temperature, options)
    return _batch_loss_jit(*args, spec=spec, temperature=temperature)


# The options of ``tuning_loss`` (and of ``loss_terms``, ``robust_gradient``) with their defaults.
_OPTION_DEFAULTS = {
    name: parameter.default
    for name, parameter in inspect.signature(tuning_loss).parameters.items()
    if parameter.kind is parameter.KEYWORD_ONLY and name != "temperature"
}
_STATIC_OPTIONS = tuple(name for name in _OPTION_DEFAULTS if name not in ("init", "robot"))


def loss_terms(gains: Gains, refs: Any, *, temperature: float | None, **options: Any) -> LossTerms:
    """Return the unweighted per-run terms of ``tuning_loss`` (same options), ``(N,)`` each, s."""
    spec, temperature, args = _prepared(gains, refs, temperature, options)
    return _batch_terms_jit(*args, spec=spec, temperature=temperature)


def robust_gradient(
    z: Any,
    refs: Any,
    *,
    temperature: float | None,
    pose_clip: float | None = 1.0,
    problem: str = "fixed",
    **options: Any,
) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
    """Return the tuner's robust batch gradient with respect to the logits ``z``.

    Each pose's gradient of the ``tuning_loss`` term is capped at ``pose_clip``
    times the batch median norm and non-finite ones are dropped before
    averaging; the loss is the mean over the finite runs.

    Args:
        z: ``(7,)`` logits.
        refs: ``(N, 3)`` reference poses.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        pose_clip: cap in multiples of the batch median norm; ``None`` caps
            nothing.
        problem: ``"fixed"`` (``z`` ``(7,)``, ``gains_from_logits``) or
            ``"schedule"`` (``z`` ``(35,)``, the gain schedule).
        **options: as for ``loss_terms``.

    Returns:
        ``(loss s, gradient (dim,), stats)`` where ``stats`` holds the fractions
        of the poses ``"dropped"`` (non-finite) and ``"clipped"``.
    """
    problem = get_problem(problem)
    # Options checked with parameters the logits can reach: no warning about gains not in use.
    start = None if problem is FIXED else problem.controller.default_params()
    # The logits map to gains through the robot: one robot for the batch.
    validate_one_robot(options.get("robot"), "robust_gradient")
    spec, temperature, (refs, _, init, robot, dt) = _prepared(start, refs, temperature, options)
    if not isinstance(z, jax.core.Tracer):
        host = real_array("z", z, f"({problem.dim},) real logits")
        require("z", host, np.isfinite(host), "finite logits")
    if np.shape(z) != (problem.dim,):
        raise ValueError(
            f"z has shape {np.shape(z)}; allowed: ({problem.dim},) for {problem.name!r}"
        )
    if pose_clip is not None:
        pose_clip = np.asarray(check_number("pose_clip", pose_clip), float_dtype())
    z = as_float_tree(z if isinstance(z, jax.Array) else np.asarray(z))
    return _robust_jit(z, refs, init, robot, dt, spec, temperature, pose_clip, problem)
