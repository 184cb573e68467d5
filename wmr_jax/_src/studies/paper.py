"""The paper's experiments (``docs/model.md §5``): the runs and numbers behind Figs. 6–10.

``wmr_jax.report.save_paper`` and ``save_fig7`` draw and write them.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import jax
import numpy as np

from wmr_jax._src.checks import as_pose_array, check_int, real_array, require
from wmr_jax._src.model.controllers.shim_sung import wheel_speeds
from wmr_jax._src.model.params import Gains, Robot, WheelSpeedWarning, validate_one_robot
from wmr_jax._src.sim import metrics
from wmr_jax._src.sim.poses import paper_refs
from wmr_jax._src.sim.rollout import DEFAULT_DT, Trajectory, batch_rollout

PAPER_STEPS = 91  # 3 s at 33 ms: every paper run has settled by then
PAPER_KR = (120.0, 60.0)  # cm/s: Figs. 7–9 violate the wheel-speed condition, Fig. 10 holds it
FIG6_MARK_DEG = 70.0  # the paper's Φ_m


def run_table(
    traj: Any, refs: np.ndarray, *, dt: float, robot: Robot | None = None
) -> list[dict[str, Any]]:
    """One row of ``docs/model.md §6`` metrics per run of a batched trajectory.

    Args:
        traj: a batched ``Trajectory`` of ``N`` runs from ``batch_rollout``.
        refs: ``(N, 3)`` references ``[x cm, y cm, θ rad]`` of the runs.
        dt: control period, s.
        robot: the robot that ran (for ``V_max``); default ``Robot()``.

    Returns:
        Per run: ``ref`` ``[x cm, y cm, θ degrees]``, ``arrival_s``, ``path_cm``,
        ``peak_wheel_cm_s``, ``saturated_fraction`` (of the samples whose
        commanded rim speed exceeds ``V_max``), ``zigzag`` and
        ``final_distance_cm``.
    """
    robot = validate_one_robot(robot, "its V_max")
    if not isinstance(traj, Trajectory) or np.ndim(traj.poses) != 3:
        shape = np.shape(getattr(traj, "poses", None))
        raise ValueError(
            f"traj = {type(traj).__name__} with poses of shape {shape} is not allowed; "
            "allowed: a Trajectory of batch_rollout, poses (N, steps + 1, 3)"
        )
    with jax.enable_x64(True):  # checked, and reported, in float64: 40.1 stays 40.1
        refs = np.asarray(as_pose_array("refs", refs), dtype=float)
    if refs.shape != (len(traj.poses), 3):
        raise ValueError(
            f"refs has shape {refs.shape}; allowed: ({len(traj.poses)}, 3), one per run of traj"
        )
    times = np.asarray(metrics.arrival_time(traj, refs, dt=dt))
    lengths = np.asarray(metrics.path_length(traj))
    zigzag = np.asarray(metrics.zigzag_count(traj))
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(-1, -2))
    # Saturated: the wheel command v_m ± L ω_m asks for more than V_max (the
    # non-ideal loop clips it; the ideal loop obeys it regardless).
    commanded = np.abs(np.asarray(wheel_speeds(traj.v, traj.omega, robot)))
    saturated = (commanded > float(robot.v_max)).any(axis=-1).mean(axis=-1)
    final = np.asarray(traj.poses[:, -1])
    return [
        {
            "ref": [float(ref[0]), float(ref[1]), round(math.degrees(float(ref[2])), 6)],
            "arrival_s": float(times[i]),
            "path_cm": float(lengths[i]),
            "peak_wheel_cm_s": float(peak[i]),
            "saturated_fraction": float(saturated[i]),
            "zigzag": int(zigzag[i]),
            "final_distance_cm": float(np.hypot(*(final[i, :2] - ref[:2]))),
        }
        for i, ref in enumerate(refs)
    ]


def residual_bound(phi_m: Any) -> Any:
    """The paper's residual distance bound ``sqrt(sin Φ_m tan Φ_m)``, cm (Fig. 6).

    ``V̇ ≤ 0`` (docs/model.md §3.6) is proven only for ``r_e`` above it.

    Args:
        phi_m: ``Φ_m`` in rad, ``0 ≤ Φ_m < π/2``; any array shape.
    """
    arr = real_array("phi_m", phi_m, "numbers 0 <= phi_m < pi/2 rad")
    require("phi_m", arr, (arr >= 0) & (arr < math.pi / 2), "0 <= phi_m < pi/2 rad")
    return np.sqrt(np.sin(arr) * np.tan(arr))


def fig6_curve(points: int = 400) -> dict[str, Any]:
    """Fig. 6's curve: ``phi_m_deg`` (1°–89°) and ``bound_cm``, ``(points,)`` each.

    Also ``mark_deg`` (70°, the paper's ``Φ_m``) and ``mark_cm``, the bound there.
    """
    points = check_int("points", points, 2, 10**6)
    phi_deg = np.linspace(1.0, 89.0, points)
    return {
        "phi_m_deg": phi_deg,
        "bound_cm": residual_bound(np.radians(phi_deg)),
        "mark_deg": FIG6_MARK_DEG,
        "mark_cm": float(residual_bound(math.radians(FIG6_MARK_DEG))),
    }


@dataclasses.dataclass(frozen=True)
class PaperCase:
    """One gain of Figs. 7–10: the seven paper runs with both velocity loops.

    Attributes:
        kr: ``k_r``, cm/s (the rest of the gains are the paper's).
        ideal, nonideal: batched trajectories of the two velocity loops.
        speed_bound: ``k_r + L k_θ``, cm/s (``docs/model.md §3.5``).
        condition: ``"holds"`` if ``speed_bound ≤ V_max``, else ``"violated"``.
        deviation: ``(7,)`` largest distance between each run's two paths, cm.
    """

    kr: float
    ideal: Trajectory
    nonideal: Trajectory
    speed_bound: float
    condition: str
    deviation: np.ndarray


@dataclasses.dataclass(frozen=True)
class PaperRuns:
    """Everything ``wmr-jax paper`` draws and tabulates.

    Attributes:
        refs: ``(7, 3)`` references of Fig. 7 ``[x cm, y cm, θ rad]``.
        robot: the robot that ran.
        fig6: Fig. 6's curve (``fig6_curve``).
        cases: one ``PaperCase`` per ``k_r`` (120, then 60 cm/s).
        runs: table rows, one per reference, gain and loop.
        summary: ``"fig6"`` (the bound at 70°) and, per ``"kr=<k_r>"``, the
            speed bound, condition, deviations and the means per loop.
    """

    refs: np.ndarray
    robot: Robot
    fig6: dict[str, Any]
    cases: tuple[PaperCase, ...]
    runs: list[dict[str, Any]]
    summary: dict[str, Any]

    def table(self) -> dict[str, Any]:
        """The JSON-ready table: ``{"robot": ..., "summary": ..., "runs": ...}``."""
        robot = {k: float(v) for k, v in vars(self.robot).items()}
        return {"robot": robot, "summary": self.summary, "runs": self.runs}


def _paper_case(refs: np.ndarray, kr: float, robot: Robot) -> tuple[PaperCase, dict]:
    """The ``PaperCase`` of ``kr`` and its table rows per loop (``"ideal"``, ``"nonideal"``)."""
    gains = Gains(kr=kr)
    ideal = batch_rollout(refs, gains, steps=PAPER_STEPS, robot=robot)
    nonideal = batch_rollout(refs, gains, steps=PAPER_STEPS, robot=robot, velocity="nonideal")
    gap = np.hypot(*np.moveaxis(np.asarray(ideal.poses - nonideal.poses)[..., :2], -1, 0))
    bound = float(kr + float(robot.half_track) * float(gains.k_theta))
    held = "holds" if bound <= float(robot.v_max) else "violated"
    case, rows = PaperCase(kr, ideal, nonideal, bound, held, gap.max(axis=-1)), {}
    for loop, traj in (("ideal", ideal), ("nonideal", nonideal)):
        rows[loop] = run_table(traj, refs, dt=DEFAULT_DT, robot=robot)
        for row, dev in zip(rows[loop], case.deviation, strict=True):
            row.update(kr=kr, loop=loop, condition=held, max_deviation_cm=float(dev))
    return case, rows


def _case_summary(case: PaperCase, rows: dict[str, list[dict]]) -> dict[str, Any]:
    return {
        "k_r + L k_theta": case.speed_bound,
        "condition": case.condition,
        "max_deviation_cm": float(case.deviation.max()),
        "mean_deviation_cm": float(case.deviation.mean()),
        **{
            f"{loop}_{key}": float(np.mean([r[key] for r in rows[loop]]))
            for loop in ("ideal", "nonideal")
            for key in ("arrival_s", "path_cm", "zigzag", "saturated_fraction")
        },
    }


def paper_runs(*, robot: Robot | None = None) -> PaperRuns:
    """Run the paper's experiments (``docs/model.md §5``) and tabulate them.

    The seven references of Fig. 7 from ``(0, 0, 0)`` for 3 s, with ``k_r =
    120`` (Figs. 7–9, wheel-speed condition violated, its warning silenced) and
    ``k_r = 60`` (Fig. 10), each with the ideal and the non-ideal loop.

    Args:
        robot: the robot; default ``Robot()`` (the paper's).
    """
    robot = Robot() if robot is None else robot
    refs = paper_refs()
    fig6 = fig6_curve()
    summary: dict[str, Any] = {"fig6": {"phi_m_deg": fig6["mark_deg"], "bound_cm": fig6["mark_cm"]}}
    cases, rows = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WheelSpeedWarning)
        for kr in PAPER_KR:
            case, case_rows = _paper_case(refs, kr, robot)
            rows += case_rows["ideal"] + case_rows["nonideal"]
            summary[f"kr={kr:g}"] = _case_summary(case, case_rows)
            cases.append(case)
    return PaperRuns(refs, robot, fig6, tuple(cases), rows, summary)


@dataclasses.dataclass(frozen=True)
class Fig7Runs:
    """Fig. 7: the seven runs of the ideal loop with the paper's gains, and their rows."""

    gains: Gains
    refs: np.ndarray
    trajectory: Trajectory
    rows: list[dict[str, Any]]

    def table(self) -> dict[str, Any]:
        """The JSON-ready table: ``{"gains": {field: value}, "runs": rows}``."""
        gains = {k: float(v) for k, v in vars(self.gains).items()}
        return {"gains": gains, "runs": self.rows}


def fig7_runs(gains: Gains | None = None) -> Fig7Runs:
    """Run Fig. 7: from ``(0, 0, 0)`` to its seven references, ideal loop, 3 s.

    Args:
        gains: default ``Gains()`` (the paper's, ``k_r = 120``; their
            ``WheelSpeedWarning`` is silenced).
    """
    gains = Gains() if gains is None else gains
    refs = paper_refs()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WheelSpeedWarning)  # the paper's own gains
        traj = batch_rollout(refs, gains, steps=PAPER_STEPS, dt=DEFAULT_DT)
    return Fig7Runs(gains, refs, traj, run_table(traj, refs, dt=DEFAULT_DT))
