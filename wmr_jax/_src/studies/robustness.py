"""Robustness Monte Carlo (docs/model.md §7, §9), and what the studies share.

On any robot the references stay the docs/model.md §6 set (tolerances and noise
are lengths and angles); the horizon scales instead (``study_horizon``).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model import controllers
from wmr_jax._src.model.params import Robot, SamplingWarning, WheelSpeedWarning, validate_one_robot
from wmr_jax._src.model.robots import same_robot
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.sim.poses import HORIZON_S, MAX_SAMPLES, horizon_steps
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.sim.sensing.disturbances import Disturbance, draw_disturbances
from wmr_jax._src.sim.sensing.estimators import resolve_estimator
from wmr_jax._src.sim.sensing.loop import check_settings, disturbed_metrics

DEFAULT_NOISE_XY = (0.0, 0.25, 0.5, 1.0, 2.0)  # σ of x and y, cm
DEFAULT_NOISE_DEG = (0.0, 0.5, 1.0, 2.0, 4.0)  # σ of θ, degrees, paired with the above

# The study's conditions (docs/model.md §7):
# (label, wheel-radius mismatch bound, body-mass mismatch bound, one-sample latency).
ROBUSTNESS_CONDITIONS = (
    ("noise", 0.0, 0.0, False),
    ("noise + mismatch", 0.03, 0.2, False),
    ("noise + mismatch + latency", 0.03, 0.2, True),
)

# The warnings about a loop's gains, which a study of several names.
_GAIN_WARNINGS = (WheelSpeedWarning, SamplingWarning)


def check_levels(noise_xy: Any, noise_deg: Any) -> tuple[list[float], list[float]]:
    """The noise levels, checked, as lists of floats."""
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


def study_horizon(robot: Robot | None = None) -> float:
    """The studies' default horizon on ``robot``, s: 6 s for the paper robot (docs/model.md §6).

    Where the paper's feasible gains exceed the wheels (``60 + 10 L > V_max``), they
    scale by ``c = V_max / (60 + 10 L)`` (docs/robots.md) and drive the same paths
    ``1 / c`` times slower: the horizon is ``6 s / c``, rounded up to 0.1 s.
    """
    # Imported here: the tuning package imports this module.
    from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS as PAPER

    robot = validate_one_robot(robot, "the studies' horizon")
    budget = float(PAPER.kr) + float(robot.half_track) * float(PAPER.k_theta)  # cm/s
    stretch = max(1.0, budget / float(robot.v_max))
    return math.ceil(HORIZON_S * stretch * 10 - 1e-9) / 10


LATE_SHARE = 0.25  # the horizon's last share, where settling again is no arrival


def settled_at_horizon(m: PoseMetrics, horizon: float) -> np.ndarray:
    """Which runs count as arrived (docs/model.md §6) only because the horizon ends, ``(N,)``.

    Under noise a run may reach the goal, leave it and hover back: its settled arrival
    comes after ``(1 − LATE_SHARE)`` of the horizon and after its first arrival.

    Args:
        m: the runs' metrics (``first_arrival`` included).
        horizon: the simulated time of the runs, s.
    """
    _check_with_first_arrivals(m, "m")
    horizon = checks.check_number("horizon", horizon, unit="s")
    late = m.arrival > (1.0 - LATE_SHARE) * horizon
    return m.success & late & (m.first_arrival < m.arrival)


def _check_with_first_arrivals(m: Any, name: str) -> None:
    """Raise unless ``m`` is ``PoseMetrics`` that carry each run's first arrival."""
    if not isinstance(m, PoseMetrics):
        raise ValueError(
            f"{name} is a {type(m).__name__}; allowed: a PoseMetrics (disturbed_metrics "
            "returns one)"
        )
    if m.first_arrival is None:
        raise ValueError(
            f"{name}.first_arrival is None (evaluate_poses does not record first arrivals); "
            "allowed: the metrics of disturbed_metrics, which do"
        )


def mean_median(times: np.ndarray) -> tuple[float, float]:
    """The mean and the median of some times, s; ``inf`` for none."""
    return (float(times.mean()), float(np.median(times))) if times.size else (math.inf, math.inf)


def _scaled(refs, noise, wheels, sxy: float, sdeg: float, latency: bool) -> Disturbance:
    """The runs' ``Disturbance`` at pose noise ``σ_xy`` cm, ``σ_θ`` degrees."""
    scale = np.array([sxy, sxy, math.radians(sdeg)])
    return Disturbance(refs, noise * scale, wheels, np.float64(1.0 if latency else 0.0))


