"""``wmr-jax simulate``: drive the robot to one reference pose and report."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax simulate``."""
    parser.add_argument(
        "--ref",
        nargs=3,
        required=True,
        metavar=("X", "Y", "THETA_DEG"),
        help="reference pose: cm, cm, degrees",
    )
    parser.add_argument(
        "--init",
        nargs=3,
        default=["0", "0", "0"],  # shown as typed: (default: 0 0 0)
        metavar=("X", "Y", "THETA_DEG"),
        help="initial pose: cm, cm, degrees",
    )
    parser.add_argument("--dt", default=0.033, metavar="S", help="control period, s")
    parser.add_argument(
        "--steps",
        metavar="N",
        help="control periods (default: 150 on the paper robot; on a slower robot as many "
        "times more as the studies' horizon is longer there, docs/robustness.md)",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument("--plot", metavar="FILE.png", help="save the path to this image")
    parser.add_argument(
        "--gains",
        metavar="FILE.json",
        help="take the controller and its parameters from this file (tuned_gains.json of "
        "wmr-jax tune: fixed gains or a gain schedule) instead of the gain flags; the robot "
        "it was tuned for comes with it",
    )
    flags.add_robot_flag(parser, default="paper, or the --gains file's robot")
    flags.add_gain_flags(parser)


def _controller_and_gains(args: Any) -> tuple[Any, Any, Any]:
    """The law, parameters and robot of ``--gains FILE``, else of the gain flags."""
    from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG

    if args.gains is None:
        return SHIM_SUNG, flags.gains_from(args), None
    given = flags.given_gain_flags(args)
    if given:
        raise ValueError(f"{given[0]} is not allowed with --gains; allowed: one or the other")
    loop = flags.tuned_file("--gains", args.gains)[0]
    if loop.estimator is not None:
        # docs/model.md §9: without noise or latency every estimator gives the nominal run.
        print(
            f"the file's estimator ({type(loop.estimator).__name__}) is not needed here: "
            "simulate measures without noise or latency, where the estimate is the pose "
            "(wmr-jax evaluate runs it under noise)"
        )
    return loop.controller, loop.params, loop.robot


def _degrees(theta: float) -> float:
    """A heading in degrees, wrapped into (-180°, 180°]: 945° is printed as -135°."""
    wrapped = math.remainder(theta, 2 * math.pi)  # [-π, π]
    return math.degrees(wrapped + 2 * math.pi if wrapped <= -math.pi else wrapped)


def default_steps(robot: Any) -> int:
    """``rollout``'s default steps stretched as the studies' horizon is on a slower robot."""
    from wmr_jax._src.sim.loops import DEFAULT_STEPS
    from wmr_jax._src.sim.poses import HORIZON_S
    from wmr_jax._src.studies.robustness import study_horizon

    stretch = 1.0 if robot is None else study_horizon(robot) / HORIZON_S
    return math.ceil(DEFAULT_STEPS * stretch - 1e-9)


# The most periods --steps allows.
MAX_STEPS = 10**7


def _not_arrived(steps: int, dt: float, gap: float, robot: Any, unsettled: bool) -> str:
    """What to try after a run that did not arrive."""
    from wmr_jax._src.model.params import Robot

    if unsettled:
        return (
            f"not arrived in {steps * dt:.3g} s; the sampled law cannot settle with these "
            "gains at this --dt (the warning above): a smaller --dt or smaller gains "
            "(docs/model.md §4.2.1)"
        )
    v_max = float((Robot() if robot is None else robot).v_max)
    need = gap / v_max  # the least time to drive there at V_max
    if 3 * need / dt > MAX_STEPS:
        return (
            f"not arrived in {steps * dt:.3g} s; the goal is {gap:.3g} cm away, at least "
            f"{need:.3g} s at V_max = {v_max:g} cm/s: more than one run of --steps {MAX_STEPS} "
            "simulates (--ref is in cm; a larger --dt covers more time)"
        )
    longer = min(max(4 * steps, math.ceil(3 * need / dt)), MAX_STEPS)
    if longer <= steps:
        return f"not arrived in {steps * dt:.3g} s, the longest run --steps allows"
    return (
        f"not arrived in {steps * dt:.3g} s; a longer run, such as --steps {longer}, shows "
        "whether it arrives later"
    )


def plot_title(ref: Any, controller: Any, gains: Any, gains_file: Any) -> str:
    """The title of ``--plot``: the reference and the gains that drove to it."""
    from wmr_jax._src.model.params import Gains

    where = f"ref = ({ref[0]:g}, {ref[1]:g}, {math.degrees(ref[2]):g}°)"
    if isinstance(gains, Gains):
        what = (
            f"k_r = {float(gains.kr):.4g}, k_θ = {float(gains.k_theta):.4g}, "
            f"Φ_m = {math.degrees(float(gains.phi_m)):.4g}°"
        )
    else:
        what = controller.name
    if gains_file is not None:
        what += f" ({Path(str(gains_file)).name})"
    return f"{where}; {what}"


def run(args: Any) -> int:
    """Run ``wmr-jax simulate``; return the exit status."""
    import numpy as np

    from wmr_jax._src.checks import position_limit
    from wmr_jax._src.identify.closed_loop import identified_rollout, loaded_identified
    from wmr_jax._src.model.params import Robot, SamplingWarning
    from wmr_jax._src.model.robots import describe_robot, same_robot
    from wmr_jax._src.sim import metrics
    from wmr_jax._src.sim.metrics import DEFAULT_TOL_R
    from wmr_jax._src.sim.rollout import make_options, prepare, rollout

    plot = None if args.plot is None else flags.image_file("--plot", args.plot)
    ref = flags.pose_from_degrees("--ref", args.ref)
    init = flags.pose_from_degrees("--init", args.init)
    dt = flags.period("--dt", args.dt)
    if args.steps is not None:
        steps = flags.positive_int("--steps", args.steps, 1, MAX_STEPS)
    velocity = flags.velocity_loop(args.velocity)
    identified = loaded_identified(args.robot, dt)
    given = flags.robot_from(args.robot) if identified is None else identified[0]
    controller, gains, saved = _controller_and_gains(args)
    robot = flags.robot_for_gains(given, saved, "--gains", args.gains)
    if given is not None and given.note:
        print(given.note)
    if args.steps is None:
        steps = default_steps(robot)
    same = {"init": init, "dt": dt, "steps": steps, "velocity": velocity, "controller": controller}
    caught: list = []
    try:
        with flags.as_flags({"ref": "--ref", "init": "--init", "dt": "--dt"}):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                if identified is not None:
                    # The rollout's checks and warnings (wheel bound, sampling) for the base robot.
                    options = make_options(steps=steps, velocity=velocity, controller=controller)
                    prepare(ref, gains, init, robot, dt, options, batch=False)
                    traj = identified_rollout(
                        ref, gains, base=robot, identified=identified[1], **same
                    )
                else:
                    traj = rollout(ref, gains, robot=robot, **same)
    finally:  # said as they came, before an error they may explain; the hint reads them
        for record in caught:
            warnings.warn_explicit(record.message, record.category, record.filename, record.lineno)
    unsettled = any(issubclass(r.category, SamplingWarning) for r in caught)
    gap = math.hypot(ref[0] - init[0], ref[1] - init[1])
    if 0.0 < gap <= DEFAULT_TOL_R:
        flags.unit_slip(
            f"--ref lies {gap:.3g} cm from the start, inside the arrival tolerance "
            f"({DEFAULT_TOL_R:g} cm); x and y are read as cm (metres need times 100)"
        )
    reach = float(np.max(np.abs(np.asarray(traj.poses)[:, :2])))
    if not reach <= position_limit():  # NaN too: the metrics could not judge the run
        cause = "the warning above says why" if unsettled else "see docs/model.md §4.2.1"
        raise ValueError(
            f"the run diverged: the robot reached x or y = ±{reach:.3g} cm ({cause}); "
            "allowed: gains and a --dt the sampled law settles with"
        )
    t_arrive = float(metrics.arrival_time(traj, np.asarray(ref), dt=dt))
    per_region = np.asarray(metrics.region_time(traj, dt=dt))
    final = np.asarray(traj.poses[-1])
    if robot is not None and not same_robot(robot, Robot()):
        # Shown only off the paper robot, the one every other run of the command uses.
        shown = describe_robot(robot)
        if given is not None and flags.is_robot_file(given.label):
            shown += f", from {given.label}"
        print(f"robot          : {shown}")
    if args.gains is not None:
        print(f"gains          : {args.gains} ({controller.name})")
    print(f"reference      : x={ref[0]:.3f} cm  y={ref[1]:.3f} cm  θ={_degrees(ref[2]):.2f}°")
    # The law folds front and back alike: a robot facing θ_r ± 180° is at its goal.
    turned = math.remainder(float(final[2]) - ref[2], 2 * math.pi)
    facing = (
        f"  (facing backwards: θ − θ_r = {math.degrees(turned):.1f}°; front and back count alike)"
        if math.cos(turned) < 0 and not math.isinf(t_arrive)  # said of a robot at its goal only
        else ""
    )
    print(
        f"final pose     : x={final[0]:.3f} cm  y={final[1]:.3f} cm  "
        f"θ={_degrees(float(final[2])):.2f}° after {steps * dt:.3f} s{facing}"
    )
    arrival = "never (not arrived at the end)" if math.isinf(t_arrive) else f"{t_arrive:.3f} s"
    print(f"arrival time   : {arrival}")
    if math.isinf(t_arrive):
        print(f"hint           : {_not_arrived(steps, dt, gap, robot, unsettled)}")
    # On an identified robot the law sees noisy measurements: no true region to time.
    regions = (
        "not timed (the law sees the tracker's noisy poses)"
        if identified is not None
        else "  ".join(f"R{k}={per_region[k]:.3f} s" for k in range(4))
    )
    print(
        f"time per region: {regions}"
        + f"  (peak wheel speed {float(np.abs(np.asarray(traj.wheel_speeds)).max()):.1f} cm/s, "
        f"V_max {float((Robot() if robot is None else robot).v_max):.4g} cm/s)"
    )
    if plot is not None:
        from wmr_jax._src.report.figures import path_figure

        path_figure(plot, traj, ref, title=plot_title(ref, controller, gains, args.gains))
        print(f"plot           : {plot}")
    return 0
