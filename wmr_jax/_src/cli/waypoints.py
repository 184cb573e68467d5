"""``wmr-jax waypoints``: consecutive motions through a chain of waypoints."""

from __future__ import annotations

import math
import re
from typing import Any

from wmr_jax._src.cli import flags
from wmr_jax._src.cli.robustness import add_study_flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax waypoints``."""
    add_study_flags(parser)
    parser.add_argument(
        "--steps",
        metavar="N",
        help="control periods of each run (default: 450, 14.85 s, for the paper robot; for a "
        "--robot whose wheels cannot follow the paper's feasible gains, 60 + 10 L > v_max, "
        "450 × h / 6 s, where h is its studies' horizon, 6 s × (60 + 10 L) / v_max rounded up "
        "to 0.1 s, as those gains are scaled to fit; printed with the robot)",
    )
    parser.add_argument("--pass-tol", default=5.0, metavar="CM", help="pass-through distance, cm")
    parser.add_argument(
        "--pass-tol-deg",
        default=30.0,
        metavar="DEG",
        help="pass-through heading tolerance, degrees, <= 90 (90 ignores the heading)",
    )
    flags.add_robot_flag(parser)


# A row's "leg i s" is cumulative: the time since the start at which waypoint i was reached.
_CUMULATIVE = re.compile(r"leg (\d+) s")


def _shown(row: dict[str, Any]) -> dict[str, Any]:
    """A result row with headers that say what its times are."""
    out = {}
    for key, value in row.items():
        match = _CUMULATIVE.fullmatch(key)
        if match:
            key = f"waypoint {match[1]}: time since start (s)"
        elif key == "slowest leg s":
            key = "slowest leg (s)"
        out[key] = value
    return out


def run(args: Any) -> int:
    """Run ``wmr-jax waypoints``; return the exit status."""
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.sim.metrics import DEFAULT_TOL_R
    from wmr_jax._src.studies.robustness import study_horizon
    from wmr_jax._src.studies.waypoints import soccer_steps

    out = flags.output_dir("--out", args.out)
    pass_deg = flags.number(
        "--pass-tol-deg", args.pass_tol_deg, low=0.0, high=90.0, closed=False, unit="degrees"
    )
    flags.warn_if_radians("--pass-tol-deg", args.pass_tol_deg, pass_deg)
    pass_cm = flags.number("--pass-tol", args.pass_tol, low=0.0, closed=False, unit="cm")
    if pass_cm < DEFAULT_TOL_R:  # tighter than arriving: the chain may never pass a waypoint
        flags.unit_slip(
            f"--pass-tol {args.pass_tol} is read in cm, under the arrival tolerance "
            f"({DEFAULT_TOL_R:g} cm): a robot may never pass a waypoint; a value in metres "
            "needs times 100"
        )
    given = flags.robot_from(args.robot)
    robot = Robot() if given is None else given.robot
    if args.steps is None:
        steps = soccer_steps(robot)
    else:
        steps = flags.positive_int("--steps", args.steps, 1, 10**7)
    settings = {
        "controller_names": flags.controller_names(args.controller),
        "velocity": flags.velocity_loop(args.velocity),
        "steps": steps,
        "pass_tol_r": pass_cm,
        "pass_tol_theta": math.radians(pass_deg),
        "robot": robot,
    }
    scaled = ""
    if given is not None and args.steps is None and steps > 450:
        scaled = f" (450 × {study_horizon(robot):g} s / 6 s, the studies' horizon on it)"
    flags.say_robot(given, f"; {steps} control periods{scaled}")

    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.report.waypoints import write_soccer
    from wmr_jax._src.sim.rollout import DEFAULT_DT
    from wmr_jax._src.studies.waypoints import soccer_study

    study = soccer_study(**settings)
    label = given.label if given is not None else "paper"
    write_soccer(out, study, extra={"robot": robot_json(robot), "robot_label": label})
    table = markdown_table([_shown(row) for row in study.rows])
    print(f"soccer-like sequence -> {out}/soccer.png, soccer.md, soccer.json\n{table}", end="")
    short = [f"{r['controller']} ({r['mode']})" for r in study.rows if _unfinished(r)]
    if short:  # inf times: the run ended before the chain did
        print(
            f"hint: {', '.join(short)} did not finish the chain within {steps} control periods "
            f"({steps * DEFAULT_DT:g} s); more --steps give it time"
        )
    return 0


def _unfinished(row: dict[str, Any]) -> bool:
    """Whether a row's run ended before its last waypoint (its slowest leg never ended)."""
    return not math.isfinite(float(row["slowest leg s"]))
