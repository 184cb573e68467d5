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
from wmr_jax._src.poses import horizon_steps
from wmr_jax._src.rollout import DEFAULT_DT
from wmr_jax._src.sensing.disturbances import (
    STANDARD_CONDITIONS,
    Disturbance,
    draw_disturbances,
    sample_disturbance,
)
from wmr_jax._src.sensing.loop import perturbed_metrics

__all__ = [
    "DEFAULT_NOISE_DEG",
    "DEFAULT_NOISE_XY",
    "ROBUSTNESS_CONDITIONS",
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
            dt=dt,
            velocity=velocity,
            x64=x64,
        )
        condition = {
            "controller": name,
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

    Returns:
        The rows of every condition, controller and noise level (in that
        order), each ``monte_carlo``'s row with its ``"condition"`` first.
    """
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    names = controllers.controller_names(controller_names)
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
            ):
                rows.append({"condition": label, **row})
    return rows


def standard_conditions(
    params_by_name: dict[str, Any],
    refs: Any,
    key: jax.Array,
    *,
    controller: Any = controllers.SHIM_SUNG,
    dt: float = DEFAULT_DT,
    x64: bool = True,
) -> list[dict[str, Any]]:
    """Judge parameter sets under the standard conditions of ``docs/model.md §7`` (hard law).

    Every set and condition sees the same unit noise (common random numbers,
    drawn from ``key`` by ``sample_disturbance``); ideal loop, horizon 6 s.

    Args:
        params_by_name: ``{label: params}`` of ``controller``.
        refs: ``(N, 3)`` reference poses (held-out poses of ``docs/model.md §6``).
        key: ``jax.random`` key of the noise.
        controller: a ``Controller`` or its registered name.
        dt: control period, s.
        x64: compute in float64.

    Returns:
        One row per (condition, set): ``condition``, ``gains``, ``success``,
        ``mean arrival s`` and ``median arrival s`` of the successful runs
        (``inf`` if none), ``mean final distance cm``, ``runs``.
    """
    if not isinstance(params_by_name, Mapping) or not params_by_name:
        raise ValueError(
            f"params_by_name = {params_by_name!r:.80} is not allowed; allowed: a dict of "
            "label -> parameters, at least one"
        )
    with jax.enable_x64(checks.check_bool("x64", x64)):  # not rounded to float32 first
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    steps = horizon_steps(dt)
    # The unit noise depends on the key and the number of runs only (drawn in
    # the session's dtype, as before): the poses themselves stay in float64.
    unit = sample_disturbance(key, np.zeros_like(refs), steps, noise_xy=1.0, noise_theta=1.0)
    noise = np.asarray(unit.noise, dtype=float)
    ones = np.ones((len(refs), 3))
    rows = []
    for label, sxy, sdeg, latency in STANDARD_CONDITIONS:
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        spec = Disturbance(refs, noise * scale, ones, np.float64(1.0 if latency else 0.0))
        for name, params in params_by_name.items():
            m = perturbed_metrics(spec, params, controller=controller, dt=dt, x64=x64)
            summary = summary_row(m)
            rows.append(
                {
                    "condition": label,
                    "gains": name,
                    "success": summary["success"],
                    "mean arrival s": summary["mean arrival s"],
                    "median arrival s": summary["median arrival s"],
                    "mean final distance cm": summary["mean final distance cm"],
                    "runs": len(refs),
                }
            )
    return rows
