"""Gradient-based gain tuning under ``k_r + L k_θ ≤ V_max``, with optax.

The question it answers: which feasible gains bring the robot to its
reference fastest, over a distribution of reference poses (SPEC §6 by
default)? Adam descends a differentiable surrogate of the arrival time through
the law's smooth relaxation, the relaxation is annealed towards the hard law,
and the result is compared, with the hard law, against the paper's feasible
gains and against a plain random search given the same wall time.

The pieces:

* **A feasible parameterisation.** Gains are a smooth image of the unit cube
  ``u ∈ [0, 1]^7`` (``gains_from_unit``) that meets ``k_r + L k_θ ≤ V_max``
  and every range of SPEC §3 by construction, so every iterate is feasible,
  not only the last. Adam works on the logits ``z`` (``u = σ(z)``); random
  search samples ``u`` uniformly: both search the same set.
* **A differentiable loss** (``tuning_loss``): a relaxed arrival time plus a
  shaping term, and a wheel-saturation penalty for the non-ideal loop.
* **A robust batch gradient.** Per-pose gradients are heavy-tailed: a run that
  grazes a switching surface, or that sits parked on its reference (where the
  bearing ``φ_e`` is undefined), can have a sensitivity many orders of
  magnitude above the median, growing geometrically with the remaining
  horizon, and in float32 overflowing. The tuner therefore caps each pose's
  gradient at a multiple of the batch median (``pose_clip``) and drops
  non-finite ones before averaging; then ``optax.chain(clip_by_global_norm,
  adam)``.
* **A driver** (``tune``) with a progress bar, atomic checkpoints and
  ``resume``, writing ``tuned_gains.json``, ``tuning_curve.png`` and
  ``evaluation.json``; ``configure_parser``/``run_cli`` are its command line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections.abc import Callable
from io import BytesIO
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from wmr_jax import io, law, simulation
from wmr_jax.controllers import SHIM_SUNG
from wmr_jax.metrics import DEFAULT_TOL_R, DEFAULT_TOL_THETA, arrival_time
from wmr_jax.params import Gains, Robot, check_feasible, validate_gains, validate_robot

__all__ = [
    "CHECKPOINT_NAME",
    "DEFAULT_HORIZON",
    "EVAL_POSES",
    "GAIN_FIELDS",
    "PAPER_FEASIBLE_GAINS",
    "Evaluation",
    "GradientCost",
    "LossWeights",
    "SearchResult",
    "TuneConfig",
    "TuneResult",
    "configure_parser",
    "evaluate",
    "gains_from_unit",
    "gradient_cost",
    "horizon_steps",
    "markdown_table",
    "random_search",
    "run_cli",
    "sample_refs",
    "tune",
    "tuning_loss",
    "unit_from_gains",
]

GAIN_FIELDS = tuple(f.name for f in dataclasses.fields(Gains))

# SPEC §6: the default evaluation set of reference poses.
DEFAULT_R_MIN = 5.0  # cm
DEFAULT_R_MAX = 80.0  # cm
DEFAULT_HORIZON = 6.0  # s
EVAL_POSES = 400
# The held-out poses come from their own seed, the same for every tuning seed,
# so that tables from different runs compare like with like.
EVAL_SEED = 2003

# The paper's Fig. 10 gains, the ones that meet k_r + L k_θ ≤ V_max
# (60 + 1.85 · 10 = 78.5 cm/s); every other field at its default.
PAPER_FEASIBLE_GAINS = Gains(kr=60.0)

# Random search scores a run that never arrives as twice the horizon: worse
# than any arrival, but finite, so that candidates' means stay comparable.
_FAILURE_FACTOR = 2.0


def horizon_steps(horizon: float, dt: float) -> int:
    """Return the number of control periods that cover ``horizon`` s."""
    # The slack keeps 6.0 / 0.033 = 181.8… at 182 despite rounding.
    return math.ceil(horizon / dt - 1e-9)


# ---------------------------------------------------------------- poses


def sample_refs(
    key: jax.Array,
    n: int,
    *,
    r_min: float = DEFAULT_R_MIN,
    r_max: float = DEFAULT_R_MAX,
) -> jax.Array:
    """Draw ``n`` reference poses per SPEC §6, for a robot starting at ``(0, 0, 0)``.

    Distance uniform in ``[r_min, r_max]`` cm; bearing and heading uniform
    in ``[−π, π)``.

    Args:
        key: a JAX PRNG key.
        n: number of poses.
        r_min: smallest distance, cm.
        r_max: largest distance, cm.

    Returns:
        ``(n, 3)`` poses ``[x cm, y cm, θ rad]`` in the default float dtype.
    """
    dtype = simulation.float_dtype()
    k_dist, k_bearing, k_heading = jax.random.split(key, 3)
    dist = jax.random.uniform(k_dist, (n,), dtype, r_min, r_max)
    bearing = jax.random.uniform(k_bearing, (n,), dtype, -jnp.pi, jnp.pi)
    heading = jax.random.uniform(k_heading, (n,), dtype, -jnp.pi, jnp.pi)
    return jnp.stack([dist * jnp.cos(bearing), dist * jnp.sin(bearing), heading], axis=-1)


def _training_refs(seed: int, iteration: int, n: int) -> jax.Array:
    """A fresh batch per iteration, a pure function of (seed, iteration): resumable."""
    stream = jax.random.fold_in(jax.random.key(seed), 0)
    return sample_refs(jax.random.fold_in(stream, iteration), n)


def _held_out_refs(eval_seed: int, n: int) -> jax.Array:
    return sample_refs(jax.random.fold_in(jax.random.key(eval_seed), 1), n)


# ---------------------------------------------------------------- feasible set

# choice: the box that tuning and random search share. The wheel budget
# k_r + L k_θ, the share of it given to k_r, Φ_m and α are linear in u; the
# radii are log-uniform (R_m over 0.5–200 cm, R_a/R_m and R_e/R_a over
# 0.01–1), since their effect is on a log scale. The margins keep strict
# inequalities strict after float32 rounding: k_r + L k_θ ≤ (1 − 1e-4) V_max.
_BUDGET = (1e-3, 1.0 - 1e-4)  # fraction of V_max spent on k_r + L k_θ
_SHARE = (1e-3, 1.0 - 1e-3)  # fraction of that budget given to k_r
_PHI_M = (1e-3, math.pi / 2 - 1e-3)  # rad
_ALPHA = (1e-3, 0.5 - 1e-3)
_LOG_R_M = (math.log(0.5), math.log(200.0))  # log cm
_LOG_RATIO = (math.log(0.01), 0.0)  # log of R_a/R_m and of R_e/R_a
# How close to a face of the cube a starting point may sit: the logit of a
# point on a face is infinite (the paper's R_a = R_m is one).
_UNIT_CLIP = 1e-3


def _lerp(u: Any, bounds: tuple[float, float]) -> Any:
    lo, hi = bounds
    return lo + (hi - lo) * u


def _unlerp(x: float, bounds: tuple[float, float]) -> float:
    lo, hi = bounds
    return (x - lo) / (hi - lo)


def gains_from_unit(u: jax.Array, robot: Robot | None = None) -> Gains:
    """Map a point of the unit cube to feasible gains (SPEC §3).

    Every ``u ∈ [0, 1]^7`` gives ``k_r + L k_θ < V_max`` with ``k_r, k_θ > 0``,
    ``0 < Φ_m < π/2``, ``0 < α < 0.5`` and ``0 < R_e ≤ R_a ≤ R_m``.

    Args:
        u: ``(..., 7)`` ``[budget, k_r share, Φ_m, α, R_m, R_a/R_m, R_e/R_a]``,
            each in ``[0, 1]``.
        robot: gives ``L`` and ``V_max``; default ``Robot()``.

    Returns:
        ``Gains`` whose fields have the leading shape of ``u``.
    """
    robot = Robot() if robot is None else robot
    u = jnp.asarray(u)
    budget = robot.v_max * _lerp(u[..., 0], _BUDGET)  # cm/s
    share = _lerp(u[..., 1], _SHARE)
    r_m = jnp.exp(_lerp(u[..., 4], _LOG_R_M))
    # exp(·) ≤ 1 here, so the products keep R_e ≤ R_a ≤ R_m after rounding.
    r_a = r_m * jnp.exp(_lerp(u[..., 5], _LOG_RATIO))
    r_e = r_a * jnp.exp(_lerp(u[..., 6], _LOG_RATIO))
    return Gains(
        kr=budget * share,
        k_theta=budget * (1.0 - share) / robot.half_track,
        phi_m=_lerp(u[..., 2], _PHI_M),
        r_m=r_m,
        r_a=r_a,
        r_e=r_e,
        alpha=_lerp(u[..., 3], _ALPHA),
    )


def unit_from_gains(gains: Gains, robot: Robot | None = None) -> np.ndarray:
    """Return the point of the unit cube that ``gains_from_unit`` maps to ``gains``.

    Gains outside the cube's box, or on its faces (the paper's ``R_a = R_m``
    is one), are moved just inside, ``1e-3`` from the faces, so that their
    logits are finite.

    Args:
        gains: feasible gains with scalar fields.
        robot: gives ``L`` and ``V_max``; default ``Robot()``.

    Returns:
        ``(7,)`` float64 array in ``[1e-3, 1 − 1e-3]``.
    """
    robot = Robot() if robot is None else robot
    validate_gains(gains)
    g = _gains_to_dict(gains)
    budget = g["kr"] + float(robot.half_track) * g["k_theta"]
    u = [
        _unlerp(budget / float(robot.v_max), _BUDGET),
        _unlerp(g["kr"] / budget, _SHARE),
        _unlerp(g["phi_m"], _PHI_M),
        _unlerp(g["alpha"], _ALPHA),
        _unlerp(math.log(g["r_m"]), _LOG_R_M),
        _unlerp(math.log(g["r_a"] / g["r_m"]), _LOG_RATIO),
        _unlerp(math.log(g["r_e"] / g["r_a"]), _LOG_RATIO),
    ]
    return np.clip(np.asarray(u, dtype=float), _UNIT_CLIP, 1.0 - _UNIT_CLIP)


def _gains_to_dict(gains: Gains) -> dict[str, float]:
    return {name: float(getattr(gains, name)) for name in GAIN_FIELDS}


def _gains_from_logits(z: jax.Array, robot: Robot) -> Gains:
    return gains_from_unit(jax.nn.sigmoid(z), robot)


def _logits(u: np.ndarray) -> np.ndarray:
    return np.log(u) - np.log1p(-u)


# ---------------------------------------------------------------- the loss


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
class _LossSpec:
    """Static part of the loss: horizon, velocity loop, tolerances, weights."""

    steps: int
    velocity: str
    substeps: int
    wheel_limit: str
    tol_r: float
    tol_theta: float
    weights: LossWeights
    remat: bool


def _pose_loss_terms(ref, gains, init, robot, dt, spec: _LossSpec, temperature):
    """Return ``(relaxed arrival s, integrated log-error s, saturation s)`` of one run.

    ``ref``, ``init``: ``(3,)``; ``gains``, ``robot``: scalar leaves;
    ``temperature``: traced scalar, or ``None`` for the hard law.
    """
    # The temperature is a traced value rather than a static option so that
    # annealing it does not recompile; Options is therefore built in the trace.
    options = simulation.Options(
        steps=spec.steps,
        velocity=spec.velocity,
        controller=SHIM_SUNG,
        temperature=temperature,
        substeps=spec.substeps,
        wheel_limit=spec.wheel_limit,
    )
    sin_tol_sq = math.sin(spec.tol_theta) ** 2
    softness = spec.weights.arrival_softness

    def body(state, _):
        new_state, out = simulation.closed_loop_step(state, ref, gains, robot, dt, options)
        err = law.polar_error(new_state.pose, ref)
        # Squared, tolerance-normalised errors; arrived ⇔ both ≤ 1 (SPEC §6),
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
        body, simulation.initial_state(init), None, length=spec.steps
    )
    # Π_{j≥k} a_j (arrived at every sample from k on) by a reversed cumulative
    # sum of logs; its complement, summed over k, counts the samples before
    # the final settled run, as the hard arrival time does (SPEC §6).
    settled = jnp.exp(jnp.cumsum(log_arrived[::-1])[::-1])
    soft_arrival = dt * (1.0 + jnp.sum(1.0 - settled))
    return soft_arrival, dt * jnp.sum(log_error), dt * jnp.sum(shortfall)


def _pose_objective(ref, gains, init, robot, dt, spec: _LossSpec, temperature):
    """Return the loss of one run, s (the per-pose term of ``tuning_loss``)."""
    arrival, log_error, shortfall = _pose_loss_terms(ref, gains, init, robot, dt, spec, temperature)
    total = arrival + spec.weights.shaping * log_error
    if spec.velocity == "nonideal":
        total = total + spec.weights.saturation * shortfall
    return total


def _per_pose(function: Callable, spec: _LossSpec, temperature) -> Callable:
    """Lift ``function(ref, gains, init, robot, dt, spec, temperature)`` over a batch."""

    def single(ref, gains, init, robot, dt, _options):
        return function(ref, gains, init, robot, dt, spec, temperature)

    return simulation.batched(single)


def _batch_loss(refs, gains, init, robot, dt, spec: _LossSpec, temperature):
    values = _per_pose(_pose_objective, spec, temperature)(refs, gains, init, robot, dt, None)
    return jnp.mean(values)


_batch_loss_jit = jax.jit(_batch_loss, static_argnames=("spec",))


def _check_number(name: str, value: Any, *, low: float = 0.0, high: float = math.inf) -> float:
    """Return ``value`` as a float in the open interval ``(low, high)``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (low < number < high):
        upper = f" and < {high:g}" if math.isfinite(high) else ""
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: a number > {low:g}{upper}")
    return number


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= {minimum}")
    return int(value)


