"""The disturbed closed loop (docs/model.md §7), with or without an estimator (§9).

One closed loop per run, with four departures from the nominal one, all
held in a ``sensing.disturbances.Disturbance``:

* **Pose-measurement noise.** The controller's side sees ``pose + n_k``;
  arrival is judged on the true pose.
* **Wheel-radius mismatch** and **mass mismatch** (``disturbances.realised``).
* **One-sample latency.** The command computed at sample ``k`` is applied over
  period ``k + 1`` (zero over the first period).

Between the measurement and the law sits the loop's estimator
(``Options.estimator``, docs/model.md §9): ``None`` hands the law the raw
measurement, as before estimators existed (bit for bit); an estimator
predicts over each period with the command applied, corrects toward the
measurement, and under latency the law sees its estimate rolled forward over
the command in flight (compensation). With no noise, no mismatch and no
latency the run is the nominal rollout, and its metrics those of
``docs/model.md §6`` (tested). The metrics stream through the scan
(``metrics.stream_update``), so batches are bounded in memory.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks, controllers, loops, metrics
from wmr_jax._src import rollout as simulation
from wmr_jax._src.loops import Options, StepOutput
from wmr_jax._src.metrics import PoseMetrics
from wmr_jax._src.params import Robot
from wmr_jax._src.rollout import DEFAULT_DT
from wmr_jax._src.sensing.disturbances import (
    Disturbance,
    checked_disturbance,
    measured,
    measurement,
    realised,
)
from wmr_jax._src.sensing.estimators import resolve_estimator

__all__ = [
    "ClosedLoop",
    "batched_disturbed",
    "disturbed_rollout",
    "disturbed_run",
    "perturbed_metrics",
    "prepare_disturbed",
]


class ClosedLoop(NamedTuple):
    """A controller, its parameters and the estimator between it and the sensor.

    What ``load_tuned`` returns and what the studies of sensed loops take.

    Attributes:
        controller: a ``Controller`` or its registered name.
        params: its parameters.
        estimator: ``None`` (raw feedback), an estimator's name, or its
            parameters (``ObserverParams`` / ``EKFParams``), docs/model.md §9.
        robot: the ``Robot`` the parameters were tuned for (their wheel
            budget ``k_r + L k_θ ≤ V_max`` is that robot's), or ``None``
            where unknown (files from before robots were recorded).
    """

    controller: Any
    params: Any
    estimator: Any = None
    robot: Any = None


def _select(flag: jax.Array, on_true: Any, on_false: Any) -> Any:
    """``on_true`` where ``flag`` else ``on_false``, leaf by leaf (pytrees of one structure)."""
    return jax.tree.map(lambda a, b: jnp.where(flag, a, b), on_true, on_false)


def disturbed_run(
    spec: Disturbance,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    estimate: Any = None,
    fold: loops.Fold | None = None,
    acc: Any = None,
    record: bool = False,
) -> tuple[jax.Array, Any, Any]:
    """Run one pose under its ``Disturbance`` (docs/model.md §7, §9); the one disturbed loop.

    The robustness Monte Carlo, the standard conditions and the robust tuner
    all run this. Over period ``k`` the robot moves under the command
    computed at sample ``k`` (``delay`` 0) or ``k − 1`` (``delay`` 1; zero over
    the first period), its rims scaled by the wheel-radius factors; in the
    non-ideal loop the true robot's mass is ``M`` times the mass factor while
    the wheel controller keeps the nominal model. The law sees the
    measurement (``options.estimator`` ``None``) or the estimator's
    estimate, compensated for latency. Arrival is judged on the true pose.

    With ``options.accel_limit`` (ideal loop; ``prepare_disturbed`` sets it
    for a robot that gives acceleration limits, docs/model.md §4.2.2) the
    command applied passes through the robot's speed limiter before the
    wheels' radii scale it, and the estimator predicts with what the
    limiter let through (its model is the ideal robot, limiter included);
    without it the run is bit for bit what it was before limiters existed.

    Args:
        spec: the disturbance of this run (no batch axes; ``noise (steps, 3)``).
        params: the controller's parameters.
        init: ``(3,)`` initial pose.
        robot: the nominal robot (the controller's and estimator's model).
        dt: control period, s.
        options: static options; ``options.temperature`` selects the relaxed
            law, ``options.estimator`` the estimator, ``options.accel_limit``
            the speed limiter.
        estimate: the estimator's parameters (unused without one).
        fold: ``fold(acc, true pose (a loops.SplitPose), StepOutput) -> acc``
            after every period.
        acc: the fold's initial accumulator.
        record: also return every true pose ``(steps, 3)``, ``StepOutput`` and
            the pose the estimator holds at each sample (the measurement
            without one) ``(steps, 3)``.

    Returns:
        ``(final true pose (3,), acc, (poses, outputs, estimates) or None)``.
    """
    ref = spec.ref
    true_robot = robot.replace(body_mass=robot.body_mass * spec.mismatch[2])
    estimator = options.estimator
    if estimator is None:
        return _raw_run(spec, params, init, robot, true_robot, dt, options, fold, acc, record)
    limiter, moving = _limiter(options)
    compensate = estimate.compensate
    late = spec.delay > 0

    def law_input(state, in_flight: loops.ArcMove) -> loops.SplitPose:
        """The estimate, rolled over the command in flight under latency (compensation)."""
        if not compensate:
            return state.pose
        return _select(late, loops.ideal_move(state.pose, in_flight), state.pose)

    def body(carry, noise_next):
        pose, wheel, fresh, held, held_move, state, acc = carry
        applied = jnp.where(late, held, fresh)
        if limiter:
            # The estimator knows what its limiter lets through: it predicts
            # with that, and rolls its estimate over the command in flight as
            # the limiter will let it through next period.
            followed, wheel = _followed(wheel, applied, robot, dt)
            move = loops.ArcMove.of(followed.real, followed.imag, dt)
        else:
            # The estimator's prediction moves its estimate by the applied
            # command's arc; under latency the command now in flight is
            # ``fresh``, whose arc is the next prediction's too (carried as
            # ``held_move``). The arc is computed here, from the carried
            # command, not where the law returns it: XLA would fuse the law
            # into each of the arc's parts and compute it four times.
            fresh_move = loops.ArcMove.of(fresh.real, fresh.imag, dt)
            followed, move = applied, _select(late, held_move, fresh_move)
        target = realised(followed, spec.mismatch, robot)
        pose, wheel, rims, distance = loops.advance_period(
            pose, wheel, target, true_robot, dt, moving, model=robot
        )
        out = StepOutput(applied.real, applied.imag, jnp.int32(-1), rims, distance)
        if fold is not None:
            acc = fold(acc, pose, out)
        sensed = measurement(pose, noise_next)
        predicted = loops.ideal_move(state.pose, move)
        state = estimator.update(state, predicted, followed, sensed, ref, estimate, robot, dt)
        if limiter:
            in_flight = _followed(wheel, fresh, robot, dt)[0]
            in_flight = loops.ArcMove.of(in_flight.real, in_flight.imag, dt)
        else:
            in_flight = held_move = fresh_move
        command = loops.split_command(law_input(state, in_flight), ref, params, options)
        recorded = (pose.stacked(), out, state.pose.stacked()) if record else None
        return (pose, wheel, command, fresh, held_move, state, acc), recorded

    pose = loops.SplitPose.of(init)
    # The estimate starts from the first measurement (docs/model.md §9); no
    # command is in flight before the first sample (a move of zero).
    state = estimator.start(measured(pose, spec.noise[0]), estimate, robot)
    zero = jnp.zeros((), init.dtype)
    still = loops.ArcMove.of(zero, zero, dt)
    first = loops.split_command(law_input(state, still), ref, params, options)
    later = jnp.concatenate([spec.noise[1:], jnp.zeros_like(spec.noise[:1])])
    wheel = loops.initial_wheel(init, options)
    carry = (pose, wheel, first, jnp.zeros_like(first), still, state, acc)
    step = loops.remat(body) if options.remat else body
    (pose, *_, acc), ys = jax.lax.scan(step, carry, later)
    return pose.stacked(), acc, ys


def _limiter(options: Options) -> tuple[bool, Options]:
    """Whether the run has the ideal loop's speed limiter, and the options that move the robot.

    The disturbed loop applies the limiter itself, to the command sent and
    before the wheels' radii realise it (a base's limiter is software; the
    mismatch is in its wheels); the robot then follows what comes out
    (``loops.advance_period`` with the limiter off).
    """
    limiter = options.velocity == "ideal" and options.accel_limit
    return limiter, dataclasses.replace(options, accel_limit=False) if limiter else options


def _followed(wheel: loops.HeldCommand, applied: jax.Array, robot: Robot, dt: jax.Array):
    """``applied`` (``v + i ω``) after the speed limiter in state ``wheel``; its new state."""
    v, omega = loops.speed_limit(wheel, applied.real, applied.imag, robot, dt)
    return jax.lax.complex(v, omega), loops.HeldCommand(v, omega)


def _raw_run(spec, params, init, robot, true_robot, dt, options, fold, acc, record):
    """``disturbed_run`` without an estimator: the law sees each measurement itself."""
    ref = spec.ref
    limiter, moving = _limiter(options)

    def body(carry, noise_next):
        pose, wheel, fresh, held, acc = carry
        applied = jnp.where(spec.delay > 0, held, fresh)
        followed = applied
        if limiter:
            followed, wheel = _followed(wheel, applied, robot, dt)
        target = realised(followed, spec.mismatch, robot)
        pose, wheel, rims, distance = loops.advance_period(
            pose, wheel, target, true_robot, dt, moving, model=robot
        )
        out = StepOutput(applied.real, applied.imag, jnp.int32(-1), rims, distance)
        if fold is not None:
            acc = fold(acc, pose, out)
        sensed = measured(pose, noise_next)
        command = loops.split_command(sensed, ref, params, options)
        recorded = (pose.stacked(), out, sensed.stacked()) if record else None
        return (pose, wheel, command, fresh, acc), recorded

    pose = loops.SplitPose.of(init)
    first = loops.split_command(measured(pose, spec.noise[0]), ref, params, options)
    # The measurement at sample k + 1 is taken at the end of period k; the
    # last period's is never used.
    later = jnp.concatenate([spec.noise[1:], jnp.zeros_like(spec.noise[:1])])
    carry = (pose, loops.initial_wheel(init, options), first, jnp.zeros_like(first), acc)
    step = loops.remat(body) if options.remat else body
    (pose, _, _, _, acc), ys = jax.lax.scan(step, carry, later)
    return pose.stacked(), acc, ys


def _perturbed_single(spec: Disturbance, params, estimate, init, robot, dt, options: Options):
    """Run one pose under its ``Disturbance``, streaming the ``docs/model.md §6`` metrics."""
    ref = spec.ref
    thresholds = metrics.Thresholds()

    def fold(acc, pose, out):
        return metrics.stream_update(acc, pose.stacked(), ref, out, thresholds, frame=pose.frame())

    final, acc, _ = disturbed_run(
        spec,
        params,
        init,
        robot,
        dt,
        options,
        estimate=estimate,
        fold=fold,
        acc=metrics.stream_start(ref.dtype),
    )
    result = metrics.stream_result(acc, dt)
    d = final[:2] - ref[:2]
    return {
        "arrival": result["arrival_time"],
        "path": result["path_length"],
        "peak_wheel": result["peak_wheel_speed"],
        "zigzag": result["zigzags"],
        "final_distance": jnp.sqrt(jnp.sum(d * d)),
        "first_arrival": result["first_arrival"],
    }


def batched_disturbed(single):
    """Lift ``single(spec, params, estimate, init, robot, dt, options)`` over disturbances.

    Every field of ``spec`` carries the batch axis, except a scalar ``delay``
    (shared); ``params``, ``estimate`` and ``robot`` leaves may carry it too.
    """

    def run(spec, params, estimate, init, robot, dt, options):
        spec_axes = Disturbance(0, 0, 0, 0 if jnp.ndim(spec.delay) == 1 else None)
        in_axes = (
            spec_axes,
            loops.batch_axes(params, 0),
            loops.batch_axes(estimate, 0),
            None,
            loops.batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: single(*a, options), in_axes=in_axes)(
            spec, params, estimate, init, robot, dt
        )

    return run


_perturbed_jit = loops.EntryJit(batched_disturbed(_perturbed_single), static_argnames=("options",))


def perturbed_metrics(
    disturbance: Disturbance,
    params: Any = None,
    *,
    controller: Any = controllers.SHIM_SUNG,
    estimator: Any = None,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    x64: bool = True,
) -> PoseMetrics:
    """Return the ``docs/model.md §6`` metrics of a batch of disturbed runs.

    Args:
        disturbance: a ``Disturbance`` with a leading batch axis ``N`` on
            every field but ``delay`` (a scalar); ``noise`` is
            ``(N, steps, 3)`` and sets the number of periods.
        params: the controller's parameters (its defaults if ``None``).
        controller: a ``Controller`` or its registered name.
        estimator: ``None`` (the law sees the raw measurement), ``"observer"``
            or ``"ekf"`` (default parameters), or an ``ObserverParams`` /
            ``EKFParams`` (docs/model.md §9).
        init: ``(3,)`` initial pose (true and measured alike), ``[cm, cm, rad]``.
        dt: control period, s.
        robot: the nominal robot (the controller's model); default ``Robot()``.
            Its acceleration limits, where above 0, limit the ideal loop's
            commands (docs/model.md §4.2.2).
        velocity: ``"ideal"`` or ``"nonideal"``.
        x64: compute in float64 (default): the polar baselines' bearing is
            rounding noise near the goal in float32.

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays, ``first_arrival`` included.

    Raises:
        ValueError: for misshapen or non-finite inputs and bad options.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        args, options = prepare_disturbed(
            disturbance, params, controller, estimator, init, dt, robot, velocity
        )
        out = _perturbed_jit(*args, options=options)
        result = PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})
        checks.require_finite_runs(
            np.isfinite(result.final_distance),
            args[-1].dtype,
            allowed="disturbances, gains and dt that keep the sampled law stable "
            "(docs/model.md §4, §7)",
        )
        return result


