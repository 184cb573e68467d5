"""``wmr-jax tune --robust``: controller and estimator tuned together (docs/model.md §7, §9).

Called by ``wmr-jax tune`` with its parsed flags. Writes ``tuned_gains.json``,
``robust_evaluation.{json,md}`` and ``robust_loss.json``; with ``--compare``,
seeds 0–2 against CMA-ES and random search into ``robust_compare.{json,md}``.
"""

from __future__ import annotations

import functools
from typing import Any

from wmr_jax._src.cli import flags

# Below these a sensor's noise is finer than most motion capture resolves: the value
# was most likely given in metres or radians.
_FINEST_XY = 0.01  # cm
_FINEST_THETA = 0.05  # degrees
# Ten times the arrival tolerances the tuner is judged by (1 cm, 5 degrees): above,
# no loop settles within them, and the tuner has nothing to descend.
_COARSEST = {"--noise": 10.0, "--noise-theta": 50.0}


def config_from(args: Any) -> Any:
    """The ``RobustConfig`` of the flags, each checked (one line naming a bad one)."""
    from wmr_jax._src.sim.sensing.estimators import BUILT_IN
    from wmr_jax._src.tuning.problems import MAX_TUNED_KNOTS
    from wmr_jax._src.tuning.robust import RobustConfig

    seed = getattr(args, "seed", None)
    seed = flags.positive_int("--seed", 0 if seed is None else seed, 0, 2**32 - 1)
    changes: dict[str, Any] = {"seed": seed}
    for flag, name in (("--iters", "iters"), ("--poses", "poses")):
        value = getattr(args, name, None)
        if value is not None:  # else the robust tuner's own default
            changes[name] = flags.positive_int(flag, value)
    velocity = getattr(args, "velocity", None)
    if velocity is not None and flags.velocity_loop(velocity) != "ideal":
        raise ValueError(
            f"--velocity {velocity!r} is not allowed with --robust; allowed: ideal "
            "(the robust loss mixes both loops itself)"
        )
    fixed = bool(getattr(args, "fixed", False))
    law = "fixed" if fixed else "schedule"
    estimator = getattr(args, "estimator", None)
    if estimator is not None:
        changes["estimator"] = flags.estimator(estimator)
        if changes["estimator"] not in (None, *BUILT_IN):  # a registered one: not tunable
            raise ValueError(
                f"--estimator {estimator!r} is not allowed with --robust; allowed: none, ekf or "
                "observer, the estimators the tuner knows"
            )
    elif fixed:  # raw feedback; the schedule keeps RobustConfig's estimator
        changes["estimator"] = None
    changes.update(law=law, compare=False)
    for flag, name, unit, finest, other in (
        ("--noise", "noise_xy", "cm", _FINEST_XY, "metres needs times 100"),
        ("--noise-theta", "noise_theta", "degrees", _FINEST_THETA, "radians needs times 180/pi"),
    ):
        value = getattr(args, flag[2:].replace("-", "_"), None)
        if value is not None:
            changes[name] = flags.number(flag, value, low=0.0, unit=unit)
            if 0 < changes[name] < finest:  # finer than motion capture: another unit
                flags.unit_slip(
                    f"{flag} {value} is read in {unit}, finer than most motion-capture trackers "
                    f"(under {finest:g} {unit}); a value in {other}"
                )
            if changes[name] > _COARSEST[flag]:
                flags.unit_slip(
                    f"{flag} {value} is read in {unit}, over ten times the arrival tolerance "
                    f"the tuner judges by ({_COARSEST[flag] / 10:g} {unit}): no loop settles "
                    "within it under such noise (a value in mm needs /10)"
                    if flag == "--noise"
                    else f"{flag} {value} is read in {unit}, over ten times the arrival "
                    f"tolerance the tuner judges by (5 degrees): no loop settles within it"
                )
    price = getattr(args, "price", None)
    if price is not None:
        changes["price"] = flags.number(
            "--price", price, low=0.0, closed=False, unit="candidates per iteration"
        )
    knots = getattr(args, "knots", None)
    if knots is not None:
        if fixed:
            raise ValueError("--knots is not allowed with --fixed, which tunes no tables")
        changes["knots"] = flags.positive_int("--knots", knots, 2, MAX_TUNED_KNOTS)
    return RobustConfig(**changes).validate()