def _make_spec(
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
) -> _LossSpec:
    """Check the loss options (before tracing) and return them as a static spec."""
    dt = simulation.check_dt(dt)
    horizon = _check_number("horizon", horizon)
    options = simulation.make_options(
        steps=horizon_steps(horizon, dt),
        velocity=velocity,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    if not isinstance(weights, LossWeights):
        raise ValueError(f"weights = {weights!r} is not allowed; allowed: a LossWeights")
    _check_number("weights.arrival_softness", weights.arrival_softness)
    for name in ("shaping", "saturation"):
        if not float(getattr(weights, name)) >= 0:
            raise ValueError(
                f"weights.{name} = {getattr(weights, name)!r} is not allowed; allowed: >= 0"
            )
    return _LossSpec(
        steps=options.steps,
        velocity=options.velocity,
        substeps=options.substeps,
        wheel_limit=options.wheel_limit,
        tol_r=_check_number("tol_r", tol_r),
        tol_theta=_check_number("tol_theta", tol_theta, high=math.pi / 2),
        weights=weights,
        remat=bool(remat),
    )


def _options_of(spec: _LossSpec) -> simulation.Options:
    return simulation.Options(
        steps=spec.steps,
        velocity=spec.velocity,
        substeps=spec.substeps,
        wheel_limit=spec.wheel_limit,
    )


def tuning_loss(
    gains: Gains,
    refs: Any,
    *,
    temperature: float | None,
    init: Any = (0.0, 0.0, 0.0),
    robot: Robot | None = None,
    dt: float = simulation.DEFAULT_DT,
    horizon: float = DEFAULT_HORIZON,
    velocity: str = "ideal",
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
    weights: LossWeights = LossWeights(),  # noqa: B008 (frozen, so safe to share)
    remat: bool = True,
) -> jax.Array:
    """Return the differentiable tuning loss of ``gains`` over a batch of references, s.

    Per run, averaged over the batch::

        T̃  +  w_shape · ∫ log(1 + q + p) dt  [ + w_sat · ∫ |v_wheel* − v_wheel|² / V_max² dt ]

    * ``T̃`` is the SPEC §6 arrival time with its indicator relaxed. With
      ``q = (r_e / tol_r)²`` and ``p = (sin θ_e / sin tol_θ)²`` at a sample,
      the robot is arrived exactly when ``q ≤ 1`` and ``p ≤ 1``. The relaxed
      test ``a = σ((1 − q)/s) σ((1 − p)/s)`` (``s = weights.arrival_softness``)
      gives ``T̃ = dt (1 + Σ_k (1 − Π_{j≥k} a_j))``, which *is* the arrival
      time, capped at the horizon, wherever ``a`` is 0 or 1. That is why the
      loss tracks arrival time; the width ``s`` makes it ask for a small
      margin inside the tolerances.
    * ``∫ log(1 + q + p) dt`` integrates the log of the tolerance-normalised
      error in the Lyapunov quantities ``r_e`` and ``θ̄_e``. ``T̃`` has no
      gradient while a run is far from its reference or never arrives; this
      term has one everywhere. For an exponential approach at rate λ from
      ``q₀ ≫ 1`` it is about ``log²(q₀) / (4λ)``, so it too shrinks as the
      arrival gets earlier.
    * Non-ideal loop only (SPEC §4): the wheel-saturation penalty integrates
      the squared shortfall of the rim speeds behind their commands at each
      sample, normalised by ``V_max``: small while the wheel loop tracks,
      large when its torque or ``±V_max`` limits saturate. With the ideal
      loop the rims follow the commands exactly and it is zero.

    The controller is the law's smooth relaxation at ``temperature``
    (``wmr_jax.law``), so the gradient reaches all seven gains, the switching
    thresholds included. ``None`` is the hard law, whose gradient with
    respect to the switching thresholds ``Φ_m``, ``R_a`` and ``R_e`` is zero
    almost everywhere (``k_r``, ``k_θ``, ``R_m`` and ``α`` scale commands and
    keep theirs).

    Args:
        gains: the gains (differentiate with respect to this argument).
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        temperature: smooth-law temperature ``> 0``, or ``None`` for the hard law.
        init: ``(3,)`` or ``(N, 3)`` initial pose(s).
        robot: robot parameters; default ``Robot()``.
        dt: control period, s.
        horizon: simulated time per run, s (SPEC §6: 6 s).
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (SPEC §4).
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
    if temperature is not None:
        temperature = _check_number("temperature", temperature)
    spec = _make_spec(
        horizon=horizon,
        dt=dt,
        velocity=velocity,
        substeps=substeps,
        wheel_limit=wheel_limit,
        tol_r=tol_r,
        tol_theta=tol_theta,
        weights=weights,
        remat=remat,
    )
    refs, gains, init, robot, dt_arr = simulation.prepare(
        refs, gains, init, robot, dt, _options_of(spec), batch=True
    )
    if temperature is not None:
        temperature = jnp.asarray(temperature, simulation.float_dtype())
    return _batch_loss_jit(refs, gains, init, robot, dt_arr, spec=spec, temperature=temperature)


# ---------------------------------------------------------------- robust gradient


def _robust_value_and_grad(z, refs, init, robot, dt, spec: _LossSpec, temperature, pose_clip):
    """Return ``(mean loss, gradient (7,) w.r.t. the logits, stats)`` over a batch.

    Each pose's gradient is capped at ``pose_clip`` times the batch median
    norm (``None``: no cap) and non-finite ones are dropped, then averaged.
    """

    def gain_vector(z):
        gains = _gains_from_logits(z, robot)
        return jnp.stack([getattr(gains, name) for name in GAIN_FIELDS])

    single = jax.value_and_grad(_pose_objective, argnums=1)
    gains = _gains_from_logits(z, robot)
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


# ---------------------------------------------------------------- optimiser


@dataclasses.dataclass(frozen=True)
class _OptimHyper:
    """Static optimiser settings (part of the train step's compile key)."""

    learning_rate: float
    iters: int
    grad_clip: float
    pose_clip: float | None


def _optimizer(hyper: _OptimHyper) -> optax.GradientTransformation:
    # Cosine decay to a tenth: large steps while the temperature is high and
    # the landscape smooth, small ones once it is close to the hard law.
    schedule = optax.cosine_decay_schedule(hyper.learning_rate, hyper.iters, alpha=0.1)
    return optax.chain(optax.clip_by_global_norm(hyper.grad_clip), optax.adam(schedule))


def _train_step(z, opt_state, refs, temperature, init, robot, dt, *, spec, hyper):
    loss, grad, stats = _robust_value_and_grad(
        z, refs, init, robot, dt, spec, temperature, hyper.pose_clip
    )
    updates, opt_state = _optimizer(hyper).update(grad, opt_state, z)
    # Feasibility needs no projection: every z maps into the feasible set.
    z = optax.apply_updates(z, updates)
    stats = dict(stats, grad_norm=jnp.linalg.norm(grad))
    return z, opt_state, loss, stats


_train_step_jit = jax.jit(_train_step, static_argnames=("spec", "hyper"))


def _temperature(config: TuneConfig, iteration: int) -> float:
    """Geometric annealing from ``temperature_start`` to ``temperature_end``."""
    frac = iteration / max(config.iters - 1, 1)
    return config.temperature_start * (config.temperature_end / config.temperature_start) ** frac


# ---------------------------------------------------------------- hard-law evaluation


class Evaluation(NamedTuple):
    """Hard-law performance of one set of gains on a set of references (SPEC §6).

    Attributes:
        mean_arrival: mean arrival time over the runs that arrive, s.
        success_rate: fraction of runs that arrive within the horizon.
        peak_wheel_speed: largest rim speed of any wheel in any run, cm/s.
        poses: number of runs.
    """

    mean_arrival: float
    success_rate: float
    peak_wheel_speed: float
    poses: int


def evaluate(
    gains: Gains,
    refs: Any,
    *,
    robot: Robot | None = None,
    dt: float = simulation.DEFAULT_DT,
    horizon: float = DEFAULT_HORIZON,
    velocity: str = "ideal",
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> Evaluation:
    """Run ``gains`` with the hard law from ``(0, 0, 0)`` to each reference; summarise.

    Args:
        gains: the gains (scalar fields).
        refs: ``(N, 3)`` reference poses.
        robot: robot parameters; default ``Robot()``.
        dt: control period, s.
        horizon: simulated time per run, s.
        velocity: ``"ideal"`` or ``"nonideal"``.
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
    """
    steps = horizon_steps(_check_number("horizon", horizon), simulation.check_dt(dt))
    traj = simulation.batch_rollout(
        refs,
        gains,
        dt=dt,
        steps=steps,
        robot=robot,
        velocity=velocity,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    times = np.asarray(arrival_time(traj, jnp.asarray(refs), dt=dt))
    arrived = np.isfinite(times)
    return Evaluation(
        mean_arrival=float(np.mean(times[arrived])) if arrived.any() else math.inf,
        success_rate=float(np.mean(arrived)),
        peak_wheel_speed=float(np.max(np.abs(np.asarray(traj.wheel_speeds)))),
        poses=int(times.size),
    )


# ---------------------------------------------------------------- random search


class SearchResult(NamedTuple):
    """Outcome of ``random_search``.

    Attributes:
        gains: the best candidate found.
        score: its mean arrival time on the search poses, failures counted as
            twice the horizon, s.
        candidates: how many candidates were scored.
        wall_s: wall time spent, s.
    """

    gains: Gains
    score: float
    candidates: int
    wall_s: float


def random_search(
    key: jax.Array,
    refs: Any,
    *,
    budget_s: float,
    robot: Robot | None = None,
    start: Gains = PAPER_FEASIBLE_GAINS,
    chunk: int = 16,
    dt: float = simulation.DEFAULT_DT,
    horizon: float = DEFAULT_HORIZON,
    velocity: str = "ideal",
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> SearchResult:
    """Search the feasible set of ``gains_from_unit`` at random for ``budget_s`` seconds.

    Candidates are ``u ~ U[0, 1]^7``, scored ``chunk`` at a time with the hard
    law on ``refs`` (mean arrival time, failures counted as twice the
    horizon); ``start`` is the first candidate, so the result is never worse
    than it on ``refs``. At least one chunk is scored whatever the budget.

    Args:
        key: PRNG key of the candidates.
        refs: ``(N, 3)`` reference poses the candidates are scored on.
        budget_s: wall-time budget, s.
        robot: robot parameters; default ``Robot()``.
        start: gains scored first.
        chunk: candidates per batched rollout.
        dt, horizon, velocity, substeps, wheel_limit: as for ``evaluate``.
    """
    robot = validate_robot(Robot() if robot is None else robot)
    budget_s = float(budget_s)
    chunk = _check_int("chunk", chunk, 1)
    steps = horizon_steps(_check_number("horizon", horizon), simulation.check_dt(dt))
    refs = simulation.as_poses("refs", refs, batch=True)
    n = refs.shape[0]
    tiled = jnp.tile(refs, (chunk, 1))
    first = jnp.asarray(unit_from_gains(start, robot), simulation.float_dtype())
    best_score, best_u, count = math.inf, first, 0
    began = time.perf_counter()
    while count == 0 or time.perf_counter() - began < budget_s:
        u = jax.random.uniform(jax.random.fold_in(key, count), (chunk, 7), simulation.float_dtype())
        if count == 0:
            u = u.at[0].set(first)
        # Candidate i runs on poses i·N … (i+1)·N − 1: one flat batch.
        population = jax.tree.map(lambda leaf: jnp.repeat(leaf, n), gains_from_unit(u, robot))
        traj = simulation.batch_rollout(
            tiled,
            population,
            dt=dt,
            steps=steps,
            robot=robot,
            velocity=velocity,
            substeps=substeps,
            wheel_limit=wheel_limit,
        )
        times = arrival_time(traj, tiled, dt=dt).reshape(chunk, n)
        scores = np.asarray(jnp.mean(jnp.minimum(times, _FAILURE_FACTOR * steps * dt), axis=1))
        i = int(np.argmin(scores))
        if scores[i] < best_score:
            best_score, best_u = float(scores[i]), u[i]
        count += chunk
    best = jax.tree.map(float, gains_from_unit(best_u, robot))
    return SearchResult(best, best_score, count, time.perf_counter() - began)


# ---------------------------------------------------------------- the driver


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Everything that decides the result of ``tune`` (saved with each checkpoint).

    Attributes:
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (SPEC §4).
        iters: Adam iterations.
        poses: reference poses per iteration, a fresh batch each time (SPEC §6).
        seed: seed of the training poses and of the random search.
        learning_rate: Adam's initial step in logit space (cosine-decayed).
        grad_clip: ``clip_by_global_norm`` threshold of the batch gradient.
        pose_clip: cap of each pose's gradient norm, in multiples of the
            batch median; ``None`` for a plain mean.
        temperature_start: smooth-law temperature of the first iteration.
        temperature_end: temperature of the last (annealed geometrically).
        horizon: simulated time per run, s.
        dt: control period, s.
        checkpoint_every: iterations between checkpoints.
        eval_poses: held-out poses of the before/after table.
        eval_seed: seed of the held-out poses (the same for every ``seed``).
        random_search: also run random search for the tuning's wall time.
        weights: terms of the loss (see ``tuning_loss``).
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
    """

    velocity: str = "ideal"
    iters: int = 400
    poses: int = 256
    seed: int = 0
    learning_rate: float = 0.1
    grad_clip: float = 1.0
    pose_clip: float | None = 1.0
    temperature_start: float = 0.1
    temperature_end: float = 0.01
    horizon: float = DEFAULT_HORIZON
    dt: float = simulation.DEFAULT_DT
    checkpoint_every: int = 25
    eval_poses: int = EVAL_POSES
    eval_seed: int = EVAL_SEED
    random_search: bool = True
    weights: LossWeights = LossWeights()
    substeps: int = simulation.DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"

    def replace(self, **changes: Any) -> TuneConfig:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)

    def validate(self) -> TuneConfig:
        """Check every field; return ``self``.

        Raises:
            ValueError: naming the field, its value and what is allowed.
        """
        _check_int("iters", self.iters, 1)
        _check_int("poses", self.poses, 1)
        _check_int("seed", self.seed, 0)
        if self.seed >= 2**32:
            raise ValueError(f"seed = {self.seed!r} is not allowed; allowed: 0 <= seed < 2**32")
        _check_int("checkpoint_every", self.checkpoint_every, 1)
        _check_int("eval_poses", self.eval_poses, 1)
        _check_int("eval_seed", self.eval_seed, 0)
        _check_number("learning_rate", self.learning_rate)
        _check_number("grad_clip", self.grad_clip)
        if self.pose_clip is not None:
            _check_number("pose_clip", self.pose_clip)
        _check_number("temperature_start", self.temperature_start)
        _check_number("temperature_end", self.temperature_end)
        if not isinstance(self.random_search, bool):
            raise ValueError(
                f"random_search = {self.random_search!r} is not allowed; allowed: True or False"
            )
        self.spec()
        return self

    def spec(self) -> _LossSpec:
        return _make_spec(
            horizon=self.horizon,
            dt=self.dt,
            velocity=self.velocity,
            substeps=self.substeps,
            wheel_limit=self.wheel_limit,
            tol_r=DEFAULT_TOL_R,
            tol_theta=DEFAULT_TOL_THETA,
            weights=self.weights,
            remat=True,
        )

    def hyper(self) -> _OptimHyper:
        pose_clip = None if self.pose_clip is None else float(self.pose_clip)
        return _OptimHyper(
            float(self.learning_rate), int(self.iters), float(self.grad_clip), pose_clip
        )

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as JSON-ready values."""
        out = dataclasses.asdict(self)
        out["weights"] = dataclasses.asdict(self.weights)
        return out


class TuneResult(NamedTuple):
    """What ``tune`` returns (and writes to its folder).

    Attributes:
        gains: the tuned gains (feasible; floats).
        evaluation: hard-law ``Evaluation`` on the held-out poses, keyed
            ``"paper_feasible"``, ``"tuned"`` and, if run, ``"random_search"``.
        history: per-iteration ``loss`` (s), ``temperature`` and ``gains``
            ``(iters, 7)`` in ``GAIN_FIELDS`` order, as NumPy arrays.
        tune_wall_s: wall time of the gradient iterations (all sessions), s.
        search: the random search's result, or ``None``.
        out_dir: the folder written to.
    """

    gains: Gains
    evaluation: dict[str, Evaluation]
    history: dict[str, np.ndarray]
    tune_wall_s: float
    search: SearchResult | None
    out_dir: Path


CHECKPOINT_NAME = "checkpoint.npz"
_CHECKPOINT_FORMAT = 1


class _Progress(NamedTuple):
    """The whole state of a tuning run after ``iteration`` iterations."""

    iteration: int
    z: jax.Array
    opt_state: Any
    losses: tuple[float, ...]
    temperatures: tuple[float, ...]
    gains: tuple[tuple[float, ...], ...]
    elapsed_s: float


def _robot_dict(robot: Robot) -> dict[str, float]:
    return {f.name: float(getattr(robot, f.name)) for f in dataclasses.fields(Robot)}


def _identity(config: TuneConfig, robot: Robot) -> str:
    """What a checkpoint must match to be resumed: the config and the robot."""
    return json.dumps({"config": config.as_dict(), "robot": _robot_dict(robot)}, sort_keys=True)


def _save_checkpoint(path: Path, progress: _Progress, identity: str) -> None:
    leaves = jax.tree.leaves(progress.opt_state)
    arrays = {f"opt_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)}
    buffer = BytesIO()
    np.savez(
        buffer,
        format=np.asarray(_CHECKPOINT_FORMAT),
        identity=np.asarray(identity),
        iteration=np.asarray(progress.iteration),
        z=np.asarray(progress.z),
        losses=np.asarray(progress.losses, dtype=float),
        temperatures=np.asarray(progress.temperatures, dtype=float),
        gains=np.asarray(progress.gains, dtype=float).reshape(-1, len(GAIN_FIELDS)),
        elapsed_s=np.asarray(progress.elapsed_s),
        **arrays,
    )
    io.atomic_write_bytes(path, buffer.getvalue())


def _load_checkpoint(path: Path, fresh: _Progress, identity: str) -> _Progress:
    """Restore a checkpoint into the structure of ``fresh``.

    Raises:
        ValueError: if it belongs to another configuration or is unreadable.
    """
    try:
        with np.load(path) as data:
            stored = {key: data[key] for key in data.files}
    except (OSError, ValueError) as err:
        raise ValueError(
            f"checkpoint {path} cannot be read ({err}); remove it to start over"
        ) from err
    if int(stored.get("format", -1)) != _CHECKPOINT_FORMAT:
        raise ValueError(f"checkpoint {path} has an unknown format; remove it to start over")
    if str(stored["identity"]) != identity:
        saved = json.loads(str(stored["identity"]))
        now = json.loads(identity)
        diffs = [
            f"{key} = {saved['config'][key]!r} there, {now['config'][key]!r} now"
            for key in now["config"]
            if saved["config"].get(key) != now["config"][key]
        ] or ["the robot differs"]
        raise ValueError(
            f"--resume: checkpoint {path} is of another run ({'; '.join(diffs)}); "
            "allowed: the same settings, or a fresh --out"
        )
    leaves, treedef = jax.tree.flatten(fresh.opt_state)
    restored = [
        jnp.asarray(stored[f"opt_{i}"], dtype=jnp.asarray(leaf).dtype)
        for i, leaf in enumerate(leaves)
    ]
    return _Progress(
        iteration=int(stored["iteration"]),
        z=jnp.asarray(stored["z"], dtype=fresh.z.dtype),
        opt_state=jax.tree.unflatten(treedef, restored),
        losses=tuple(float(x) for x in stored["losses"]),
        temperatures=tuple(float(x) for x in stored["temperatures"]),
        gains=tuple(tuple(float(x) for x in row) for row in stored["gains"]),
        elapsed_s=float(stored["elapsed_s"]),
    )


def tune(
    out_dir: str | Path,
    config: TuneConfig | None = None,
    *,
    robot: Robot | None = None,
    resume: bool = False,
    progress: bool = True,
    callback: Callable[[int, float, Gains], None] | None = None,
) -> TuneResult:
    """Tune the gains by gradient descent and write the results to ``out_dir``.

    Starts from the paper's feasible gains (``PAPER_FEASIBLE_GAINS``, moved
    just inside the search box), runs ``config.iters`` Adam iterations on
    ``tuning_loss`` over a fresh batch of ``config.poses`` references each
    (robust batch gradient, see the module docstring), annealing the
    temperature, and then, with the hard law:

    * ``random_search`` over the same feasible set for the same wall time;
    * evaluates the paper's feasible gains, the tuned ones and the random
      search's on ``config.eval_poses`` held-out references.

    Files in ``out_dir``: ``tuned_gains.json`` (exactly the ``Gains`` field
    names), ``evaluation.json``, ``tuning_curve.png``, ``random_search_gains.json``
    and ``checkpoint.npz`` (written atomically every ``config.checkpoint_every``
    iterations and at the end).

    Args:
        out_dir: output folder (created if needed).
        config: the settings; default ``TuneConfig()``.
        robot: robot parameters; default ``Robot()``.
        resume: continue from ``out_dir/checkpoint.npz`` if present (it must
            come from the same settings); the result is the same as that of
            an uninterrupted run. Without it, any checkpoint is overwritten.
        progress: show a progress bar with the loss.
        callback: called as ``callback(iteration, loss, gains)`` after each
            iteration; an exception it raises stops the run (a checkpoint
            from the last ``checkpoint_every`` boundary stays behind).

    Returns:
        A ``TuneResult``.

    Raises:
        ValueError: for bad settings or a checkpoint of another run.
    """
    config = (TuneConfig() if config is None else config).validate()
    robot = validate_robot(Robot() if robot is None else robot)
    robot = simulation.as_float_tree(robot)
    out_dir = Path(out_dir)
    spec, hyper = config.spec(), config.hyper()
    dtype = simulation.float_dtype()
    dt = jnp.asarray(config.dt, dtype)
    init = jnp.zeros((3,), dtype)
    identity = _identity(config, robot)
    checkpoint = out_dir / CHECKPOINT_NAME

    z0 = jnp.asarray(_logits(unit_from_gains(PAPER_FEASIBLE_GAINS, robot)), dtype)
    state = _Progress(0, z0, _optimizer(hyper).init(z0), (), (), (), 0.0)
    if resume and checkpoint.exists():
        state = _load_checkpoint(checkpoint, state, identity)

    from tqdm.auto import tqdm

    bar = tqdm(
        total=config.iters,
        initial=state.iteration,
        desc=f"tune ({config.velocity})",
        disable=not progress,
        dynamic_ncols=True,
    )
    try:
        for iteration in range(state.iteration, config.iters):
            began = time.perf_counter()
            temperature = _temperature(config, iteration)
            refs = _training_refs(config.seed, iteration, config.poses)
            z, opt_state, loss, stats = _train_step_jit(
                state.z,
                state.opt_state,
                refs,
                jnp.asarray(temperature, dtype),
                init,
                robot,
                dt,
                spec=spec,
                hyper=hyper,
            )
            loss = float(loss)
            gains = _gains_from_logits(z, robot)
            row = tuple(float(getattr(gains, name)) for name in GAIN_FIELDS)
            state = _Progress(
                iteration + 1,
                z,
                opt_state,
                state.losses + (loss,),
                state.temperatures + (temperature,),
                state.gains + (row,),
                state.elapsed_s + time.perf_counter() - began,
            )
            bar.update(1)
            bar.set_postfix(loss=f"{loss:.3f}s", T=f"{temperature:.3g}", refresh=False)
            if state.iteration % config.checkpoint_every == 0 or state.iteration == config.iters:
                _save_checkpoint(checkpoint, state, identity)
            if callback is not None:
                callback(iteration, loss, gains)
    finally:
        bar.close()

    tuned = Gains(**dict(zip(GAIN_FIELDS, state.gains[-1], strict=True)))
    io.atomic_write_json(out_dir / "tuned_gains.json", _gains_to_dict(tuned))
    history = {
        "loss": np.asarray(state.losses),
        "temperature": np.asarray(state.temperatures),
        "gains": np.asarray(state.gains).reshape(-1, len(GAIN_FIELDS)),
    }

    run_options = dict(
        robot=robot,
        dt=config.dt,
        horizon=config.horizon,
        velocity=config.velocity,
        substeps=config.substeps,
        wheel_limit=config.wheel_limit,
    )
    search = None
    if config.random_search:
        stream = jax.random.fold_in(jax.random.key(config.seed), 2)
        search_refs = sample_refs(jax.random.fold_in(jax.random.key(config.seed), 3), config.poses)
        search = random_search(stream, search_refs, budget_s=state.elapsed_s, **run_options)
        io.atomic_write_json(out_dir / "random_search_gains.json", _gains_to_dict(search.gains))

    held_out = _held_out_refs(config.eval_seed, config.eval_poses)
    evaluation = {
        "paper_feasible": evaluate(PAPER_FEASIBLE_GAINS, held_out, **run_options),
        "tuned": evaluate(tuned, held_out, **run_options),
    }
    if search is not None:
        evaluation["random_search"] = evaluate(search.gains, held_out, **run_options)
    _write_evaluation(out_dir, config, robot, tuned, evaluation, state.elapsed_s, search)
    _plot_history(out_dir / "tuning_curve.png", history, config)
    return TuneResult(tuned, evaluation, history, state.elapsed_s, search, out_dir)


def _write_evaluation(out_dir, config, robot, tuned, evaluation, tune_wall_s, search) -> None:
    paper = evaluation["paper_feasible"].mean_arrival
    rows = {name: dict(ev._asdict()) for name, ev in evaluation.items()}
    for row in rows.values():
        row["speedup_vs_paper"] = paper / row["mean_arrival"]
    io.atomic_write_json(
        out_dir / "evaluation.json",
        {
            "velocity": config.velocity,
            "held_out_poses": config.eval_poses,
            "horizon_s": config.horizon,
            "law": "hard (temperature None)",
            "rows": rows,
            "tuned_gains": _gains_to_dict(tuned),
            "feasible": bool(check_feasible(tuned, robot)),
            "wall_time_s": {
                "tuning": tune_wall_s,
                "random_search": None if search is None else search.wall_s,
            },
            "random_search_candidates": None if search is None else search.candidates,
            "config": config.as_dict(),
        },
    )


def markdown_table(evaluation: dict[str, Evaluation]) -> str:
    """Return the before/after table as Markdown (mean arrival, success, peak wheel speed)."""
    paper = evaluation["paper_feasible"].mean_arrival
    lines = [
        "| gains | mean arrival (s) | vs paper | success | peak wheel speed (cm/s) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, ev in evaluation.items():
        lines.append(
            f"| {name.replace('_', ' ')} | {ev.mean_arrival:.3f} | "
            f"{paper / ev.mean_arrival:.2f}× | {100 * ev.success_rate:.2f} % | "
            f"{ev.peak_wheel_speed:.1f} |"
        )
    return "\n".join(lines) + "\n"


_GAIN_LABELS = {
    "kr": "k_r (cm/s)",
    "k_theta": "k_θ (rad/s)",
    "phi_m": "Φ_m (deg)",
    "r_m": "R_m (cm)",
    "r_a": "R_a (cm)",
    "r_e": "R_e (cm)",
    "alpha": "α",
}


def _plot_history(path: Path, history: dict[str, np.ndarray], config: TuneConfig) -> None:
    """Save the loss (with the temperature) and each gain against the iteration."""
    from wmr_jax.plotting import plt

    steps = np.arange(1, len(history["loss"]) + 1)
    fig, axes = plt.subplots(2, 4, figsize=(14, 6), constrained_layout=True)
    ax = axes[0, 0]
    ax.plot(steps, history["loss"], lw=0.8, color="C0")
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss (s)", color="C0")
    twin = ax.twinx()
    twin.plot(steps, history["temperature"], lw=1.0, color="C3")
    twin.set_yscale("log")
    twin.set_ylabel("temperature", color="C3")
    ax.set_title(f"loss ({config.velocity} loop)")
    paper = _gains_to_dict(PAPER_FEASIBLE_GAINS)
    for k, name in enumerate(GAIN_FIELDS):
        ax = axes.flat[k + 1]
        values = history["gains"][:, k]
        start = paper[name]
        if name == "phi_m":
            values, start = np.degrees(values), math.degrees(start)
        ax.plot(steps, values, lw=1.0)
        ax.axhline(start, ls="--", lw=0.8, color="gray", label="paper (feasible)")
        ax.set_title(_GAIN_LABELS[name])
        ax.set_xlabel("iteration")
    axes.flat[1].legend(fontsize=8)
    io.save_figure(fig, path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------- gradient cost


class GradientCost(NamedTuple):
    """Measured cost of one loss gradient against the forward pass.

    Attributes:
        poses: batch size.
        steps: control periods per run.
        remat: whether the scan body was checkpointed.
        forward_s: wall time of the jitted loss (fastest of the repeats), s.
        gradient_s: wall time of the jitted robust gradient (fastest), s.
        forward_peak_bytes: XLA's peak memory estimate of the loss.
        gradient_peak_bytes: XLA's peak memory estimate of the gradient.
    """

    poses: int
    steps: int
    remat: bool
    forward_s: float
    gradient_s: float
    forward_peak_bytes: int
    gradient_peak_bytes: int


def _peak_bytes(stats: Any) -> int:
    """Bytes the compiled program allocates: arguments, outputs and temporaries.

    XLA's own ``peak_memory_in_bytes`` leaves the temporaries out on the CPU.
    """
    return int(
        stats.argument_size_in_bytes
        + stats.output_size_in_bytes
        + stats.temp_size_in_bytes
        - stats.alias_size_in_bytes
    )


def gradient_cost(
    *,
    poses: int = 4096,
    steps: int = simulation.DEFAULT_STEPS,
    remat: bool = True,
    velocity: str = "ideal",
    temperature: float = 0.05,
    repeats: int = 5,
    seed: int = 0,
) -> GradientCost:
    """Time the loss and its gradient on ``poses`` × ``steps`` and read their peak memory.

    Peak memory is read from XLA's compile-time ``memory_analysis``:
    arguments + outputs + temporaries, what the compiled program allocates
    (the process's resident set adds the runtime and compiled code on top).

    Args:
        poses: batch size.
        steps: control periods per run.
        remat: ``jax.checkpoint`` on the scan body.
        velocity: ``"ideal"`` or ``"nonideal"``.
        temperature: smooth-law temperature.
        repeats: timed calls after a warm-up; the fastest is reported.
        seed: seed of the reference poses.
    """
    poses = _check_int("poses", poses, 1)
    steps = _check_int("steps", steps, 1)
    repeats = _check_int("repeats", repeats, 1)
    dt = simulation.DEFAULT_DT
    spec = _make_spec(
        horizon=steps * dt,
        dt=dt,
        velocity=velocity,
        substeps=simulation.DEFAULT_SUBSTEPS,
        wheel_limit="clip",
        tol_r=DEFAULT_TOL_R,
        tol_theta=DEFAULT_TOL_THETA,
        weights=LossWeights(),
        remat=remat,
    )
    dtype = simulation.float_dtype()
    robot = simulation.as_float_tree(Robot())
    refs = sample_refs(jax.random.key(seed), poses)
    init = jnp.zeros((3,), dtype)
    z = jnp.asarray(_logits(unit_from_gains(PAPER_FEASIBLE_GAINS)), dtype)
    args = (z, refs, init, robot, jnp.asarray(dt, dtype), jnp.asarray(temperature, dtype))

    def forward(z, refs, init, robot, dt, temperature):
        gains = _gains_from_logits(z, robot)
        return _batch_loss(refs, gains, init, robot, dt, spec, temperature)

    def gradient(z, refs, init, robot, dt, temperature):
        return _robust_value_and_grad(z, refs, init, robot, dt, spec, temperature, 1.0)[:2]

    results = []
    for function in (forward, gradient):
        compiled = jax.jit(function).lower(*args).compile()
        peak = _peak_bytes(compiled.memory_analysis())
        jax.block_until_ready(compiled(*args))
        times = []
        for _ in range(repeats):
            began = time.perf_counter()
            jax.block_until_ready(compiled(*args))
            times.append(time.perf_counter() - began)
        # The fastest of the repeats: on a shared machine the others measure
        # the neighbours too.
        results.append((min(times), peak))
    (forward_s, forward_peak), (gradient_s, gradient_peak) = results
    return GradientCost(
        poses, steps, bool(remat), forward_s, gradient_s, forward_peak, gradient_peak
    )


# ---------------------------------------------------------------- command line


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax tune`` to ``parser``."""
    defaults = TuneConfig()
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--velocity",
        default=defaults.velocity,
        metavar="ideal|nonideal",
        help=f"velocity loop the gains are tuned for (default {defaults.velocity})",
    )
    parser.add_argument(
        "--iters",
        default=defaults.iters,
        metavar="N",
        help=f"gradient iterations (default {defaults.iters})",
    )
    parser.add_argument(
        "--poses",
        default=defaults.poses,
        metavar="N",
        help=f"reference poses per iteration (default {defaults.poses})",
    )
    parser.add_argument(
        "--seed",
        default=defaults.seed,
        metavar="S",
        help=f"seed of the training poses and the random search (default {defaults.seed})",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue from DIR/checkpoint.npz (same settings) instead of starting over",
    )


def _int_flag(flag: str, text: Any, minimum: int, maximum: int | None = None) -> int:
    try:
        value = int(str(text), 10)
    except ValueError:
        value = None
    if value is None or value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise ValueError(f"{flag} {text!r} is not allowed; allowed: an integer >= {minimum}{upper}")
    return value


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax tune`` with parsed ``args``; return the exit status.

    Raises:
        ValueError: one line naming a bad flag, its value and what is allowed.
    """
    if args.velocity not in simulation.VELOCITY_LOOPS:
        raise ValueError(
            f"--velocity {args.velocity!r} is not allowed; allowed: "
            + " or ".join(simulation.VELOCITY_LOOPS)
        )
    config = TuneConfig(
        velocity=args.velocity,
        iters=_int_flag("--iters", args.iters, 1),
        poses=_int_flag("--poses", args.poses, 1),
        seed=_int_flag("--seed", args.seed, 0, 2**32 - 1),
    )
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {str(out)!r} is not allowed; allowed: a folder (it is a file)")
    result = tune(out, config, resume=args.resume)
    tuned = _gains_to_dict(result.gains)
    print(f"tuned gains ({config.velocity} loop) -> {out / 'tuned_gains.json'}")
    print("  " + "  ".join(f"{name}={value:.4g}" for name, value in tuned.items()))
    print(
        f"held-out evaluation, {config.eval_poses} poses (SPEC §6), hard law "
        f"-> {out / 'evaluation.json'}"
    )
    print(markdown_table(result.evaluation), end="")
    search = result.search
    extra = "" if search is None else f"; random search {search.candidates} candidates"
    print(f"tuning wall time {result.tune_wall_s:.1f} s{extra}")
    print(f"curve -> {out / 'tuning_curve.png'}")
    return 0
