"""Robustness Monte Carlo and the standard conditions (docs/model.md §7, §9).

The studies of the disturbed loop (``sensing.loop``): success and arrival
against the level of pose noise, with wheel-radius and mass mismatch and
latency (``monte_carlo``, ``robustness_study``), and parameter sets judged
under the standard conditions (``standard_conditions``), raw feedback or an
estimator alike. The engine returns values; ``wmr_jax.report`` draws and
writes them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from wmr_jax._src import checks, controllers
from wmr_jax._src.metrics import PoseMetrics
from wmr_jax._src.poses import HORIZON_S, horizon_steps
from wmr_jax._src.rollout import DEFAULT_DT
from wmr_jax._src.sensing.disturbances import (
    STANDARD_CONDITIONS,
    STANDARD_MISMATCH,
    Disturbance,
    draw_disturbances,
    sample_disturbance,
)
from wmr_jax._src.sensing.estimators import resolve_estimator
from wmr_jax._src.sensing.loop import ClosedLoop, perturbed_metrics

__all__ = [
    "DEFAULT_NOISE_DEG",
    "DEFAULT_NOISE_XY",
    "MODEL_ROBOT",
    "NOISE_CURVE_XY",
    "noise_curve",
    "ROBUSTNESS_CONDITIONS",
    "evaluate_loop",
    "monte_carlo",
    "robustness_study",
    "standard_conditions",
    "summary_row",
]

DEFAULT_NOISE_XY = (0.0, 0.25, 0.5, 1.0, 2.0)  # σ of x and y, cm
DEFAULT_NOISE_DEG = (0.0, 0.5, 1.0, 2.0, 4.0)  # σ of θ, degrees, paired with the above

# The study's conditions (docs/model.md §7):
# (label, wheel-radius mismatch bound, body-mass mismatch bound, one-sample latency).
ROBUSTNESS_CONDITIONS = (
    ("noise", 0.0, 0.0, False),
    ("noise + mismatch", 0.03, 0.2, False),
    ("noise + mismatch + latency", 0.03, 0.2, True),
)


def _check_levels(noise_xy: Any, noise_deg: Any) -> tuple[list[float], list[float]]:
    """Return the noise levels as lists of floats after checking them."""
    levels = []
    for name, seq in (("noise_xy", noise_xy), ("noise_deg", noise_deg)):
        if isinstance(seq, (str, bytes)) or np.ndim(seq) != 1:
            raise ValueError(
                f"{name} = {seq!r} is not allowed; allowed: a sequence of levels, one per row"
            )
        levels.append(list(seq))
    noise_xy, noise_deg = levels
    if len(noise_xy) != len(noise_deg) or not noise_xy:
        raise ValueError(
            f"noise_xy has {len(noise_xy)} levels and noise_deg {len(noise_deg)}; "
            "allowed: the same number, at least one"
        )
    limits = (("noise_xy", noise_xy, "cm", 1e6), ("noise_deg", noise_deg, "degrees", 360.0))
    for name, seq, unit, high in limits:
        for i, value in enumerate(seq):
            checks.check_number(f"{name}[{i}]", value, closed=True, high=high, unit=unit)
    return [float(x) for x in noise_xy], [float(x) for x in noise_deg]


def summary_row(m: PoseMetrics) -> dict[str, Any]:
    """Return success, arrival, first arrival, final distance and zig-zag of a batch."""
    ok = m.success
    t = m.arrival[ok]
    return {
        "success": float(ok.mean()),
        "mean arrival s": float(t.mean()) if t.size else math.inf,
        "median arrival s": float(np.median(t)) if t.size else math.inf,
        "reached": float(np.isfinite(m.first_arrival).mean()),
        "median first arrival s": _median_finite(m.first_arrival),
        "mean final distance cm": float(m.final_distance.mean()),
        "mean zigzag": float(m.zigzag.mean()),
    }


def _median_finite(times: np.ndarray) -> float:
    finite = times[np.isfinite(times)]
    return float(np.median(finite)) if finite.size else math.inf


def monte_carlo(
    key: jax.Array,
    *,
    controller: Any = controllers.SHIM_SUNG,
    params: Any = None,
    n_runs: int = 256,
    noise_xy: Sequence[float] = DEFAULT_NOISE_XY,
    noise_deg: Sequence[float] = DEFAULT_NOISE_DEG,
    radius_mismatch: float = 0.0,
    mass_mismatch: float = 0.0,
    latency: bool = False,
    velocity: str = "ideal",
    dt: float = DEFAULT_DT,
    x64: bool = True,
    estimator: Any = None,
) -> list[dict[str, Any]]:
    """Return success and arrival against noise level for one controller and condition.

    Every noise level reuses the same references, unit noise and mismatch
    (common random numbers), so differences between levels are the noise's.
    Each run lasts the ``docs/model.md §6`` horizon (6 s).

    Args:
        key: ``jax.random`` key; the same key gives the same numbers.
        controller: a ``Controller`` or its registered name.
        params: its parameters (defaults if ``None``).
        n_runs: Monte Carlo runs per noise level.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        radius_mismatch: bound of each wheel's relative radius error, ``[0, 1)``.
        mass_mismatch: bound of the relative body-mass error (non-ideal loop),
            ``[0, 1)``.
        latency: apply each command one sample late.
        velocity: ``"ideal"`` or ``"nonideal"``.
        dt: control period, s.
        x64: compute in float64 (see ``perturbed_metrics``).
        estimator: between the measurements and the law: ``None`` (raw
            feedback), ``"observer"``, ``"ekf"`` or their parameters
            (docs/model.md §9).

    Returns:
        One row per noise level: success rate, mean and median arrival of the
        successful runs (s), the fraction of runs ever arrived (if only for a
        sample) and their median first arrival (s), mean final distance (cm),
        mean zig-zag count.

    Raises:
        ValueError: for a bad count, noise level, mismatch bound or option.
    """
    n_runs = checks.check_int("n_runs", n_runs)
    checks.check_key("key", key)
    noise_xy, noise_deg = _check_levels(noise_xy, noise_deg)
    if not isinstance(latency, (bool, np.bool_)):
        raise ValueError(f"latency = {latency!r} is not allowed; allowed: True or False")
    for name, value in (("radius_mismatch", radius_mismatch), ("mass_mismatch", mass_mismatch)):
        checks.check_number(name, value, high=1.0, closed=True)
    if mass_mismatch > 0 and velocity == "ideal":
        raise ValueError(
            f"mass_mismatch = {mass_mismatch!r} is not allowed with velocity = 'ideal', whose "
            "robot has no mass; allowed: 0, or velocity = 'nonideal'"
        )
    name = controllers.get_controller(controller).name
    estimator_used, _ = resolve_estimator(estimator)
    refs, unit, mismatch = draw_disturbances(
        key, n_runs, horizon_steps(dt), radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch
    )
    delay = np.float64(1.0 if latency else 0.0)
    rows = []
    for sxy, sdeg in zip(noise_xy, noise_deg, strict=True):
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        m = perturbed_metrics(
            Disturbance(refs, unit * scale, mismatch, delay),
            params,
            controller=name,
            estimator=estimator,
            dt=dt,
            velocity=velocity,
            x64=x64,
        )
        condition = {
            "controller": name,
            "feedback": "raw" if estimator_used is None else estimator_used.name,
            "noise xy cm": float(sxy),
            "noise theta deg": float(sdeg),
            "radius mismatch": float(radius_mismatch),
            "mass mismatch": float(mass_mismatch),
            "latency": bool(latency),
            "runs": int(n_runs),
        }
        rows.append({**condition, **summary_row(m)})
    return rows


def robustness_study(
    *,
    seed: int = 0,
    controller_names: Sequence[str] | None = None,
    n_runs: int = 256,
    velocity: str = "ideal",
    noise_xy: Sequence[float] = DEFAULT_NOISE_XY,
    noise_deg: Sequence[float] = DEFAULT_NOISE_DEG,
    x64: bool = True,
    estimator: Any = None,
) -> list[dict[str, Any]]:
    """Run the Monte Carlo for each controller and condition (``docs/model.md §7``).

    Conditions (``ROBUSTNESS_CONDITIONS``): measurement noise alone; noise
    with ±3 % wheel-radius and ±20 % body-mass mismatch (the latter in the
    non-ideal loop only: the ideal one has no mass); and the same with
    one-sample latency. Each controller sees the same draws (one key per
    condition, from ``seed``). ``wmr_jax.report.write_robustness`` draws and
    writes the rows.

    Args:
        seed: PRNG seed, an integer in ``[0, 2³² − 1]``.
        controller_names: registered controllers; default every one.
        n_runs: Monte Carlo runs per noise level.
        velocity: ``"ideal"`` or ``"nonideal"``.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        x64: compute in float64 (see ``perturbed_metrics``).
        estimator: the estimator of every controller (``None``: raw feedback).

    Returns:
        The rows of every condition, controller and noise level (in that
        order), each ``monte_carlo``'s row with its ``"condition"`` first.
    """
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    names = controllers.controller_names(controller_names)
    resolve_estimator(estimator)  # refused before any run
    keys = jax.random.split(jax.random.PRNGKey(seed), len(ROBUSTNESS_CONDITIONS))
    rows = []
    for (label, radius, mass, latency), key in zip(ROBUSTNESS_CONDITIONS, keys, strict=True):
        if velocity == "ideal":
            mass = 0.0  # the ideal loop has no mass: the rows say so rather than ±20 %
        for name in names:
            for row in monte_carlo(
                key,
                controller=name,
                n_runs=n_runs,
                noise_xy=noise_xy,
                noise_deg=noise_deg,
                radius_mismatch=radius,
                mass_mismatch=mass,
                latency=latency,
                velocity=velocity,
                x64=x64,
                estimator=estimator,
            ):
                rows.append({"condition": label, **row})
    return rows


def _closed_loop(value: Any, controller: Any, estimator: Any) -> ClosedLoop:
    """A set of ``standard_conditions``: a ``ClosedLoop`` as it is, or params of ``controller``."""
    if isinstance(value, ClosedLoop):
        return value
    return ClosedLoop(controller, value, estimator)


def _unit_draws(key: jax.Array, refs: np.ndarray, steps: int, mismatch: float):
    """Unit noise ``(N, steps, 3)`` and wheel factors ``(N, 3)`` (mass 1) of ``key``.

    What standard_conditions, evaluate_loop and noise_curve scale per level:
    the draws depend on the key and the number of runs only (drawn in the
    session's dtype), while the poses themselves stay in float64.
    """
    unit = sample_disturbance(
        key, np.zeros_like(refs), steps, noise_xy=1.0, noise_theta=1.0, radius_mismatch=mismatch
    )
    factors = np.array(unit.mismatch, dtype=float)
    factors[:, 2] = 1.0  # the wheel radii only: the ideal loop has no mass
    return np.asarray(unit.noise, dtype=float), factors


# The model robot's row: no mismatch, no noise, no latency (docs/model.md §9).
MODEL_ROBOT = "model robot"


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
) -> list[dict[str, Any]]:
    """Judge closed loops under the standard conditions of docs/model.md §7 and §9 (hard law).

    The conditions: the model robot (no mismatch, no noise, no latency),
    then nominal, latency, noise and both, each with every wheel's radius
    off by ``δ ~ U(−mismatch, mismatch)`` drawn per run (docs/model.md §9:
    without it, dead reckoning would be exact). Every set and condition sees
    the same draws (common random numbers, from ``key`` by
    ``sample_disturbance``); ideal loop, horizon 6 s, the estimate starting
    from the first measurement.

    Args:
        params_by_name: ``{label: params of controller}`` or ``{label:
            ClosedLoop}`` (a controller, its parameters and an estimator,
            as ``load_tuned`` returns them).
        refs: ``(N, 3)`` reference poses (held-out poses of ``docs/model.md §6``).
        key: ``jax.random`` key of the noise and the mismatch.
        controller: a ``Controller`` or its registered name, for plain params.
        estimator: the estimator of plain params (``None``: raw feedback).
        mismatch: bound of each wheel's relative radius error, ``[0, 1)``;
            0 judges the model robot under every condition.
        dt: control period, s.
        x64: compute in float64.

    Returns:
        One row per (condition, set): ``condition``, ``gains``, ``feedback``
        (``raw`` or the estimator's name), ``success``, ``mean arrival s``
        and ``median arrival s`` of the successful runs (``inf`` if none),
        ``mean final distance cm``, ``peak wheel cm/s`` (the largest over the
        runs), ``mismatch``, ``runs``.
    """
    if not isinstance(params_by_name, Mapping) or not params_by_name:
        raise ValueError(
            f"params_by_name = {params_by_name!r:.80} is not allowed; allowed: a dict of "
            "label -> parameters or ClosedLoop, at least one"
        )
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    sets = {
        name: _closed_loop(value, controller, estimator) for name, value in params_by_name.items()
    }
    for loop in sets.values():  # every set is refused before any runs
        resolve_estimator(loop.estimator)
        controllers.get_controller(loop.controller)
    with jax.enable_x64(checks.check_bool("x64", x64)):  # not rounded to float32 first
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    noise, factors = _unit_draws(key, refs, horizon_steps(dt), mismatch)
    ones = np.ones((len(refs), 3))
    conditions = [(MODEL_ROBOT, 0.0, 0.0, False, ones)]
    conditions += [(*condition, factors) for condition in STANDARD_CONDITIONS]
    rows = []
    for label, sxy, sdeg, latency, wheels in conditions:
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        spec = Disturbance(refs, noise * scale, wheels, np.float64(1.0 if latency else 0.0))
        for name, loop in sets.items():
            m = perturbed_metrics(
                spec,
                loop.params,
                controller=loop.controller,
                estimator=loop.estimator,
                dt=dt,
                x64=x64,
            )
            summary = summary_row(m)
            estimator_used, _ = resolve_estimator(loop.estimator)
            rows.append(
                {
                    "condition": label,
                    "gains": name,
                    "feedback": "raw" if estimator_used is None else estimator_used.name,
                    "success": summary["success"],
                    "mean arrival s": summary["mean arrival s"],
                    "median arrival s": summary["median arrival s"],
                    "mean final distance cm": summary["mean final distance cm"],
                    "peak wheel cm/s": float(np.max(m.peak_wheel)),
                    "mismatch": 0.0 if label == MODEL_ROBOT else mismatch,
                    "runs": len(refs),
                }
            )
    return rows


def evaluate_loop(
    loop: Any,
    refs: Any,
    *,
    condition: str = "nominal",
    mismatch: float = STANDARD_MISMATCH,
    seed: int = 0,
    horizon: float = HORIZON_S,
    velocity: str = "ideal",
    dt: float = DEFAULT_DT,
    x64: bool = True,
) -> dict[str, Any]:
    """Judge one closed loop on the user's own references under one standard condition.

    The robot starts at the origin facing +x; hard law; the metrics of
    docs/model.md §6 on the true pose. The noise and each wheel's radius
    error (``δ ~ U(−mismatch, mismatch)`` per run) are drawn from ``seed``
    by ``sample_disturbance``, as ``standard_conditions`` draws them.

    Args:
        loop: a ``ClosedLoop`` (``load_tuned`` returns one) or ``Gains``
            (Shim–Sung, raw feedback).
        refs: ``(N, 3)`` references ``[x cm, y cm, θ rad]``.
        condition: ``"nominal"``, ``"latency"``, ``"noise"`` or ``"both"``
            (docs/model.md §7).
        mismatch: bound of each wheel's relative radius error, ``[0, 1)``;
            0 for the model robot.
        seed: seed of the draws, an integer in ``[0, 2³² − 1]``.
        horizon: simulated time per run, s.
        velocity: ``"ideal"`` or ``"nonideal"``.
        dt: control period, s.
        x64: compute in float64.

    Returns:
        ``{"success": fraction, "mean_arrival_s": mean over the successful
        runs (None if none arrived), "median_arrival_s", "peak_wheel_speed":
        cm/s (the largest rim speed of any run, mismatch included), "n",
        "condition", "mismatch", "seed", "horizon_s", "velocity",
        "controller", "feedback"}``.

    Raises:
        ValueError: for a bad argument, before any run.
    """
    labels = {label: (sxy, sdeg, lat) for label, sxy, sdeg, lat in STANDARD_CONDITIONS}
    if condition not in labels:
        raise ValueError(f"condition = {condition!r} is not allowed; allowed: {', '.join(labels)}")
    loop = _closed_loop(loop, controllers.SHIM_SUNG, None)
    estimator, _ = resolve_estimator(loop.estimator)
    controller = controllers.get_controller(loop.controller)
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    steps = horizon_steps(dt, horizon)
    with jax.enable_x64(checks.check_bool("x64", x64)):
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    sxy, sdeg, latency = labels[condition]
    noise, factors = _unit_draws(jax.random.key(seed), refs, steps, mismatch)
    scale = np.array([sxy, sxy, math.radians(sdeg)])
    spec = Disturbance(refs, noise * scale, factors, np.float64(float(latency)))
    m = perturbed_metrics(
        spec,
        loop.params,
        controller=controller,
        estimator=loop.estimator,
        dt=dt,
        velocity=velocity,
        x64=x64,
    )
    arrived = m.arrival[m.success]
    return {
        "success": float(m.success.mean()),
        "mean_arrival_s": float(arrived.mean()) if arrived.size else None,
        "median_arrival_s": float(np.median(arrived)) if arrived.size else None,
        "peak_wheel_speed": float(np.max(m.peak_wheel)),
        "n": len(refs),
        "condition": condition,
        "mismatch": mismatch,
        "seed": seed,
        "horizon_s": steps * float(dt),
        "velocity": velocity,
        "controller": controller.name,
        "feedback": "raw" if estimator is None else estimator.name,
    }


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
) -> list[dict[str, Any]]:
    """Success and mean arrival of closed loops against the level of pose noise.

    ``σ_θ`` follows ``σ_xy`` as in the standard conditions (1° per 0.5 cm,
    docs/model.md §7); every wheel's radius is off by ``δ ~ U(−mismatch,
    mismatch)`` per run (docs/model.md §9). Every loop and level sees the
    same unit noise and mismatch (common random numbers, from ``key``).

    Args:
        loops_by_name: ``{label: ClosedLoop or Shim–Sung Gains (raw feedback)}``.
        refs: ``(N, 3)`` references (held-out poses of docs/model.md §6).
        key: ``jax.random`` key of the draws.
        noise_xy: the levels of ``σ_xy``, cm, each in ``[0, 1e6]``.
        mismatch: bound of each wheel's relative radius error, ``[0, 1)``.
        latency: one sample of latency in every run.
        dt: control period, s.
        x64: compute in float64.

    Returns:
        One row per (loop, level): ``gains``, ``feedback``, ``noise xy cm``,
        ``noise theta deg``, ``success``, ``mean arrival s`` (``inf`` if
        none arrived), ``mismatch``, ``latency``, ``runs``.
    """
    if not isinstance(loops_by_name, Mapping) or not loops_by_name:
        raise ValueError(
            f"loops_by_name = {loops_by_name!r:.80} is not allowed; allowed: a dict of "
            "label -> ClosedLoop or Gains, at least one"
        )
    levels, _ = _check_levels(list(noise_xy), [_DEG_PER_CM * float(x) for x in noise_xy])
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    latency = checks.check_bool("latency", latency)
    sets = {name: _closed_loop(v, controllers.SHIM_SUNG, None) for name, v in loops_by_name.items()}
    for loop in sets.values():
        resolve_estimator(loop.estimator)
        controllers.get_controller(loop.controller)
    with jax.enable_x64(checks.check_bool("x64", x64)):
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    noise, factors = _unit_draws(key, refs, horizon_steps(dt), mismatch)
    rows = []
    for name, loop in sets.items():
        used, _ = resolve_estimator(loop.estimator)
        for sxy in levels:
            sdeg = _DEG_PER_CM * sxy
            scale = np.array([sxy, sxy, math.radians(sdeg)])
            spec = Disturbance(refs, noise * scale, factors, np.float64(1.0 if latency else 0.0))
            m = perturbed_metrics(
                spec, loop.params, controller=loop.controller, estimator=loop.estimator,
                dt=dt, x64=x64,
            )  # fmt: skip
            summary = summary_row(m)
            rows.append(
                {
                    "gains": name,
                    "feedback": "raw" if used is None else used.name,
                    "noise xy cm": sxy,
                    "noise theta deg": sdeg,
                    "success": summary["success"],
                    "mean arrival s": summary["mean arrival s"],
                    "mismatch": mismatch,
                    "latency": latency,
                    "runs": len(refs),
                }
            )
    return rows