def _around_identified(config: Any, args: Any) -> Any:
    """With ``--robot`` an ``identified.json``: training centred on it (``tuning/centred.py``)."""
    import math

    from wmr_jax._src.identify.closed_loop import is_identified, read_identified
    from wmr_jax._src.tuning.centred import for_config

    source = getattr(args, "robot", None)
    if not is_identified(source):
        return config
    for flag in ("--noise", "--noise-theta"):
        if getattr(args, flag[2:].replace("-", "_"), None) is not None:
            raise ValueError(
                f"{flag} is not allowed with --robot {source}; allowed: the tracker noise it "
                "identified"
            )
    config = for_config(config, read_identified(source)[1])
    r = config.around
    print(
        f"training centred on the robot identified in {source}: wheel scales "
        f"U[{r.scale_left[0]:.5g}, {r.scale_left[1]:.5g}] and U[{r.scale_right[0]:.5g}, "
        f"{r.scale_right[1]:.5g}], latency {' or '.join(map(str, r.latency))} samples, "
        f"σ_xy U[{r.noise_xy[0]:.3g}, {r.noise_xy[1]:.3g}] cm, σ_θ "
        f"U[{math.degrees(r.noise_theta[0]):.3g}, {math.degrees(r.noise_theta[1]):.3g}]°"
    )
    return config


def run(args: Any) -> int:
    """Run ``wmr-jax tune --robust``; return the exit status."""
    from wmr_jax._src.model.params import Robot

    out = flags.output_dir("--out", args.out)
    config = config_from(args)
    given = flags.robot_from(args.robot)
    if given is not None and given.note:
        print(given.note)
    robot = Robot() if given is None else given.robot
    config = _around_identified(config, args)
    if args.compare:
        return _compare(out, config, robot, resume=args.resume)

    from wmr_jax._src.model.robots import describe_robot
    from wmr_jax._src.studies.robustness import study_horizon
    from wmr_jax._src.tuning.robust_run import described, finished, tune

    every = args.checkpoint_every
    every = None if every is None else flags.positive_int("--checkpoint-every", every)
    resume = args.resume
    if resume and finished(out, config, robot):
        print(
            f"--resume: {out} holds this run finished (tuned_gains.json, "
            "robust_evaluation.json); nothing to resume. Without --resume it tunes again"
        )
        return 0
    print(
        f"tuning the {described(config)} through the disturbances on the robot "
        f"{describe_robot(robot)}, horizon {study_horizon(robot):g} s",
        flush=True,
    )

    def progress(state: Any) -> None:
        i = state.iteration
        if i == 1 or i % 25 == 0 or i == config.iters:
            print(f"iteration {i}/{config.iters}: loss {state.losses[-1]:.3f} s", flush=True)

    say = functools.partial(print, flush=True)
    result, table = tune(
        out, config, robot, resume=resume, checkpoint_every=every, progress_fn=progress, say=say
    )
    print(f"robust_evaluation.md/json -> {out}")
    print(table, end="")
    if config.around is not None:  # trained around an identified robot, judged as any loop
        source = args.robot
        print(
            f"(the standard conditions, as for any loop; on the robot identified in {source}: "
            f"wmr-jax robustness --robot {source} --robust-gains {out / 'tuned_gains.json'} "
            "--out DIR)"
        )
    kept = f"kept iteration {result.best_iteration} (best validation score)"
    print(f"tuning CPU time {result.tune_cpu_s:.1f} s; {kept}")
    if result.note is not None:
        print(result.note)
    return 0


def _compare(out: Any, config: Any, robot: Any, *, resume: bool) -> int:
    """Gradient, CMA-ES and random search at equal compute, seeds 0–2; each seed kept."""
    from wmr_jax._src.report.tuning import robust_comparison_table
    from wmr_jax._src.tuning.robust import evosax_available
    from wmr_jax._src.tuning.robust_run import run_comparison

    if not evosax_available():
        print(
            "CMA-ES skipped: evosax is not installed (pip install 'wmr_jax[search]'); "
            "comparing the gradient with random search only"
        )
    rows = run_comparison(out, config, robot=robot, resume=resume, progress=print)
    print(robust_comparison_table(rows), end="")
    print(f"-> {out / 'robust_compare.json'}, {out / 'robust_compare.md'}")
    return 0
