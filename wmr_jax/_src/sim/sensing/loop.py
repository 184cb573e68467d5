"""The disturbed closed loop (docs/model.md §7), with or without an estimator (§9).

Arrival is judged on the true pose; the metrics stream through the scan, so
batches are bounded in memory.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks, quiet
from wmr_jax._src.model import controllers
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import loops, metrics
from wmr_jax._src.sim.loops import Options
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.sim.rollout import DEFAULT_DT, make_options, prepare, require_memory
from wmr_jax._src.sim.sensing.disturbances import Disturbance, checked_disturbance
from wmr_jax._src.sim.sensing.estimators import resolve_estimator


class ClosedLoop(NamedTuple):
    """A controller, its parameters and the estimator between it and the sensor (``load_tuned``).

    Attributes:
        controller: a ``Controller`` or its registered name.
        params: its parameters.
        estimator: ``None`` (raw feedback), a registered estimator's name or
            parameters (``ObserverParams`` / ``EKFParams``), or an
            ``Estimator``: docs/model.md §9, docs/custom_controller.md.
        robot: the ``Robot`` whose wheel budget the parameters were tuned
            within, or ``None`` where unknown.
    """

    controller: Any
    params: Any
    estimator: Any = None
    robot: Any = None


def disturbed_run(
    spec: Disturbance,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    **kwargs: Any,
) -> tuple[jax.Array, Any, Any]:
    """``loops.scan_closed_loop`` of one pose toward ``spec.ref`` under ``spec`` (no batch axes).

    Returns ``(final true pose (3,), acc, (poses, outputs, estimates) or None)``.
    """
    return loops.scan_closed_loop(
        spec.ref, params, init, robot, dt, options, disturbance=spec, **kwargs
    )


def metrics_fold(ref: jax.Array) -> loops.Fold:
    """The fold that streams the ``docs/model.md §6`` metrics of a run toward ``ref`` (3,)."""
    thresholds = metrics.Thresholds()

    def fold(acc, pose, out):
        return metrics.stream_update(acc, pose.stacked(), ref, out, thresholds, frame=pose.frame())

    return fold


def _disturbed_single(spec: Disturbance, params, estimate, init, robot, dt, options: Options):
    ref = spec.ref
    fold, acc = metrics_fold(ref), metrics.stream_start(ref.dtype)
    final, acc, _ = disturbed_run(
        spec, params, init, robot, dt, options, estimate=estimate, fold=fold, acc=acc
    )
    return metrics_result(acc, final, ref, dt)


def metrics_result(acc: Any, final: jax.Array, ref: jax.Array, dt: jax.Array) -> dict:
    """The metrics ``metrics_fold`` streamed, and the distance from ``final`` (3,) to ``ref``."""
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

    Every field of ``spec`` carries the batch axis but a scalar ``delay``;
    ``params``, ``estimate`` and ``robot`` leaves may carry it too.
    """

    one = jax.jit(single, static_argnums=6)  # traced once per run's shapes (``loops.batched``)

    def run(spec, params, estimate, init, robot, dt, options):
        spec_axes = type(spec)(0, 0, 0, 0 if jnp.ndim(spec.delay) == 1 else None)
        in_axes = (
            spec_axes,
            loops.batch_axes(params, 0),
            loops.batch_axes(estimate, 0),
            None,
            loops.batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: one(*a, options), in_axes=in_axes)(
            spec, params, estimate, init, robot, dt
        )

    return run


_disturbed_jit = loops.EntryJit(batched_disturbed(_disturbed_single), static_argnames=("options",))


def disturbed_metrics(
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
            or ``"ekf"`` (default parameters), an ``ObserverParams`` /
            ``EKFParams`` (docs/model.md §9), or an estimator of one's own
            (docs/custom_controller.md).
        init: ``(3,)`` initial pose (true and measured alike), ``[cm, cm, rad]``.
        dt: control period, s.
        robot: the nominal robot (the controller's model); default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        x64: compute in float64 (default): near the goal the polar baselines'
            bearing is rounding noise in float32.

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays, ``first_arrival`` included.

    Raises:
        ValueError: for misshapen or non-finite inputs and bad options.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        args, options = prepare_disturbed(
            disturbance, params, controller, estimator, init, dt, robot, velocity
        )
        out = _disturbed_jit(*args, options=options)
        result = PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})
        allowed = options.controller.finite_allowed(
            "disturbances, gains and dt that keep the sampled law stable (docs/model.md §4, §7)"
        )
        estimator = options.estimator
        if estimator is not None and not estimator.own:
            allowed += f", and estimates of {estimator.name!r} that stay finite"
        finite = np.isfinite(result.final_distance)
        checks.require_finite_runs(finite, args[-1].dtype, allowed=allowed)
        return result


