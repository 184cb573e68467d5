"""``wmr-jax animate``: animated GIF of a batch of robots driving to their poses."""

from __future__ import annotations

import math
from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax animate`` (their values are checked in ``run``)."""
    from wmr_jax._src.model.controllers import SHIM_SUNG, registered_names

    options = {
        "--out": {"required": True, "metavar": "FILE.gif", "help": "GIF to write"},
        "--controller": {
            "default": SHIM_SUNG.name,
            "metavar": "NAME",
            "help": "controller: " + ", ".join(registered_names()),
        },
        "--robots": {"metavar": "N", "help": "number of random references (default: 8)"},
        "--seed": {"metavar": "S", "help": "seed of the random references (default: 0)"},
        "--paper": {
            "action": "store_true",
            "help": "use the paper's seven Fig. 7 references instead of random ones",
        },
        "--velocity": {"default": "ideal", "help": "velocity loop: ideal or nonideal"},
        "--seconds": {"default": 4.0, "metavar": "S", "help": "simulated time, s"},
        "--speed": {
            "default": 1.0,
            "metavar": "X",
            "help": "playback speed, 1 = real time (each frame lasts its simulated time)",
        },
    }
    for flag, keywords in options.items():
        parser.add_argument(flag, **keywords)
    flags.add_robot_flag(parser)


def run(args: Any) -> int:
    """Run ``wmr-jax animate``; return the exit status."""
    import jax
    import numpy as np

    from wmr_jax._src.report.animation import (
        SQUARE_PIXELS,
        check_frames,
        frame_timing,
        gif_path,
        max_frames,
        run_title,
        write_gif,
    )
    from wmr_jax._src.sim.poses import horizon_steps, paper_refs, sample_poses
    from wmr_jax._src.sim.rollout import DEFAULT_DT, batch_rollout
    from wmr_jax._src.studies.robustness import robot_defaults

    gif_path("--out", args.out)
    out = flags.output_file("--out", args.out)
    name = flags.controller_names([args.controller])[0]
    given = flags.robot_from(args.robot)
    robot = None if given is None else given.robot
    velocity = flags.velocity_loop(args.velocity)
    for flag, value in (("--robots", args.robots), ("--seed", args.seed)):
        if args.paper and value is not None:
            raise ValueError(
                f"{flag} is not allowed with --paper, whose seven references it would not change"
            )
    robots = flags.positive_int("--robots", 8 if args.robots is None else args.robots, 1, 10_000)
    seed = flags.positive_int("--seed", 0 if args.seed is None else args.seed, 0, 2**32 - 1)
    # At least one control period, named as the flag (not as the horizon it sets).
    seconds = flags.number("--seconds", args.seconds, low=DEFAULT_DT, high=600.0, unit="s")
    speed = flags.number(
        "--speed", args.speed, low=0.0, closed=False, high=100.0, unit="× real time"
    )
    # A speed no GIF can play, or more frames than memory holds, is refused before the runs.
    stride, _ = frame_timing(DEFAULT_DT, None, speed)
    shown = f"--seconds {seconds:g} at --speed {speed:g}"
    longest = (max_frames(SQUARE_PIXELS) - 1) * stride * DEFAULT_DT  # the frames' span, s
    longest = math.floor(longest * 100) / 100  # shown rounded down: the value shown is allowed
    remedy = f" (--seconds {longest:.2f} at the most at --speed {speed:g})"
    check_frames(horizon_steps(DEFAULT_DT, seconds) + 1, stride, SQUARE_PIXELS, shown, remedy)
    params = robot_defaults(name, robot)
    flags.say_robot(given)
    refs = np.asarray(paper_refs() if args.paper else sample_poses(seed, robots), dtype=float)
    steps = horizon_steps(DEFAULT_DT, seconds)
    with jax.enable_x64(True):
        runs = batch_rollout(
            refs, params, steps=steps, robot=robot, velocity=velocity, controller=name
        )
    title = run_title(name, velocity, len(refs))
    path = write_gif(out, np.asarray(runs.poses), refs, dt=DEFAULT_DT, title=title, speed=speed)
    print(f"animation -> {path}")
    return 0