def summary_row(m: PoseMetrics, horizon: float | None = None) -> dict[str, Any]:
    """Success, arrival, first arrival, final distance and zig-zag of a batch.

    Given the runs' ``horizon`` (s), also ``"settled at horizon"`` and the
    mean and median arrival of the other successes (``inf`` if none).
    """
    _check_with_first_arrivals(m, "m")
    ok = m.success
    mean, median = mean_median(m.arrival[ok])
    row = {
        "success": float(ok.mean()),
        "mean arrival s": mean,
        "median arrival s": median,
        "reached": float(np.isfinite(m.first_arrival).mean()),
        "median first arrival s": mean_median(m.first_arrival[np.isfinite(m.first_arrival)])[1],
        "mean final distance cm": float(m.final_distance.mean()),
        "mean zigzag": float(m.zigzag.mean()),
    }
    if horizon is None:
        return row
    late = settled_at_horizon(m, horizon)
    row["settled at horizon"] = float(late.mean())
    mean, median = mean_median(m.arrival[ok & ~late])
    row["mean arrival, not at horizon s"] = mean
    row["median arrival, not at horizon s"] = median
    return row


def _checked(
    n_runs, noise_xy, noise_deg, radius_mismatch, mass_mismatch, latency,
    controller, params, velocity, dt, x64, estimator, robot, horizon,
):  # fmt: skip
    """``monte_carlo``'s settings checked, before anything is drawn.

    Returns ``(n_runs, noise_xy, noise_deg, latency, controller name, params, steps, horizon)``.
    """
    n_runs = checks.check_int("n_runs", n_runs, 1, MAX_SAMPLES)
    noise_xy, noise_deg = check_levels(noise_xy, noise_deg)
    latency = checks.check_bool("latency", latency)
    for name, value in (("radius_mismatch", radius_mismatch), ("mass_mismatch", mass_mismatch)):
        checks.check_number(name, value, high=1.0, closed=True)
    if mass_mismatch > 0 and velocity == "ideal":
        raise ValueError(
            f"mass_mismatch = {mass_mismatch!r} is not allowed with velocity = 'ideal', whose "
            "robot has no mass; allowed: 0, or velocity = 'nonideal'"
        )
    name = controllers.get_controller(controller).name
    steps, horizon = study_steps(robot, horizon, dt)
    params = robot_defaults(name, robot) if params is None else params
    check_settings(params, name, estimator, dt, robot, velocity, steps, x64)
    return n_runs, noise_xy, noise_deg, latency, name, params, steps, horizon


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
    robot: Robot | None = None,
    horizon: float | None = None,
) -> list[dict[str, Any]]:
    """Success and arrival against noise level for one controller and condition.

    Every level reuses the same references, unit noise and mismatch.

    Args:
        key: ``jax.random`` key; the same key gives the same numbers.
        controller, velocity, dt, x64, robot: as ``disturbed_metrics``.
        params: its parameters; default ``robot_defaults(controller, robot)``.
        n_runs: Monte Carlo runs per noise level.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        radius_mismatch: bound of each wheel's relative radius error, ``[0, 1)``.
        mass_mismatch: bound of the relative body-mass error (non-ideal loop),
            ``[0, 1)``.
        latency: apply each command one sample late.
        estimator: as ``disturbed_metrics`` (``None``: raw feedback); parameters with
            one value per run hold ``n_runs``, the same at every level.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.

    Returns:
        One row per noise level: the condition, ``summary_row`` with the
        horizon, and the peak wheel speed of any run (cm/s).
    """
    checks.check_key("key", key)
    n_runs, noise_xy, noise_deg, latency, name, params, steps, horizon = _checked(
        n_runs, noise_xy, noise_deg, radius_mismatch, mass_mismatch, latency,
        controller, params, velocity, dt, x64, estimator, robot, horizon,
    )  # fmt: skip
    estimator_used, _ = resolve_estimator(estimator)
    refs, unit, mismatch = draw_disturbances(
        key, n_runs, steps, radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch
    )
    run = {"estimator": estimator, "dt": dt, "robot": robot, "velocity": velocity, "x64": x64}
    rows = []
    for sxy, sdeg in zip(noise_xy, noise_deg, strict=True):
        spec = _scaled(refs, unit, mismatch, sxy, sdeg, latency)
        m = disturbed_metrics(spec, params, controller=name, **run)
        condition = {
            "controller": name,
            "feedback": "raw" if estimator_used is None else estimator_used.name,
            "noise xy cm": float(sxy),
            "noise theta deg": float(sdeg),
            "radius mismatch": float(radius_mismatch),
            "mass mismatch": float(mass_mismatch),
            "latency": bool(latency),
            "runs": int(n_runs),
            "horizon s": horizon,
        }
        peak = {"peak wheel cm/s": float(np.max(m.peak_wheel))}
        rows.append({**condition, **summary_row(m, horizon), **peak})
    return rows


