"""Judging closed loops under the standard conditions (docs/model.md §7, §9), on shared draws."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model import controllers
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.model.robots import describe_robot, robot_json, same_robot
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.sim.sensing.disturbances import (
    STANDARD_CONDITIONS,
    STANDARD_MISMATCH,
    Disturbance,
    sample_disturbance,
)
from wmr_jax._src.sim.sensing.estimators import resolve_estimator
from wmr_jax._src.sim.sensing.loop import ClosedLoop, check_settings, disturbed_metrics
from wmr_jax._src.studies.optimal import time_bounds
from wmr_jax._src.studies.robustness import (
    _scaled,
    check_levels,
    mean_median,
    named_warnings,
    settled_at_horizon,
    study_steps,
    summary_row,
)


def as_closed_loop(value: Any, controller: Any, estimator: Any, where: str) -> ClosedLoop:
    """A ``ClosedLoop`` as it is, or params of ``controller``; refused if batched."""
    loop = value if isinstance(value, ClosedLoop) else ClosedLoop(controller, value, estimator)
    allowed = "scalars: one loop (disturbed_metrics runs a batch of parameters)"
    checks.require_unbatched(loop.params, f"{where}.params", allowed)
    if not isinstance(loop.estimator, str):  # a name is its default parameters
        checks.require_unbatched(loop.estimator, f"{where}.estimator", allowed)
    return loop


def _unit_draws(key: jax.Array, refs: np.ndarray, steps: int, mismatch: float):
    """Unit noise ``(N, steps, 3)`` and wheel factors ``(N, 3)`` (mass 1) of ``key``."""
    unit = sample_disturbance(
        key, np.zeros_like(refs), steps, noise_xy=1.0, noise_theta=1.0, radius_mismatch=mismatch
    )
    factors = np.array(unit.mismatch, dtype=float)
    factors[:, 2] = 1.0  # the wheel radii only: the ideal loop has no mass
    return np.asarray(unit.noise, dtype=float), factors


def _runs(
    refs: Any,
    key: jax.Array | None,
    robot: Robot,
    horizon: Any,
    dt: float,
    mismatch: float,
    x64: Any,
    loops: Mapping[str, ClosedLoop] | None = None,
    velocity: str = "ideal",
    seed: int | None = None,
):
    """What every study here runs: ``(refs (N, 3), unit noise, wheel factors, horizon s)``.

    ``key``: a ``jax.random`` key, or ``None`` for one of ``seed`` (checked).
    The ``loops`` the study runs are checked first, before anything is drawn.
    """
    if seed is None:
        checks.check_key("key", key)
    steps, horizon = study_steps(robot, horizon, dt)
    for loop in (loops or {}).values():
        check_settings(
            loop.params, loop.controller, loop.estimator, dt, robot, velocity, steps, x64
        )
    with jax.enable_x64(checks.check_bool("x64", x64)):  # not rounded to float32 first
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    key = key if seed is None else jax.random.key(seed)
    noise, factors = _unit_draws(key, refs, steps, mismatch)
    return refs, noise, factors, horizon


# The model robot's row: no mismatch, no noise, no latency (docs/model.md §9).
MODEL_ROBOT = "model robot"


def _standard_table(factors: np.ndarray, noise: Any) -> list[tuple]:
    """The model robot, then each standard condition: ``(label, σ_xy cm, σ_θ °, latency, wheels)``.

    ``factors``: the runs' wheel factors ``(N, 3)``; ``noise``: ``(σ_xy, σ_θ)`` of the noisy ones.
    """
    table = [(MODEL_ROBOT, 0.0, 0.0, False, np.ones_like(factors))]
    for label, sxy, sdeg, latency in STANDARD_CONDITIONS:
        if noise is not None and sxy:
            sxy, sdeg = noise
        table.append((label, sxy, sdeg, latency, factors))
    return table


def standard_conditions(
    params_by_name: dict[str, Any],
    refs: Any,
    key: jax.Array,
    *,
    controller: Any = controllers.SHIM_SUNG,
    estimator: Any = None,
    mismatch: float = STANDARD_MISMATCH,
    dt: float = DEFAULT_DT,
    x64: bool = True,
    robot: Robot | None = None,
    horizon: float | None = None,
    noise: tuple[float, float] | None = None,
) -> list[dict[str, Any]]:
    """Judge closed loops under the standard conditions of docs/model.md §7 and §9 (hard law).

    The model robot (no mismatch, noise or latency), then nominal, latency,
    noise and both, each with every wheel's radius off by
    ``δ ~ U(−mismatch, mismatch)`` per run. Ideal loop; every set and condition
    sees the same draws (``sample_disturbance`` of ``key``).

    Args:
        params_by_name: ``{label: params of controller}`` or ``{label:
            ClosedLoop}``; each one loop, without a batch axis.
        refs: ``(N, 3)`` reference poses (held-out poses of ``docs/model.md §6``).
        key: ``jax.random`` key of the noise and the mismatch.
        controller: a ``Controller`` or its registered name, for plain params.
        estimator: the estimator of plain params (``None``: raw feedback).
        mismatch: bound of each wheel's relative radius error, ``[0, 1)``.
        dt: control period, s.
        x64: compute in float64.
        robot: the robot of every run; default the loops' own, else
            ``Robot()``. A loop tuned for another robot is refused.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.
        noise: ``(σ_xy cm, σ_θ degrees)`` of the noise and both conditions;
            default the standard 0.5 cm, 1°.

    Returns:
        One row per (condition, set): ``condition``, ``gains``, ``feedback``,
        ``success``, the mean and median arrival of the successes (``inf`` if
        none), ``mean final distance cm``, ``peak wheel cm/s``, ``mismatch``,
        ``runs``, ``settled at horizon``, ``mean arrival, not at horizon s``,
        ``horizon s``.
    """
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    if noise is not None:
        if not isinstance(noise, (tuple, list)) or len(noise) != 2:
            raise ValueError(
                f"noise = {noise!r:.80} is not allowed; allowed: (σ_xy cm, σ_θ degrees) or None"
            )
        noise = tuple(
            checks.check_number(f"noise[{i}]", v, closed=True, unit=u)
            for i, (v, u) in enumerate(zip(noise, ("cm", "degrees"), strict=True))
        )
    sets, robot = _loops(params_by_name, "params_by_name", controller, estimator, robot)
    refs, unit, factors, horizon = _runs(refs, key, robot, horizon, dt, mismatch, x64, sets)
    rows, said = [], set()
    for label, sxy, sdeg, latency, wheels in _standard_table(factors, noise):
        spec = _scaled(refs, unit, wheels, sxy, sdeg, latency)
        for name, loop in sets.items():
            with named_warnings(name if len(sets) > 1 else None, said):
                row, m = _judged(spec, loop, dt, robot, x64, horizon)
            rows.append(
                {
                    "condition": label,
                    "gains": name,
                    **_columns(row, "feedback", "success", "mean arrival s", "median arrival s"),
                    "mean final distance cm": row["mean final distance cm"],
                    "peak wheel cm/s": float(np.max(m.peak_wheel)),
                    "mismatch": 0.0 if label == MODEL_ROBOT else mismatch,
                    "runs": len(refs),
                    **_columns(row, *_LATE_COLUMNS),
                }
            )
    return rows


def _loops(given: Any, name: str, controller: Any, estimator: Any, robot: Any):
    """The loops of a study, each checked before any run, and the study's robot."""
    if not isinstance(given, Mapping) or not given:
        raise ValueError(
            f"{name} = {given!r:.80} is not allowed; allowed: a dict of label -> parameters, "
            "ClosedLoop or Gains, at least one"
        )
    sets = {
        label: as_closed_loop(value, controller, estimator, f"{name}[{label!r}]")
        for label, value in given.items()
    }
    for loop in sets.values():
        resolve_estimator(loop.estimator)
        controllers.get_controller(loop.controller)
    return sets, _study_robot(robot, sets, name)


