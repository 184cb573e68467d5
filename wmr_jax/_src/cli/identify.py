"""``wmr-jax identify``: fit the true robot to its logs, or plan the driving that does."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    parser.add_argument(
        "--log",
        nargs="+",
        metavar="FILE",
        help="logs: CSV t,v_cmd,omega_cmd,x,y,theta (s, cm/s, rad/s, cm, cm, rad) "
        "or ROS 2 bags (.mcap, .db3)",
    )
    flags.add_robot_flag(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (identified.json, fit.png)")
    parser.add_argument(
        "--cmd-topic", metavar="TOPIC", help="bag topic of the commands (Twist, TwistStamped)"
    )
    parser.add_argument(
        "--pose-topic",
        metavar="TOPIC",
        help="bag topic of the tracked poses (PoseStamped, Odometry)",
    )
    parser.add_argument(
        "--dt",
        metavar="S",
        help="control period of a bag, s (default: the commands' median spacing)",
    )
    parser.add_argument(
        "--plan", metavar="OUT.csv", help="write a command plan to drive instead of fitting"
    )
    parser.add_argument("--minutes", metavar="MIN", help="length of the plan (default: 5)")
    period = "the plan's period, s (default: 0.033, the commands': latency counts its samples)"
    parser.add_argument("--plan-dt", metavar="S", help=period)
    parser.add_argument("--seed", metavar="N", help="the plan's random seed (default: 0)")


# Flags of one mode only: those that plan, and those that read bags.
_PLAN_FLAGS = ("--minutes", "--plan-dt", "--seed")
_BAG_FLAGS = ("--dt", "--cmd-topic", "--pose-topic")


def _given(args: Any, names: tuple[str, ...]) -> list[str]:
    return [name for name in names if getattr(args, name[2:].replace("-", "_")) is not None]


def run(args: Any) -> int:
    from wmr_jax._src.model.robots import load_robot

    label = "paper" if args.robot is None else flags.robot_from(args.robot).label
    robot = load_robot("paper") if args.robot is None else flags.robot_from(args.robot).robot
    if args.plan is not None:
        fitting_flags = _given(args, ("--log", "--out", *_BAG_FLAGS))
        if fitting_flags:
            raise ValueError(
                f"{fitting_flags[0]} is not allowed with --plan, which writes a plan and fits "
                "nothing; allowed: --robot, --minutes, --plan-dt, --seed"
            )
        return _plan(args, robot)
    if not args.log or args.out is None:
        raise ValueError("identify needs --log FILE [FILE ...] and --out DIR (or --plan OUT.csv)")
    planning = _given(args, _PLAN_FLAGS)
    if planning:
        raise ValueError(f"{planning[0]} is not allowed without --plan; it sets the plan's driving")
    bag_only = _given(args, _BAG_FLAGS)
    if bag_only and all(str(p).lower().endswith(".csv") for p in args.log):
        raise ValueError(
            f"{bag_only[0]} is not allowed with CSV logs only (their t column sets the period); "
            "allowed: with a ROS 2 bag (.mcap, .db3)"
        )
    from wmr_jax._src.identify import fit as fitting
    from wmr_jax._src.identify import logs as reading
    from wmr_jax._src.identify import result as output

    out = flags.output_dir("--out", args.out)
    dt = None if args.dt is None else flags.period("--dt", args.dt)
    minimum = fitting.WARMUP + fitting.SEGMENT + 1
    logs = [
        reading.read_log(
            p, cmd_topic=args.cmd_topic, pose_topic=args.pose_topic, dt=dt, minimum=minimum
        )
        for p in args.log
    ]
    for log in logs:
        _check_speed_unit(log, robot, label)
    period = logs[0].dt
    for log in logs[1:]:
        if abs(log.dt - period) > 1e-3 * period:
            raise ValueError(
                f"--log {log.source} has a period of {log.dt:.6g} s; allowed: that of "
                f"{logs[0].source} ({period:.6g} s)"
            )
    start = time.perf_counter()
    found = fitting.fit_log([(g.commands, g.poses) for g in logs], robot, period)
    seconds = time.perf_counter() - start
    content = output.identified(robot, found, [g.source for g in logs], period)
    content["fit_seconds"] = seconds
    path = output.write(out, content)
    output.plot_fit(out / "fit.png", logs, robot, found, period)
    print(output.table(content))
    print(f"fitted in {seconds:.1f} s; wrote {path} and {out / 'fit.png'}")
    return 0


# A log that asks for translation (in this share of its samples at least), but
# never for this share of V_max, is in m and m/s.
_MOVING_SHARE = 0.1
_SLOWEST_SHARE = 0.02


def _check_speed_unit(log: Any, robot: Any, label: str) -> None:
    """Refuse a log written wholly in metres: poses and commands agree, but 100 times small."""
    import numpy as np

    speeds = np.abs(log.commands[:, 0])
    fastest, v_max = float(np.max(speeds)), float(robot.v_max)
    moving = float(np.mean(speeds > 0))
    if moving >= _MOVING_SHARE and fastest < _SLOWEST_SHARE * v_max:
        raise ValueError(
            f"--log {log.source}: its fastest v_cmd is {fastest:.3g} cm/s, under "
            f"{100 * _SLOWEST_SHARE:g} % of V_max of the robot {label} ({v_max:g} cm/s): the log "
            "looks like m/s and metres; allowed: v_cmd in cm/s and x, y in cm (multiply by 100), "
            "or --robot naming the slower robot it drove"
        )


def _plan(args: Any, robot: Any) -> int:
    import numpy as np

    from wmr_jax._src import io
    from wmr_jax._src.identify import plan
    from wmr_jax._src.sim.rollout import DEFAULT_DT

    defaults = {"minutes": "5", "plan_dt": f"{DEFAULT_DT:g}", "seed": "0"}
    text = {k: d if getattr(args, k) is None else getattr(args, k) for k, d in defaults.items()}
    minutes = flags.number("--minutes", text["minutes"], low=0, closed=False)
    dt = flags.period("--plan-dt", text["plan_dt"])
    seed = flags.positive_int("--seed", text["seed"], minimum=0)
    path = Path(flags.output_file("--plan", args.plan))
    commands = plan.plan_commands(robot, dt, minutes, seed)
    rows = np.column_stack([np.arange(len(commands)) * dt, commands])
    lines = ["t,v_cmd,omega_cmd", *(",".join(f"{v:.6f}" for v in row) for row in rows)]
    io.atomic_write_text(path, "\n".join(lines) + "\n")  # and makes its folder
    print(f"wrote {len(commands)} commands ({minutes:g} min at {dt:g} s) to {path}")
    return 0
