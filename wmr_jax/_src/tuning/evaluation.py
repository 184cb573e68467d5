"""Hard-law evaluation of gains on a set of references (``docs/model.md §6``).

Tuned gains are always judged with the paper's hard law, never with the
smooth relaxation they were tuned through, on held-out poses.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import warnings
from collections.abc import Iterator
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import check_int, require_concrete
from wmr_jax._src.model.controllers.schedule import SCHEDULE, ScheduleParams
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Gains, Robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.metrics import arrival_time
from wmr_jax._src.sim.poses import MAX_SAMPLES, horizon_steps, sample_poses

# The options of a hard-law run that ``evaluate`` and ``random_search`` take.
RUN_OPTIONS = ("robot", "dt", "horizon", "velocity", "substeps", "wheel_limit")

EVAL_POSES = 400
# The held-out poses come from their own seed, the same for every tuning seed,
# so that tables from different runs compare like with like.
EVAL_SEED = 2003


class Evaluation(NamedTuple):
    """Hard-law performance of one set of gains on a set of references (``docs/model.md §6``).

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


def held_out_poses(n: int = EVAL_POSES, eval_seed: int = EVAL_SEED) -> jax.Array:
    """Return the ``n`` held-out reference poses of the before/after table, ``(n, 3)``."""
    eval_seed = check_int("eval_seed", eval_seed, 0, 2**32 - 1)
    check_int("n", n, 0, MAX_SAMPLES)  # before the key
    return sample_poses(jax.random.fold_in(jax.random.key(eval_seed), 1), n)


def poses_digest(poses: Any) -> str:
    """The first 16 hex digits of the sha256 of ``poses`` (float64): which poses judged a row."""
    return hashlib.sha256(np.asarray(poses, dtype=np.float64).tobytes()).hexdigest()[:16]