def _judged(spec: Disturbance, loop: ClosedLoop, dt, robot, x64, horizon, velocity="ideal"):
    """``summary_row`` of one loop's runs, with its ``feedback``, and the runs' metrics."""
    m = disturbed_metrics(
        spec, loop.params, controller=loop.controller, estimator=loop.estimator,
        dt=dt, robot=robot, velocity=velocity, x64=x64,
    )  # fmt: skip
    used, _ = resolve_estimator(loop.estimator)
    row = {"feedback": "raw" if used is None else used.name, **summary_row(m, horizon)}
    return {**row, "horizon s": horizon}, m


# What every row of these studies ends with: the runs settled only at the horizon.
_LATE_COLUMNS = ("settled at horizon", "mean arrival, not at horizon s", "horizon s")


def _columns(row: dict[str, Any], *keys: str) -> dict[str, Any]:
    return {key: row[key] for key in keys}


def _study_robot(robot: Any, loops: Mapping[str, ClosedLoop], name: str) -> Robot:
    """``robot``, else the one the ``loops`` record, else the paper's; other robots refused."""
    recorded = {label: loop.robot for label, loop in loops.items() if loop.robot is not None}
    if robot is None and recorded:
        robot = next(iter(recorded.values()))
    study = validate_one_robot(robot, "the study")
    for label, tuned in recorded.items():
        tuned = validate_one_robot(tuned, f"{name}[{label!r}].robot")
        if not same_robot(tuned, study):
            raise ValueError(
                f"{name}[{label!r}] was tuned for {describe_robot(tuned)}, which is not allowed "
                f"in a study of {describe_robot(study)}; allowed: loops tuned for the study's "
                "robot, or with no robot recorded"
            )
    return study