# What disturbed_rollout keeps per run and period: the pose, v, ω and the
# estimate handed to the law (8 floats).
_DISTURBED_RECORD = (8, 0)


def prepare_disturbed(
    disturbance, params, controller, estimator, init, dt, robot, velocity, *, record=None
) -> tuple[tuple, Options]:
    """Check a batch of disturbances and the run's settings; return the jitted core's arguments.

    ``record``: ``(floats, int32s)`` the caller keeps per run and period, for
    a run that keeps every period: one larger than the memory is refused
    before anything grows with the runs.

    Returns:
        ``((spec, params, estimate, init, robot, dt), options)``.
    """
    refs, noise, mismatch, delay = checked_disturbance(disturbance)
    estimator, estimate = resolve_estimator(estimator)
    if estimator is not None:
        # One value per run, or one for all: as the gains, before any tracing
        # (a list is an array of values, as everywhere, not a tree of them).
        estimate = jax.tree.map(
            lambda v: np.asarray(v) if isinstance(v, list) else v,
            estimate,
            is_leaf=lambda v: isinstance(v, list),
        )
    runs = checks.common_batch_size({"gains": params, "robot": robot, "estimator": estimate})
    if record is not None:
        simulation.require_memory(max(len(refs), runs), noise.shape[1], record, disturbance)
    if len(refs) == 1 and runs > 1:
        # One disturbance shared by every run of batched parameters, as a
        # batch axis of size 1 is everywhere (README: the Python API).
        refs, noise, mismatch = (np.repeat(a, runs, axis=0) for a in (refs, noise, mismatch))
        delay = np.repeat(delay, runs, axis=0) if delay.ndim else delay
    options = simulation.make_options(
        steps=noise.shape[1], velocity=velocity, controller=controller
    )
    refs_j, params, init, robot, dt = simulation.prepare(
        refs, params, init, robot, dt, options, batch=None
    )
    if options.velocity == "ideal":
        # The robot's speed limiter, as in the rollouts (docs/model.md §4.2.2).
        options = loops.for_robot(options, robot, dt)
    if np.ndim(init) != 1:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,)")
    dtype = dt.dtype
    spec = Disturbance(
        refs_j,
        jnp.asarray(noise, dtype),
        jnp.asarray(mismatch, dtype),
        jnp.asarray(delay, dtype),
    )
    if estimator is not None:
        sizes = {"disturbance.ref": len(refs), **checks.batch_sizes({"estimator": estimate})}
        checks.require_one_batch_size(sizes)

        def shared(leaf):  # an axis of size 1 is every run's value
            leaf = jnp.asarray(leaf, dtype)
            return leaf[0] if leaf.ndim >= 1 and leaf.shape[0] == 1 else leaf

        estimate = jax.tree.map(shared, estimate)
        options = dataclasses.replace(options, estimator=estimator)
    return (spec, params, estimate, init, robot, dt), options