# What disturbed_rollout keeps per run and period: the pose, v, ω and the
# estimate handed to the law (8 floats).
_DISTURBED_RECORD = (8, 0)


def prepare_disturbed(
    disturbance, params, controller, estimator, init, dt, robot, velocity, *, record=None
) -> tuple[tuple, Options]:
    """Check a batch of disturbances and the run's settings; return the jitted core's arguments.

    ``record``: ``(floats, int32s)`` kept per run and period, refused beyond
    the memory. Returns ``((spec, params, estimate, init, robot, dt), options)``.
    """
    refs, noise, mismatch, delay = checked_disturbance(disturbance)
    estimator, estimate = resolve_estimator(estimator)
    if estimator is not None:
        # A list is an array of values, one per run, not a tree of them.
        estimate = jax.tree.map(
            lambda v: np.asarray(v) if isinstance(v, list) else v,
            estimate,
            is_leaf=lambda v: isinstance(v, list),
        )
    runs = checks.common_batch_size({"gains": params, "robot": robot, "estimator": estimate})
    if record is not None:
        require_memory(max(len(refs), runs), noise.shape[1], record, disturbance)
    if len(refs) == 1 and runs > 1:
        # One disturbance shared by every run of batched parameters.
        refs, noise, mismatch = (np.repeat(a, runs, axis=0) for a in (refs, noise, mismatch))
        delay = np.repeat(delay, runs, axis=0) if delay.ndim else delay
    options = make_options(steps=noise.shape[1], velocity=velocity, controller=controller)
    refs_j, params, init, robot, dt = prepare(refs, params, init, robot, dt, options, batch=None)
    if options.velocity == "ideal":
        options = loops.for_robot(options, robot, dt)
    options = dataclasses.replace(options, max_delay=max(1, int(np.max(delay))))
    if np.ndim(init) != 1:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,)")
    dtype = dt.dtype
    # A subclass keeps its own methods (how it measures, realises, perturbs the robot).
    spec = type(disturbance)(refs_j, *(jnp.asarray(a, dtype) for a in (noise, mismatch, delay)))
    if estimator is not None:
        sizes = {"disturbance.ref": len(refs), **checks.batch_sizes({"estimator": estimate})}
        checks.require_one_batch_size(sizes)
        estimate = checks.drop_shared_axes(jax.tree.map(lambda v: jnp.asarray(v, dtype), estimate))
        options = dataclasses.replace(options, estimator=estimator)
    return (spec, params, estimate, init, robot, dt), options


def check_settings(params, controller, estimator, dt, robot, velocity, steps, x64) -> None:
    """Refuse the settings of disturbed runs as ``disturbed_metrics`` would, with no run.

    ``prepare_disturbed``'s checks on one run standing still at a reference,
    for a study to call before it draws its disturbances; the package's
    warnings are the runs' to give (``quiet``).
    """
    still = Disturbance(
        np.array([[30.0, 0.0, 0.0]]), np.zeros((1, steps, 3)), np.ones((1, 3)), np.float64(0.0)
    )
    with jax.enable_x64(checks.check_bool("x64", x64)), quiet.quiet():
        init = (0.0, 0.0, 0.0)
        prepare_disturbed(still, params, controller, estimator, init, dt, robot, velocity)


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

    Args: as for ``disturbed_metrics``.

    Returns:
        ``{"poses": (N, steps + 1, 3)`` true poses, the initial one first;
        ``"v": (N, steps)`` cm/s, ``"omega": (N, steps)`` rad/s, the command
        applied over each period (zero over the first under latency; before a
        speed limiter); ``"estimates": (N, steps, 3)``, the estimate at the end
        of each period (the measurement without an estimator; the last one
        from a noise-free measurement)``}``.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        args, options = prepare_disturbed(
            disturbance, params, controller, estimator, init, dt, robot, velocity,
            record=_DISTURBED_RECORD,
        )  # fmt: skip
        out = _trajectory_jit(*args, options=options)
        return {name: np.asarray(value) for name, value in out.items()}
