"""The project's disturbed loop driven by a compiled controller (docs/model.md §7, §9).

The robot's side of every period is the one closed-loop step's
(``loops.ClosedLoopStep.move``: the speed limiter, the disturbance's wheels
and mass, the velocity loop and the robot, the streamed metrics of
``sensing.loop.metrics_fold``), and the sensor is the disturbance's; only
the controller's side is the C one (the law, the commands in flight, the
estimator): every period the host hands the compiled controllers the poses
measured at the sample and applies the commands they sent ``latency``
periods before. One jitted, batched period per call; the C steps every run
in one foreign call.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks, io
from wmr_jax._src.export.codegen import MAX_LATENCY
from wmr_jax._src.export.compiled import CompiledController
from wmr_jax._src.sim import loops, metrics, motion
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.sim.sensing.disturbances import Disturbance
from wmr_jax._src.sim.sensing.loop import (
    ClosedLoop,
    metrics_fold,
    metrics_result,
    prepare_disturbed,
)

# What `wmr-jax export` writes beside the C: the loop it was generated from.
METADATA = "wmr_controller.json"


def _period(pose, wheel, acc, applied, noise_next, spec, robot, dt, options):
    """One period of one run: the one step's plant half (``ClosedLoopStep.move``).

    The robot moves under ``applied`` ``(v, ω)``, the command the C sent
    ``latency`` periods before (the law, the commands in flight and the
    estimator are the C's); returns the moved state and what the sensor
    reports at the end of the period, ``[x, y, θ]``.
    """
    fold = metrics_fold(spec.ref)
    step = loops.ClosedLoopStep(spec.ref, None, robot, dt, options, disturbance=spec, fold=fold)
    command = jax.lax.complex(applied[0], applied[1])
    pose, wheel, _, _, acc = step.move(pose, wheel, command, spec.ref, acc)
    return pose, wheel, acc, spec.measurement(pose, noise_next).pose().stacked()


_batched_period = jax.jit(
    jax.vmap(_period, in_axes=(0, 0, 0, 0, 0, Disturbance(0, 0, 0, None), None, None, None)),
    static_argnames=("options",),
)
_batched_result = jax.jit(
    jax.vmap(lambda acc, pose, ref, dt: metrics_result(acc, pose.stacked(), ref, dt),
             in_axes=(0, 0, 0, None))
)  # fmt: skip


def _latencies(delay: Any, n: int) -> np.ndarray:
    delay = np.asarray(delay, dtype=float)
    ok = delay.shape in ((), (n,)) and bool(
        np.all((delay >= 0) & (delay <= MAX_LATENCY) & (delay == np.round(delay)))
    )
    if not ok:
        raise ValueError(
            f"disturbance.delay = {delay!r:.80} is not allowed; allowed: whole numbers of "
            f"periods 0 to {MAX_LATENCY}, one or ({n},)"
        )
    return np.broadcast_to(delay, (n,)).astype(int)


def compiled_metrics(
    compiled: CompiledController,
    disturbance: Disturbance,
    loop: ClosedLoop,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Any = None,
    velocity: str = "ideal",
) -> PoseMetrics:
    """The ``docs/model.md §6`` metrics of disturbed runs with the compiled controller in the loop.

    The counterpart of ``disturbed_metrics`` (float64): the same runs, the
    command of each period given by the C controller instead of the JAX law
    and estimator. ``disturbance.delay`` may be any whole number of periods
    up to ``MAX_LATENCY`` (the C holds that many commands in flight).

    Args:
        compiled: the compiled controller (``compile_controller``).
        disturbance: as for ``disturbed_metrics``, ``delay`` 0, 1, 2, …
        loop: the loop the controller was generated from (its parameters
            check the run's settings as ``disturbed_metrics`` does).
        init: ``(3,)`` initial pose.
        dt: control period, s: the controller's own (``wmr_period()``).
        robot: the nominal robot; default the loop's, else ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.

    Raises:
        ValueError: for bad inputs, or a ``dt`` other than the controller's period.
    """
    if not math.isclose(float(dt), compiled.period, rel_tol=1e-12):
        raise ValueError(
            f"dt = {dt!r} is not allowed; allowed: the compiled controller's period, "
            f"{compiled.period!r} s"
        )
    if not isinstance(disturbance, Disturbance):
        raise ValueError(
            f"disturbance = {type(disturbance).__name__} is not allowed; allowed: a Disturbance"
        )
    n = np.shape(disturbance.ref)[0]
    latency = _latencies(disturbance.delay, n)
    robot = loop.robot if robot is None else robot
    limits = (getattr(robot, "accel_max", 0.0), getattr(robot, "angular_accel_max", 0.0))
    if velocity == "nonideal" and any(float(np.max(x)) > 0 for x in limits):
        raise ValueError(
            "velocity = 'nonideal' is not allowed with a robot that gives acceleration limits; "
            "allowed: 'ideal' (the C applies the robot's speed limiter, docs/model.md §4.2.2, "
            "which the non-ideal loop does not model)"
        )
    with jax.enable_x64(True):
        args, options = prepare_disturbed(
            disturbance._replace(delay=np.float64(0.0)),
            loop.params,
            loop.controller,
            None,
            init,
            dt,
            robot,
            velocity,
        )
        spec, _, _, init_j, robot_j, dt_j = args
        refs = np.asarray(spec.ref)
        noise = np.asarray(spec.noise)
        steps = noise.shape[1]
        pose = jax.vmap(motion.SplitPose.of)(jnp.broadcast_to(init_j, (n, 3)))
        wheel = jax.vmap(lambda _: motion.initial_wheel(init_j, options))(jnp.arange(n))
        acc = jax.vmap(lambda _: metrics.stream_start(init_j.dtype))(jnp.arange(n))
        compiled.start(refs, latency)
        sense = jax.vmap(lambda p, z: spec.measurement(p, z).pose().stacked())
        first = np.asarray(sense(pose, spec.noise[:, 0]))
        sent = [compiled.step(first)]
        later = np.concatenate([noise[:, 1:], np.zeros_like(noise[:, :1])], axis=1)
        rows = np.arange(n)
        for k in range(steps):
            # The command sent `latency` periods ago acts now (zero before the first).
            applied = np.zeros((n, 2))
            due = k - latency
            ok = due >= 0
            if np.any(ok):
                history = np.stack(sent)  # (k + 1, n, 2)
                applied[ok] = history[due[ok], rows[ok]]
            pose, wheel, acc, sensed = _batched_period(
                pose, wheel, acc, jnp.asarray(applied), jnp.asarray(later[:, k]),
                spec, robot_j, dt_j, options,
            )  # fmt: skip
            if k + 1 < steps:
                sent.append(compiled.step(np.asarray(sensed)))
        out = _batched_result(acc, pose, spec.ref, dt_j)
        result = PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})
    checks.require_finite_runs(
        np.isfinite(result.final_distance),
        np.dtype(np.float64),
        allowed="disturbances and a controller that keep the sampled loop stable",
    )
    return result


def read_metadata(folder: str | os.PathLike) -> dict[str, Any]:
    """The ``wmr_controller.json`` that ``wmr-jax export`` wrote beside the C."""
    path = Path(folder) / METADATA
    try:
        values = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise ValueError(
            f"folder {os.fspath(folder)!r} cannot be read: {METADATA}: {io.os_reason(err)}; "
            "allowed: a folder written by wmr-jax export"
        ) from None
    if not isinstance(values, dict) or (values.get("gains") or values.get("baseline")) is None:
        raise ValueError(f"folder {os.fspath(folder)!r}: {METADATA} holds no gains")
    return values


def exported_loop(folder: str | os.PathLike) -> tuple[ClosedLoop, dict[str, Any]]:
    """The loop a folder of ``wmr-jax export`` was generated from, and its ``wmr_controller.json``.

    Raises:
        ValueError: one line naming the folder, for a missing or bad file.
    """
    from wmr_jax._src.tuning.saved import tuned_from_values

    meta = read_metadata(folder)
    if meta.get("baseline") is not None:
        return _baseline_loop(meta["baseline"], folder), meta
    return tuned_from_values(meta["gains"], f"folder {os.fspath(folder)!r}: {METADATA}")[0], meta


def _baseline_loop(values: Any, folder: Any) -> ClosedLoop:
    """The baseline loop a ``wmr_controller.json`` records (``codegen._baseline_json``)."""
    from wmr_jax._src.model.controllers import get_controller
    from wmr_jax._src.model.robots import robot_from_values, warn_unit_slips
    from wmr_jax._src.tuning.estimation import estimator_from_json

    where = f"folder {os.fspath(folder)!r}: {METADATA}"
    try:
        controller = get_controller(values["controller"])
        params = controller.validate(controller.params_type(**values["params"]))
        estimator = values.get("estimator")
        estimator = None if estimator is None else estimator_from_json(estimator, where)
        robot = values.get("robot")
        robot = None if robot is None else robot_from_values(robot, where)
    except (KeyError, TypeError) as err:
        raise ValueError(f"{where} holds no loop ({err})") from None
    if robot is not None:
        warn_unit_slips(robot, f"{where}: robot", ros=False)
    return ClosedLoop(controller, params, estimator, robot)


def evaluate_compiled(
    compiled: CompiledController,
    loop: ClosedLoop,
    refs: Any,
    *,
    condition: str = "nominal",
    mismatch: float = 0.03,
    seed: int = 0,
    horizon: float | None = None,
    velocity: str = "ideal",
    robot: Any = None,
) -> dict[str, Any]:
    """``evaluate_loop`` of a compiled controller: the same draws, runs and figures (float64).

    ``loop`` is the loop the controller was generated from; the runs are
    those ``evaluate_loop(loop, refs, ...)`` makes, the commands the C's.
    """
    from wmr_jax._src.studies import conditions

    labels = {label: (sxy, sdeg, lat) for label, sxy, sdeg, lat in conditions.STANDARD_CONDITIONS}
    if condition not in labels:
        raise ValueError(f"condition = {condition!r} is not allowed; allowed: {', '.join(labels)}")
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    robot = conditions._study_robot(robot, {"loop": loop}, "evaluate_compiled")
    dt = compiled.period
    refs, noise, factors, horizon = conditions._runs(
        refs, None, robot, horizon, dt, mismatch, True, {"loop": loop}, velocity, seed
    )
    spec = conditions._scaled(refs, noise, factors, *labels[condition])
    m = compiled_metrics(compiled, spec, loop, dt=dt, robot=robot, velocity=velocity)
    return _figures(m, loop, refs, robot, condition, mismatch, seed, horizon, velocity, dt)


def _figures(m, loop, refs, robot, condition, mismatch, seed, horizon, velocity, dt):
    """The result dict of ``conditions.evaluate_loop``, of the compiled controller's runs."""
    from wmr_jax._src.model import controllers
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.sim.sensing.estimators import resolve_estimator
    from wmr_jax._src.studies import conditions

    estimator, _ = resolve_estimator(loop.estimator)
    row = conditions.figures(m, refs, robot, dt, horizon, condition, mismatch, seed, velocity)
    row.update(
        controller=controllers.get_controller(loop.controller).name + " (compiled C)",
        feedback="raw" if estimator is None else estimator.name,
        robot=robot_json(robot),
        dtype="float64",
        per_reference=conditions.per_reference(m, refs, horizon),
    )
    return row