def evaluate_loop(
    loop: Any,
    refs: Any,
    *,
    condition: str = "nominal",
    mismatch: float = STANDARD_MISMATCH,
    seed: int = 0,
    horizon: float | None = None,
    velocity: str = "ideal",
    dt: float = DEFAULT_DT,
    x64: bool = True,
    robot: Robot | None = None,
    identified: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Judge one closed loop on the user's own references under one standard condition.

    The robot starts at the origin facing +x; hard law; the metrics of
    docs/model.md §6 on the true pose, with the draws of
    ``standard_conditions`` from ``seed``.

    Args:
        loop: a ``ClosedLoop`` or ``Gains`` (Shim–Sung, raw feedback).
        refs: ``(N, 3)`` references ``[x cm, y cm, θ rad]``.
        condition: ``"nominal"``, ``"latency"``, ``"noise"`` or ``"both"``.
        mismatch, horizon, dt, x64: as ``standard_conditions``.
        seed: seed of the draws, an integer in ``[0, 2³² − 1]``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        robot: the robot; default the loop's own, else ``Robot()``.
        identified: the content of an ``identified.json`` whose base is
            ``robot``: the runs are on the identified robot while the loop
            believes ``robot``; ``condition`` must be ``"nominal"``. The
            result's condition is then ``"identified"``, its mismatch the
            largest wheel scale's departure from 1.

    Returns:
        ``figures``'s dict with ``controller``, ``feedback``, ``robot``,
        ``dtype`` and ``per_reference``: one ``{"ref", "success",
        "arrival_s" (None if not arrived), "final_distance_cm",
        "settled_at_horizon"}`` per reference, in order.
    """
    labels = {label: (sxy, sdeg, lat) for label, sxy, sdeg, lat in STANDARD_CONDITIONS}
    if condition not in labels:
        raise ValueError(f"condition = {condition!r} is not allowed; allowed: {', '.join(labels)}")
    loop = as_closed_loop(loop, controllers.SHIM_SUNG, None, "loop")
    estimator, _ = resolve_estimator(loop.estimator)
    controller = controllers.get_controller(loop.controller)
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    robot = _study_robot(robot, {"loop": loop}, "evaluate_loop")
    if identified is not None:
        from wmr_jax._src.identify.closed_loop import check_identified

        check_identified(identified, "identified")
    refs, noise, factors, horizon = _runs(
        refs, None, robot, horizon, dt, mismatch, x64, {"loop": loop}, velocity, seed
    )
    if identified is None:
        spec = _scaled(refs, noise, factors, *labels[condition])
        _, m = _judged(spec, loop, dt, robot, x64, horizon, velocity)
    else:
        m, condition, mismatch = _on_identified(
            identified, condition, refs, noise, loop, controller, dt, robot, velocity, x64
        )
    return {
        **figures(m, refs, robot, dt, horizon, condition, mismatch, seed, velocity),
        "controller": controller.name,
        "feedback": "raw" if estimator is None else estimator.name,
        "robot": robot_json(robot),
        "dtype": "float64" if x64 else "float32",
        "per_reference": per_reference(m, refs, horizon),
    }


def per_reference(m: Any, refs: Any, horizon: float) -> list[dict[str, Any]]:
    """Each run's reference, arrival, final distance and whether it settled only at the horizon."""
    late = settled_at_horizon(m, horizon)
    return [
        {
            "ref": [float(v) for v in ref],
            "success": bool(ok),
            "arrival_s": float(t) if ok else None,
            "final_distance_cm": float(d),
            "settled_at_horizon": bool(s),
        }
        for ref, ok, t, d, s in zip(
            np.asarray(refs), m.success, m.arrival, m.final_distance, late, strict=True
        )
    ]


def figures(m, refs, robot, dt, horizon, condition, mismatch, seed, velocity) -> dict[str, Any]:
    """The figures of one condition's runs and the settings that drew them.

    The peak wheel speed is within ``v_max`` when every rim stays within
    ``v_max (1 + mismatch)``.
    """
    mean = median = optimal = None
    if m.success.any():
        mean, median = mean_median(m.arrival[m.success])
        optimal = float(np.mean(time_bounds(refs[m.success], robot=robot, dt=dt).turn_drive_turn))
    peak = float(np.max(m.peak_wheel))
    return {
        "success": float(m.success.mean()),
        "mean_arrival_s": mean,
        "median_arrival_s": median,
        "settled_at_horizon": float(settled_at_horizon(m, horizon).mean()),
        "peak_wheel_speed": peak,
        "v_max": float(robot.v_max),
        "peak_wheel_speed_ok": bool(peak <= float(robot.v_max) * (1.0 + mismatch) * (1 + 1e-6)),
        "turn_drive_turn_s": optimal,
        "vs_turn_drive_turn": None if optimal is None else mean / optimal,
        "n": len(refs),
        "condition": condition,
        "mismatch": mismatch,
        "seed": seed,
        "horizon_s": horizon,
        "velocity": velocity,
    }


def _on_identified(identified, condition, refs, noise, loop, controller, dt, robot, velocity, x64):
    """``evaluate_loop``'s metrics, condition and mismatch on an identified robot."""
    from wmr_jax._src.identify.closed_loop import identified_metrics

    if condition != "nominal":
        raise ValueError(
            f"condition = {condition!r} is not allowed on an identified robot; allowed: "
            "nominal (its latency and tracker noise are the identified ones)"
        )
    sigma = identified["noise"]
    sdeg = math.degrees(sigma["sigma_theta"])
    spec = _scaled(refs, noise, np.ones((len(refs), 3)), sigma["sigma_xy"], sdeg, False)
    m = identified_metrics(
        spec, loop.params, identified=dict(identified), controller=controller,
        estimator=loop.estimator, dt=dt, robot=robot, velocity=velocity, x64=x64,
    )  # fmt: skip
    scale = identified["wheel_scale"]
    return m, "identified", max(abs(scale["left"] - 1.0), abs(scale["right"] - 1.0))


# σ_xy of the noise-level curve, cm (σ_θ = 2° per cm, as the standard 0.5 cm and 1°).
NOISE_CURVE_XY = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0)
_DEG_PER_CM = 2.0