@contextlib.contextmanager
def quiet_scoring() -> Iterator[None]:
    """Ignore warnings while candidates or iterates are scored: the score says what they would."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def run_options(values: dict[str, Any]) -> dict[str, Any]:
    """Pick the ``RUN_OPTIONS`` out of ``values`` (a function's ``locals()``)."""
    return {name: values[name] for name in RUN_OPTIONS}


def run_horizon(horizon: float | None, robot: Any) -> float:
    """``horizon``, or where it is ``None`` the robot's ``studies.study_horizon``."""
    if horizon is not None:
        return horizon
    from wmr_jax._src.studies.robustness import study_horizon  # it imports the tuning package

    return study_horizon(robot)


def check_run(run: dict[str, Any]) -> dict[str, Any]:
    """The run options of a search (``RUN_OPTIONS``, names and values) checked before it
    starts; a ``horizon`` of ``None`` is the robot's study horizon, as ``evaluate`` has it."""
    unknown = sorted(set(run) - set(RUN_OPTIONS))
    if unknown:
        raise ValueError(f"unknown option {unknown[0]!r}; allowed: {', '.join(RUN_OPTIONS)}")
    run = {**run, "horizon": run_horizon(run["horizon"], run["robot"])}
    simulation.make_options(
        steps=horizon_steps(run["dt"], run["horizon"]),
        velocity=run["velocity"],
        substeps=run["substeps"],
        wheel_limit=run["wheel_limit"],
    )
    return run


def hard_runs(
    refs: Any,
    gains: Gains,
    *,
    robot: Robot | None,
    dt: float,
    horizon: float,
    velocity: str,
    substeps: int,
    wheel_limit: str,
    controller: Any = SHIM_SUNG,
) -> tuple[simulation.Trajectory, jax.Array, int]:
    """Run ``gains`` with the hard law from the origin to each reference.

    Returns:
        ``(trajectory, arrival times (N,) s, steps)``.
    """
    steps = horizon_steps(dt, horizon)
    traj = simulation.batch_rollout(
        refs,
        gains,
        dt=dt,
        steps=steps,
        robot=robot,
        velocity=velocity,
        substeps=substeps,
        wheel_limit=wheel_limit,
        controller=controller,
    )
    return traj, arrival_time(traj, jnp.asarray(refs), dt=dt), steps


def evaluate(
    gains: Gains,
    refs: Any,
    *,
    robot: Robot | None = None,
    dt: float = simulation.DEFAULT_DT,
    horizon: float | None = None,
    velocity: str = "ideal",
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    controller: Any = None,
) -> Evaluation:
    """Run ``gains`` with the hard law from ``(0, 0, 0)`` to each reference; summarise.

    Args:
        gains: the gains (scalar fields).
        refs: ``(N, 3)`` reference poses.
        robot: robot parameters; default ``Robot()``.
        dt: control period, s.
        horizon: simulated time per run, s; default the studies' horizon on
            ``robot`` (``studies.study_horizon``), as ``wmr-jax evaluate`` runs it.
        velocity: ``"ideal"`` or ``"nonideal"``.
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        controller: the law; default: the gain-scheduled one for a
            ``ScheduleParams``, else Shim–Sung.

    Raises:
        ValueError: for out-of-range gains, poses or options, naming the value.
    """
    require_concrete("tuning.evaluate", gains, refs, robot, dt, horizon)  # a summary, on the host
    if gains is None:
        raise ValueError(
            "gains = None is not allowed; allowed: the controller's parameters "
            "(a Gains, a ScheduleParams, ...)"
        )
    if controller is None:
        controller = SCHEDULE if isinstance(gains, ScheduleParams) else SHIM_SUNG
    horizon = run_horizon(horizon, robot)
    traj, times, _ = hard_runs(refs, gains, **run_options(locals()), controller=controller)
    times = np.asarray(times)
    arrived = np.isfinite(times)
    return Evaluation(
        mean_arrival=float(np.mean(times[arrived])) if arrived.any() else math.inf,
        success_rate=float(np.mean(arrived)),
        peak_wheel_speed=float(np.max(np.abs(np.asarray(traj.wheel_speeds)))),
        poses=int(times.size),
    )


# Why a report's ratio is null (JSON) or "none arrived" (print): a mean arrival
# of inf has no ratio worth writing (inf, 0 or NaN would each mislead).
NONE_ARRIVED = "none arrived: no held-out run of these parameters reached its goal in the horizon"
PAPER_NONE_ARRIVED = (
    "none arrived with the paper's gains: no held-out run of them reached its goal in the horizon"
)


def report_ratios(mean_arrival: float, bounds: Any, paper: float | None = None) -> dict[str, Any]:
    """The ratios of a report row: to the §8 yardsticks and, with ``paper``, the speed-up.

    Each ratio is a finite number, or ``None`` with a ``"<ratio>_reason"``
    where a mean arrival it needs is ``inf``: a report never holds NaN.

    Args:
        mean_arrival: the row's mean arrival time, s (``inf``: none arrived).
        bounds: ``time_bounds`` of the same poses.
        paper: the paper's gains' mean arrival on them, s; adds
            ``speedup_vs_paper`` (``paper / mean_arrival``).

    Returns:
        ``{"turn_drive_turn_s", "lower_bound_s", "vs_turn_drive_turn",
        "vs_lower_bound"}`` (and ``"speedup_vs_paper"``).
    """
    from wmr_jax._src.studies.optimal import bound_ratios

    out: dict[str, Any] = {}
    arrived = math.isfinite(mean_arrival)
    if paper is not None:
        if arrived and math.isfinite(paper):
            out["speedup_vs_paper"] = paper / mean_arrival
        else:
            out["speedup_vs_paper"] = None
            out["speedup_vs_paper_reason"] = NONE_ARRIVED if not arrived else PAPER_NONE_ARRIVED
    for key, value in bound_ratios(mean_arrival, bounds).items():
        if key.startswith("vs_") and not arrived:
            out[key], out[f"{key}_reason"] = None, NONE_ARRIVED
        else:
            out[key] = value
    return out