def _disturbed_trajectory(spec, params, estimate, init, robot, dt, options):
    _, _, (poses, out, held) = disturbed_run(
        spec, params, init, robot, dt, options, estimate=estimate, record=True
    )
    return {
        "poses": jnp.concatenate([init[None], poses]),
        "v": out.v,
        "omega": out.omega,
        "estimates": held,
    }


_trajectory_jit = loops.EntryJit(
    batched_disturbed(_disturbed_trajectory), static_argnames=("options",)
)


def disturbed_rollout(
    disturbance: Disturbance,
    params: Any = None,
    *,
    controller: Any = controllers.SHIM_SUNG,
    estimator: Any = None,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    x64: bool = True,
) -> dict[str, np.ndarray]:
    """Return the true poses, estimates and applied commands of disturbed runs (docs/model.md §7).

    Args: as for ``perturbed_metrics``.

    Returns:
        ``{"poses": (N, steps + 1, 3) true poses, the initial one first,
        "v": (N, steps) cm/s, "omega": (N, steps) rad/s``: the command
        applied over each period (zero over the first one under latency;
        before a speed limiter, as a ``Trajectory``'s), ``"estimates": (N,
        steps, 3)``: the estimate of the pose at the end of each period (the
        measurement itself without an estimator); the last one follows a
        noise-free measurement, since no command uses it``}``.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        args, options = prepare_disturbed(
            disturbance, params, controller, estimator, init, dt, robot, velocity,
            record=_DISTURBED_RECORD,
        )  # fmt: skip
        out = _trajectory_jit(*args, options=options)
        return {name: np.asarray(value) for name, value in out.items()}