def noise_curve(
    loops_by_name: dict[str, Any],
    refs: Any,
    key: jax.Array,
    *,
    noise_xy: Sequence[float] = NOISE_CURVE_XY,
    mismatch: float = STANDARD_MISMATCH,
    latency: bool = False,
    dt: float = DEFAULT_DT,
    x64: bool = True,
    robot: Robot | None = None,
    horizon: float | None = None,
) -> list[dict[str, Any]]:
    """Success and mean arrival of closed loops against the level of pose noise.

    ``σ_θ`` follows ``σ_xy`` at 2° per cm, as the standard conditions; the
    draws are shared by every loop and level, as in ``standard_conditions``.

    Args:
        loops_by_name: ``{label: ClosedLoop or Shim–Sung Gains (raw feedback)}``.
        refs: ``(N, 3)`` references (held-out poses of docs/model.md §6).
        key: ``jax.random`` key of the draws.
        noise_xy: the levels of ``σ_xy``, cm, each in ``[0, 1e6]``.
        mismatch, dt, x64, robot, horizon: as ``standard_conditions``.
        latency: one sample of latency in every run.

    Returns:
        One row per (loop, level): ``gains``, ``feedback``, ``noise xy cm``,
        ``noise theta deg``, ``success``, ``mean arrival s``, ``mismatch``,
        ``latency``, ``runs``, ``settled at horizon``, ``mean arrival, not at
        horizon s``, ``horizon s``.
    """
    levels, _ = check_levels(list(noise_xy), [_DEG_PER_CM * float(x) for x in noise_xy])
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    latency = checks.check_bool("latency", latency)
    sets, robot = _loops(loops_by_name, "loops_by_name", controllers.SHIM_SUNG, None, robot)
    refs, noise, factors, horizon = _runs(refs, key, robot, horizon, dt, mismatch, x64, sets)
    rows, said = [], set()
    for name, loop in sets.items():
        for sxy in levels:
            sdeg = _DEG_PER_CM * sxy
            spec = _scaled(refs, noise, factors, sxy, sdeg, latency)
            with named_warnings(name if len(sets) > 1 else None, said):
                row, _ = _judged(spec, loop, dt, robot, x64, horizon)
            rows.append(
                {
                    "gains": name,
                    "feedback": row["feedback"],
                    "noise xy cm": sxy,
                    "noise theta deg": sdeg,
                    **_columns(row, "success", "mean arrival s"),
                    "mismatch": mismatch,
                    "latency": latency,
                    "runs": len(refs),
                    **_columns(row, *_LATE_COLUMNS),
                }
            )
    return rows
