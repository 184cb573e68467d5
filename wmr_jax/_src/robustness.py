"""Robustness Monte Carlo and the standard conditions (docs/model.md §7, §9).

The studies of the disturbed loop (``sensing.loop``): success and arrival
against the level of pose noise, with wheel-radius and mass mismatch and
latency (``monte_carlo``, ``robustness_study``), and parameter sets judged
under the standard conditions (``standard_conditions``), raw feedback or an
estimator alike. The engine returns values; ``wmr_jax.report`` draws and
writes them.

**Your robot.** Every study takes ``robot`` (default: the robot the loops
record, ``ClosedLoop.robot``, else ``Robot()``, the paper robot) and runs
its loop on that robot; the peak wheel speeds are judged against that
robot's ``V_max`` (the ideal loop follows every command, so gains set for a
faster robot show there), and the Monte Carlo runs the Shim–Sung laws on
the paper's gains scaled into its budget (``robot_defaults``). The
references keep the evaluation set of docs/model.md §6
(5–80 cm, any bearing and heading) whatever the robot, since the arrival
tolerances (1 cm, 5°) and the sensor noise of §7 are lengths and angles,
not speeds; the horizon scales instead (``study_horizon``): the paper's
feasible gains, scaled into a slower robot's wheel budget, drive the same
paths ``c`` times slower, and the horizon is the paper robot's 6 s over
``c``, so that they have the time on that robot that they have on the
paper's. A study given a ``horizon`` runs that one. A robot's acceleration
limits (``accel_max``, ``angular_accel_max``) limit the ideal loop's commands
in every study, as in the rollouts (docs/model.md §4.2.2): the disturbed loop
turns its speed limiter on for such a robot (``sensing.loop``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from wmr_jax._src import checks, controllers
from wmr_jax._src.metrics import PoseMetrics
from wmr_jax._src.params import Robot, validate_one_robot
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
    "LATE_SHARE",
    "MODEL_ROBOT",
    "NOISE_CURVE_XY",
    "noise_curve",
    "ROBUSTNESS_CONDITIONS",
    "evaluate_loop",
    "monte_carlo",
    "robot_defaults",
    "robustness_study",
    "settled_at_horizon",
    "standard_conditions",
    "study_horizon",
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


def study_horizon(robot: Robot | None = None) -> float:
    """The studies' default horizon on ``robot``, s: 6 s for the paper robot (docs/model.md §6).

    The paper's feasible gains (``k_r = 60`` cm/s, ``k_θ = 10`` rad/s) fit the
    paper robot's wheel budget; on a robot where ``60 + 10 L > V_max`` they
    are scaled by ``c = V_max / (60 + 10 L)`` to fit (docs/robots.md), and
    both gains scaled by ``c`` drive the same paths ``1 / c`` times slower
    (in continuous time; the sampled law nearly so).
    The horizon is ``6 s / c`` (6 s where ``c ≥ 1``), rounded up to 0.1 s:
    the TurtleBot3 Burger's (``L = 8`` cm, ``V_max = 22.72`` cm/s) is 37 s.

    Raises:
        ValueError: for anything but one valid robot.
    """
    # Imported here: the tuning package imports this module.
    from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS as PAPER

    robot = validate_one_robot(robot, "the studies' horizon")
    budget = float(PAPER.kr) + float(robot.half_track) * float(PAPER.k_theta)  # cm/s
    stretch = max(1.0, budget / float(robot.v_max))
    return math.ceil(HORIZON_S * stretch * 10 - 1e-9) / 10


# A success that settles only in the last quarter of the horizon, after the run
# had been within the tolerance and left it, is no arrival (settled_at_horizon).
LATE_SHARE = 0.25


def settled_at_horizon(m: PoseMetrics, horizon: float) -> np.ndarray:
    """Which runs count as arrived (docs/model.md §6) only because the horizon ends, ``(N,)``.

    A run that reached the goal, left its tolerance and is back in it over
    the final stretch has a finite settled arrival: the start of that
    stretch, set by where the horizon cuts the run rather than by the run.
    Under noise such runs hover about the goal and their "arrival" moves
    with the horizon (the paper's gains under the standard noise "arrive"
    at 5.7 s of 6 on average). Such a run is one whose settled arrival comes
    after ``(1 − LATE_SHARE)`` of the horizon and after its first arrival;
    a run that arrives late without having left the tolerance is not.

    Args:
        m: the runs' metrics (``first_arrival`` included).
        horizon: the simulated time of the runs, s.
    """
    late = m.arrival > (1.0 - LATE_SHARE) * float(horizon)
    return m.success & late & (m.first_arrival < m.arrival)


def summary_row(m: PoseMetrics, horizon: float | None = None) -> dict[str, Any]:
    """Return success, arrival, first arrival, final distance and zig-zag of a batch.

    Given the runs' ``horizon`` (s), also ``"settled at horizon"``: the
    fraction of the runs that count as successes only because the horizon
    ends (``settled_at_horizon``), and the mean and median arrival of the
    other successes (``inf`` if none), which the figures draw.
    """
    ok = m.success
    t = m.arrival[ok]
    row = {
        "success": float(ok.mean()),
        "mean arrival s": float(t.mean()) if t.size else math.inf,
        "median arrival s": float(np.median(t)) if t.size else math.inf,
        "reached": float(np.isfinite(m.first_arrival).mean()),
        "median first arrival s": _median_finite(m.first_arrival),
        "mean final distance cm": float(m.final_distance.mean()),
        "mean zigzag": float(m.zigzag.mean()),
    }
    if horizon is None:
        return row
    late = settled_at_horizon(m, horizon)
    early = m.arrival[ok & ~late]
    row["settled at horizon"] = float(late.mean())
    row["mean arrival, not at horizon s"] = float(early.mean()) if early.size else math.inf
    row["median arrival, not at horizon s"] = float(np.median(early)) if early.size else math.inf
    return row


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
    robot: Robot | None = None,
    horizon: float | None = None,
) -> list[dict[str, Any]]:
    """Return success and arrival against noise level for one controller and condition.

    Every noise level reuses the same references, unit noise and mismatch
    (common random numbers), so differences between levels are the noise's.
    The references are the evaluation set of ``docs/model.md §6`` on every
    robot; each run lasts ``horizon`` (default ``study_horizon(robot)``: the
    paper robot's 6 s, longer on a slower robot).

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
        robot: the robot (the controller's model and, up to the mismatch,
            the true one); default ``Robot()``. With ``params`` ``None`` on
            another robot than the paper's, the two Shim–Sung laws run the
            paper's feasible gains scaled into its wheel budget
            (``robot_defaults``); the ideal loop does not limit wheel
            commands, and gains set for a faster robot would drive it beyond
            its ``V_max``.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.

    Returns:
        One row per noise level: success rate, mean and median arrival of the
        successful runs (s), the fraction of runs ever arrived (if only for a
        sample) and their median first arrival (s), mean final distance (cm),
        mean zig-zag count, the fraction of runs that only settle at the
        horizon (``settled_at_horizon``) and the mean and median arrival of
        the other successes (s), the horizon (s) and the peak wheel speed
        (cm/s, the largest of any run).

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
    steps, horizon = _steps(robot, horizon, dt)
    if params is None:
        params = robot_defaults(name, robot)
    refs, unit, mismatch = draw_disturbances(
        key, n_runs, steps, radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch
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
            robot=robot,
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
            "horizon s": horizon,
        }
        peak = {"peak wheel cm/s": float(np.max(m.peak_wheel))}
        rows.append({**condition, **summary_row(m, horizon), **peak})
    return rows


def robot_defaults(controller: Any, robot: Robot | None = None) -> Any:
    """The parameters a study runs for ``controller`` on ``robot`` when given none.

    On the paper robot (and for ``robot`` ``None``), ``None``: the
    controller's defaults. On another robot, ``shim-sung`` runs the paper's
    feasible gains scaled into that robot's wheel budget
    (``tuning.paper_feasible_gains``: ``k_r : k_θ = 60 : 10``,
    ``k_r + L k_θ ≤ V_max``) and ``shim-sung-schedule`` the same gains as
    constant tables capped with that robot's ``V_max`` and ``L``: their
    defaults are set for the paper robot's wheels. Other controllers keep
    their defaults (``None``): their commands grow with the distance and
    are bounded by no wheel budget (docs/model.md §3.8).
    """
    from wmr_jax._src.controllers.schedule import SCHEDULE, ScheduleParams
    from wmr_jax._src.robots import same_robot
    from wmr_jax._src.tuning.parametrisation import paper_feasible_gains

    name = controllers.get_controller(controller).name
    if robot is None or same_robot(validate_one_robot(robot, "the study"), Robot()):
        return None
    if name == controllers.SHIM_SUNG.name:
        return paper_feasible_gains(robot)
    if name == SCHEDULE.name:
        return ScheduleParams.from_gains(paper_feasible_gains(robot), robot=robot)
    return None


def _steps(robot: Any, horizon: Any, dt: float) -> tuple[int, float]:
    """The periods and the horizon (s, a whole number of periods) of a study's runs.

    ``horizon`` ``None`` is ``study_horizon(robot)``; the robot is checked either way.
    """
    default = study_horizon(robot)
    steps = horizon_steps(dt, default if horizon is None else horizon)
    return steps, steps * float(dt)


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
        robot: the robot of every run (``monte_carlo``); default ``Robot()``.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.

    Returns:
        The rows of every condition, controller and noise level (in that
        order), each ``monte_carlo``'s row with its ``"condition"`` first.
    """
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    names = controllers.controller_names(controller_names)
    resolve_estimator(estimator)  # refused before any run
    _steps(robot, horizon, DEFAULT_DT)  # and the robot and the horizon
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
                robot=robot,
                horizon=horizon,
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
    robot: Robot | None = None,
    horizon: float | None = None,
) -> list[dict[str, Any]]:
    """Judge closed loops under the standard conditions of docs/model.md §7 and §9 (hard law).

    The conditions: the model robot (no mismatch, no noise, no latency),
    then nominal, latency, noise and both, each with every wheel's radius
    off by ``δ ~ U(−mismatch, mismatch)`` drawn per run (docs/model.md §9:
    without it, dead reckoning would be exact). Every set and condition sees
    the same draws (common random numbers, from ``key`` by
    ``sample_disturbance``); ideal loop, the estimate starting from the
    first measurement, on ``robot`` for ``horizon`` (by default the paper
    robot's 6 s, longer on a slower robot: ``study_horizon``).

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
        robot: the robot of every run; default: the robot the loops record
            (``ClosedLoop.robot``), else ``Robot()``. A loop tuned for
            another robot is refused.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.

    Returns:
        One row per (condition, set): ``condition``, ``gains``, ``feedback``
        (``raw`` or the estimator's name), ``success``, ``mean arrival s``
        and ``median arrival s`` of the successful runs (``inf`` if none),
        ``mean final distance cm``, ``peak wheel cm/s`` (the largest over the
        runs, the mismatch included), ``mismatch``, ``runs``, ``settled at
        horizon`` (the fraction of runs that only settle at the horizon,
        ``settled_at_horizon``), ``mean arrival, not at horizon s`` (of the
        other successes), ``horizon s``.
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
    robot = _study_robot(robot, sets, "params_by_name")
    steps, horizon = _steps(robot, horizon, dt)
    with jax.enable_x64(checks.check_bool("x64", x64)):  # not rounded to float32 first
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    noise, factors = _unit_draws(key, refs, steps, mismatch)
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
                robot=robot,
                x64=x64,
            )
            summary = summary_row(m, horizon)
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
                    "settled at horizon": summary["settled at horizon"],
                    "mean arrival, not at horizon s": summary["mean arrival, not at horizon s"],
                    "horizon s": horizon,
                }
            )
    return rows