def robot_defaults(controller: Any, robot: Robot | None = None) -> Any:
    """The parameters a study runs for ``controller`` on ``robot`` when given none.

    On another robot than the paper's, ``shim-sung`` runs ``paper_feasible_gains(robot)``
    and ``shim-sung-schedule`` them as constant tables; else ``None`` (the defaults).
    """
    from wmr_jax._src.tuning.parametrisation import paper_feasible_gains

    name = controllers.get_controller(controller).name
    if robot is None or same_robot(validate_one_robot(robot, "the study"), Robot()):
        return None
    if name == controllers.SHIM_SUNG.name:
        return paper_feasible_gains(robot)
    if name == controllers.SCHEDULE.name:
        return controllers.ScheduleParams.from_gains(paper_feasible_gains(robot), robot=robot)
    return None


def study_steps(robot: Any, horizon: Any, dt: float) -> tuple[int, float]:
    """The periods and the horizon (s, whole periods; default ``study_horizon(robot)``)."""
    default = study_horizon(robot)
    steps = horizon_steps(dt, default if horizon is None else horizon)
    return steps, steps * float(dt)


@contextlib.contextmanager
def named_warnings(name: str | None, said: set[str]):
    """Say the gain warnings of one loop's runs once per study, with the loop's name.

    A study of several loops runs each under every condition; a warning about
    one loop's gains (the wheel bound, the sampled law) names that loop
    (``name=None``: the study has one loop, the warning is as the runs give it).
    Other warnings pass unchanged. As ``warnings.catch_warnings``, not for
    studies run in several threads at once.
    """
    with warnings.catch_warnings(record=True) as records:
        for category in _GAIN_WARNINGS:
            warnings.simplefilter("always", category)
        yield
    for record in records:
        if not issubclass(record.category, _GAIN_WARNINGS):
            warnings.warn_explicit(record.message, record.category, record.filename, record.lineno)
            continue
        text = str(record.message) if name is None else f"gains {name!r}: {record.message}"
        if text not in said:
            said.add(text)
            # 1: here, 2: contextlib, 3: the study, 4: its caller.
            warnings.warn(text, record.category, stacklevel=4)


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
    robot: Robot | None = None,
    horizon: float | None = None,
) -> list[dict[str, Any]]:
    """Run the Monte Carlo for each controller and condition (``docs/model.md §7``).

    The conditions are ``ROBUSTNESS_CONDITIONS`` (body-mass mismatch in the
    non-ideal loop only); each controller sees the same draws (one key per
    condition, from ``seed``).

    Args:
        seed: PRNG seed, an integer in ``[0, 2³² − 1]``.
        controller_names: registered controllers; default every one.
        n_runs, velocity, noise_xy, noise_deg, x64, estimator, robot, horizon:
            as ``monte_carlo``.

    Returns:
        The rows of every condition, controller and noise level (in that
        order), each ``monte_carlo``'s row with its ``"condition"`` first.
    """
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    names = controllers.controller_names(controller_names)
    for name in names:  # every run's settings refused before the first draw
        _checked(
            n_runs, noise_xy, noise_deg, 0.0, 0.0, False,
            name, None, velocity, DEFAULT_DT, x64, estimator, robot, horizon,
        )  # fmt: skip
    keys = jax.random.split(jax.random.PRNGKey(seed), len(ROBUSTNESS_CONDITIONS))
    shared = {"n_runs": n_runs, "noise_xy": noise_xy, "noise_deg": noise_deg, "x64": x64}
    shared.update(velocity=velocity, estimator=estimator, robot=robot, horizon=horizon)
    rows, said = [], set()
    for (label, radius, mass, latency), key in zip(ROBUSTNESS_CONDITIONS, keys, strict=True):
        if velocity == "ideal":
            mass = 0.0  # the ideal loop has no mass: the rows say so rather than ±20 %
        condition = {"radius_mismatch": radius, "mass_mismatch": mass, "latency": latency}
        for name in names:
            with named_warnings(name if len(names) > 1 else None, said):
                found = monte_carlo(key, controller=name, **condition, **shared)
            rows += [{"condition": label, **row} for row in found]
    return rows
