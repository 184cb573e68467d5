"""``wmr-jax export``: a tuned loop as a C controller for the robot (docs/deploy.md)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax export``."""
    parser.add_argument("--gains", required=True, metavar="FILE.json", help=flags.GAINS_FILE_HELP)
    parser.add_argument(
        "--out", required=True, metavar="DIR", help="folder to write the C files into"
    )
    parser.add_argument(
        "--real",
        default="double",
        metavar="TYPE",
        help="arithmetic of the controller's step: double or float",
    )
    parser.add_argument(
        "--period",
        metavar="S",
        help="control period the C is called at, s: the one the gains were tuned for "
        "(a tuned_gains.json does not record it; default the project's DEFAULT_DT, 0.033)",
    )
    flags.add_robot_flag(parser, default="the --gains file's robot, else paper")


def _object_size(folder: Path) -> tuple[int, int] | None:
    """``(sizeof(wmr_controller), bytes of the compiled code)``, or ``None`` without a compiler."""
    from wmr_jax._src.export.compiled import compile_controller, compiler
    from wmr_jax._src.studies.bench import code_bytes

    if compiler() is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        try:
            size = compile_controller(folder, build=tmp).size
        except RuntimeError as err:
            raise ValueError(f"the exported C does not compile: {err}") from None
        return size, code_bytes(folder / "wmr_controller.c", Path(tmp))


def _longest_settling_period(check: Any, params: Any, period: float, category: type) -> float:
    """The period below which ``check(params, dt)`` no longer warns ``category``: the
    sampling margins grow with the period (docs/model.md §4), so a bisection finds it."""
    import warnings

    low, high = 0.0, period
    for _ in range(60):
        middle = (low + high) / 2
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check(params, middle)
        if any(issubclass(r.category, category) for r in caught):
            high = middle
        else:
            low = middle
    return low


def run(args: Any) -> int:
    """Run ``wmr-jax export``; return the exit status."""
    from wmr_jax._src.export.codegen import REALS, c_sources, write_sources
    from wmr_jax._src.sim.rollout import DEFAULT_DT

    out = flags.output_dir("--out", args.out)
    real = flags.choice("--real", args.real, REALS)
    period = DEFAULT_DT
    if args.period is not None:
        period = flags.period("--period", args.period)
    given = flags.robot_from(args.robot)
    loop = flags.tuned_file("--gains", args.gains)[0]
    robot = flags.robot_for_gains(given, loop.robot, "--gains", args.gains)
    if robot is not None:
        loop = loop._replace(robot=robot)
    import warnings

    from wmr_jax._src.model.controllers import get_controller
    from wmr_jax._src.model.params import Robot, SamplingWarning

    control = get_controller(loop.controller)
    # What a rollout of these gains warns of: the wheel budget, then the period. A
    # controller that cannot settle at its period is not written (it would drive a robot).
    checks = [("--gains", control.check_robot, Robot() if loop.robot is None else loop.robot)]
    checks.append((f"--period {period:g} s", control.check_sampling, period))
    for shown, check, against in checks:
        if check is None:
            continue
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check(loop.params, against)
        for record in caught:
            if issubclass(record.category, SamplingWarning):
                given = "" if args.period is not None else " (the default)"
                longest = _longest_settling_period(check, loop.params, period, SamplingWarning)
                raise ValueError(
                    f"--period {period:g}{given} is not allowed for {args.gains}: "
                    f"{record.message}; allowed: a period below {longest:.4g} s, at which "
                    "these gains settle (or gains tuned for this one)"
                )
            warnings.warn(f"{shown}: {record.message}", record.category, 2)
    sources = c_sources(loop, real=real, period=period)
    for path in write_sources(out, sources, loop):
        print(f"export -> {path}")
    sizes = _object_size(out)
    if sizes is not None:
        print(f"sizeof(wmr_controller) = {sizes[0]} bytes; code and constants: {sizes[1]} bytes")
    print(f"period {sources.period:g} s, latency 0 to {sources.max_latency} periods, {real}")
    return 0