def _study_robot(robot: Any, loops: Mapping[str, ClosedLoop], name: str) -> Robot:
    """The study's robot: ``robot``, else the one the ``loops`` record, else the paper's.

    A loop that records the robot it was tuned for (``ClosedLoop.robot``,
    as ``load_tuned`` returns it) is judged on that robot only: its gains
    live in that robot's wheel budget, and a schedule caps its commands
    with that robot's ``V_max`` and ``L``, so on another robot the numbers
    would belong to neither.

    Raises:
        ValueError: naming the loop, for a loop tuned for another robot.
    """
    from wmr_jax._src.robots import describe_robot, same_robot

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
        horizon: simulated time per run, s; default ``study_horizon(robot)``
            (6 s on the paper robot, longer on a slower one).
        velocity: ``"ideal"`` or ``"nonideal"``.
        dt: control period, s.
        x64: compute in float64.
        robot: the robot; default the one the loop records
            (``ClosedLoop.robot``), else ``Robot()``. Another robot than the
            loop's is refused.

    Returns:
        ``{"success": fraction, "mean_arrival_s": mean over the successful
        runs (None if none arrived), "median_arrival_s", "settled_at_horizon":
        the fraction of runs that only settle at the horizon
        (``settled_at_horizon``), "peak_wheel_speed": cm/s (the largest rim
        speed of any run, mismatch included), "v_max": the robot's rim limit,
        cm/s, "peak_wheel_speed_ok": whether the commands stayed within
        ``V_max``, i.e. every rim within ``V_max (1 + mismatch)`` (a wheel
        larger than modelled by ``δ`` turns ``V_max`` into ``(1 + δ) V_max``
        at its rim), "turn_drive_turn_s": the mean time-optimal turn–drive–turn time
        of docs/model.md §8 over the references that arrived (None if none),
        "vs_turn_drive_turn": the mean arrival over it, "n", "condition",
        "mismatch", "seed", "horizon_s", "velocity", "controller",
        "feedback", "robot": {field: value}}``.

    Raises:
        ValueError: for a bad argument, before any run.
    """
    from wmr_jax._src.optimal import time_bounds
    from wmr_jax._src.robots import robot_json

    labels = {label: (sxy, sdeg, lat) for label, sxy, sdeg, lat in STANDARD_CONDITIONS}
    if condition not in labels:
        raise ValueError(f"condition = {condition!r} is not allowed; allowed: {', '.join(labels)}")
    loop = _closed_loop(loop, controllers.SHIM_SUNG, None)
    estimator, _ = resolve_estimator(loop.estimator)
    controller = controllers.get_controller(loop.controller)
    mismatch = checks.check_number("mismatch", mismatch, high=1.0, closed=True)
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    robot = _study_robot(robot, {"loop": loop}, "evaluate_loop")
    steps, horizon = _steps(robot, horizon, dt)
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
        robot=robot,
        velocity=velocity,
        x64=x64,
    )
    arrived = m.arrival[m.success]
    mean = float(arrived.mean()) if arrived.size else None
    optimal = None
    if arrived.size:  # the same references as the mean arrival: those that arrived
        optimal = float(np.mean(time_bounds(refs[m.success], robot=robot, dt=dt).turn_drive_turn))
    return {
        "success": float(m.success.mean()),
        "mean_arrival_s": mean,
        "median_arrival_s": float(np.median(arrived)) if arrived.size else None,
        "settled_at_horizon": float(settled_at_horizon(m, horizon).mean()),
        "peak_wheel_speed": float(np.max(m.peak_wheel)),
        "v_max": float(robot.v_max),
        "peak_wheel_speed_ok": bool(
            np.max(m.peak_wheel) <= float(robot.v_max) * (1.0 + mismatch) * (1 + 1e-6)
        ),
        "turn_drive_turn_s": optimal,
        "vs_turn_drive_turn": None if optimal is None else mean / optimal,
        "n": len(refs),
        "condition": condition,
        "mismatch": mismatch,
        "seed": seed,
        "horizon_s": horizon,
        "velocity": velocity,
        "controller": controller.name,
        "feedback": "raw" if estimator is None else estimator.name,
        "robot": robot_json(robot),
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
    robot: Robot | None = None,
    horizon: float | None = None,
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
        robot: the robot of every run; default: the robot the loops record
            (``ClosedLoop.robot``), else ``Robot()``. A loop tuned for
            another robot is refused.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.

    Returns:
        One row per (loop, level): ``gains``, ``feedback``, ``noise xy cm``,
        ``noise theta deg``, ``success``, ``mean arrival s`` (``inf`` if
        none arrived), ``mismatch``, ``latency``, ``runs``, ``settled at
        horizon`` (``settled_at_horizon``), ``mean arrival, not at horizon
        s`` (of the other successes), ``horizon s``.
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
    robot = _study_robot(robot, sets, "loops_by_name")
    steps, horizon = _steps(robot, horizon, dt)
    with jax.enable_x64(checks.check_bool("x64", x64)):
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    noise, factors = _unit_draws(key, refs, steps, mismatch)
    rows = []
    for name, loop in sets.items():
        used, _ = resolve_estimator(loop.estimator)
        for sxy in levels:
            sdeg = _DEG_PER_CM * sxy
            scale = np.array([sxy, sxy, math.radians(sdeg)])
            spec = Disturbance(refs, noise * scale, factors, np.float64(1.0 if latency else 0.0))
            m = perturbed_metrics(
                spec, loop.params, controller=loop.controller, estimator=loop.estimator,
                dt=dt, robot=robot, x64=x64,
            )  # fmt: skip
            summary = summary_row(m, horizon)
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
                    "settled at horizon": summary["settled at horizon"],
                    "mean arrival, not at horizon s": summary["mean arrival, not at horizon s"],
                    "horizon s": horizon,
                }
            )
    return rows
