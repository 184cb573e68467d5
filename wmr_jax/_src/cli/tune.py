"""``wmr-jax tune``: tune gains by gradient descent under k_r + L k_θ ≤ V_max."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags

# flag, TuneConfig field (or None), metavar, help
_FLAGS = (
    ("--velocity", "velocity", "ideal|nonideal", "velocity loop the gains are tuned for"),
    ("--iters", "iters", "N", "gradient iterations"),
    ("--poses", "poses", "N", "reference poses per iteration"),
    ("--seed", "seed", "S", "seed of the training poses and the random search"),
    (
        "--horizon",
        "horizon",
        "S",
        "simulated time per run, s; longer for a --robot too slow for the paper's gains",
    ),
    ("--eval-poses", "eval_poses", "N", "held-out poses of the before/after table"),
    ("--checkpoint-every", "checkpoint_every", "N", "iterations between checkpoints"),
)


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax tune``."""
    from wmr_jax._src.sim.poses import HORIZON_S
    from wmr_jax._src.tuning.robust import RobustConfig
    from wmr_jax._src.tuning.training import TuneConfig

    defaults = TuneConfig()
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    for flag, field, metavar, text in _FLAGS:
        # None stands for "not given": --schedule and --robust have defaults of their own.
        default = getattr(defaults, field)
        if field == "horizon":  # None: the robot's (studies.study_horizon)
            default = f"the robot's study horizon, {HORIZON_S:g} on the paper robot"
        if field in ("iters", "poses"):
            robust = getattr(RobustConfig(), field)
            scheduled = getattr(TuneConfig.for_problem("schedule"), field)
            default = f"{default}, {scheduled} with --schedule, {robust} with --robust"
        parser.add_argument(flag, metavar=metavar, help=f"{text} (default: {default})")
    parser.add_argument(
        "--no-random-search",
        action="store_true",
        help="skip the random-search baseline (same CPU time as the tuning)",
    )
    flags.add_robot_flag(parser)
    for flag, (metavar, text) in _MODE_FLAGS.items():
        kind = {"action": "store_true"} if metavar is None else {"metavar": metavar}
        parser.add_argument(flag, help=text, **kind)


# The flags that choose and shape a mode: flag -> (metavar, or None for a switch; help).
_MODE_FLAGS = {
    "--resume": (
        None,
        "continue from DIR/checkpoint.npz (same settings) instead of starting over; with "
        "--compare, keep the seeds DIR/compare.json (robust_compare.json) already holds",
    ),
    "--schedule": (
        None,
        "tune the gain-scheduled law (35 parameters by default, docs/model.md §3.9) instead of "
        "the 7 fixed gains, with the schedule's own defaults for --iters, the step and the "
        "annealing (wmr_jax.tuning.TuneConfig.for_problem)",
    ),
    "--knots": (
        "K",
        "with --schedule: knots per table, 3K + 5 parameters (default: 10, 35 parameters; at "
        "most 60, whose gradient takes 40 s and 2.4 GB to compile)",
    ),
    "--robust": (
        None,
        "tune the gain schedule and a pose estimator together for robustness to noise, latency "
        "and a robot unlike its model (docs/model.md §7, §9); with --compare, gradient against "
        "CMA-ES and random search at equal compute (the candidates an iteration's CPU time "
        "buys), seeds 0-2",
    ),
    "--fixed": (None, "with --robust: tune the 7 fixed gains with raw feedback instead"),
    "--estimator": (
        "NAME",
        "with --robust: the estimator tuned with the law: ekf, observer or none (raw feedback) "
        "(default: ekf; none with --fixed)",
    ),
    "--noise": (
        "CM",
        "with --robust: your sensor's position noise σ_xy in cm; the tuning trains on up to "
        "twice it and judges the noise conditions at it (default: 0.5)",
    ),
    "--noise-theta": (
        "DEG",
        "with --robust: your sensor's heading noise σ_θ in degrees, as --noise (default: 1)",
    ),
    "--compare": (
        None,
        "instead of tuning once, compare gradient, CMA-ES and random search at equal CPU time, "
        "fixed gains and schedules (with --schedule: the schedule only), seeds 0-2, into "
        "DIR/compare.{json,md}",
    ),
    "--price": (
        "C",
        "with --robust --compare: candidates one gradient iteration is worth in the searches' "
        "budget; a price robust_compare.json recorded gives them as many candidates on any "
        "machine (default: measured)",
    ),
}


def _horizon(args: Any) -> float | None:
    """``--horizon`` (warned of when it looks like milliseconds), else ``None``: the robot's."""
    if args.horizon is None:
        return None
    given = flags.robot_from(args.robot)
    return flags.horizon("--horizon", args.horizon, None if given is None else given.robot)


def _config_from(args: Any, *, problem: str) -> Any:
    """The ``TuneConfig`` of the flags, each checked (one line naming a bad one)."""
    from wmr_jax._src.sim.poses import MAX_SAMPLES
    from wmr_jax._src.tuning.problems import MAX_TUNED_KNOTS
    from wmr_jax._src.tuning.training import TuneConfig

    base = TuneConfig.for_problem(problem)

    def given(name: str) -> Any:
        # A flag left alone keeps the problem's default.
        value = getattr(args, name)
        return getattr(base, name) if value is None else value

    config = base.replace(
        velocity=flags.velocity_loop(given("velocity")),
        iters=flags.positive_int("--iters", given("iters"), 1),
        poses=flags.positive_int("--poses", given("poses"), 1, MAX_SAMPLES),
        seed=flags.positive_int("--seed", given("seed"), 0, 2**32 - 1),
        horizon=_horizon(args),
        eval_poses=flags.positive_int("--eval-poses", given("eval_poses"), 1, MAX_SAMPLES),
        checkpoint_every=flags.positive_int("--checkpoint-every", given("checkpoint_every"), 1),
        random_search=not args.no_random_search,
    )
    if problem == "schedule" and args.knots is not None:
        knots = flags.positive_int("--knots", args.knots, 2, MAX_TUNED_KNOTS)
        config = config.replace(knots=knots)
    return config.validate()  # the horizon against dt, before any work


def _check_modes(args: Any) -> None:
    """Refuse flags the chosen mode would ignore (one line naming them)."""
    for name in ("fixed", "estimator", "noise", "noise_theta"):
        if getattr(args, name) not in (None, False) and not args.robust:
            flag = f"--{name.replace('_', '-')}"
            raise ValueError(f"{flag} is not allowed without --robust, whose problem it sets")
    if args.price is not None and not (args.robust and args.compare):
        raise ValueError("--price is not allowed without --robust --compare, which it budgets")
    # --robust --compare is the robust comparison (--knots sizes its schedule).
    mode = "robust" if args.robust else "compare" if args.compare else None
    if args.robust and args.compare:
        for flag, value in (("--seed", args.seed), ("--checkpoint-every", args.checkpoint_every)):
            if value is not None:
                why = "runs seeds 0-2" if flag == "--seed" else "keeps each seed, not checkpoints"
                raise ValueError(f"{flag} is not allowed with --robust --compare, which {why}")
    if args.knots is not None and not args.schedule and not args.robust:
        raise ValueError("--knots is not allowed without --schedule, whose tables it sizes")
    unused = {
        "robust": ("schedule", "horizon", "eval_poses", "no_random_search"),
        "compare": ("seed", "checkpoint_every", "no_random_search"),
    }.get(mode, ())
    for name in unused:
        if getattr(args, name) not in (None, False):
            flag, other = f"--{name.replace('_', '-')}", f"--{mode}"
            why = "which does not use it"
            if (mode, name) == ("robust", "schedule"):
                why = "which tunes a gain schedule already (and fixed gains with --fixed)"
            raise ValueError(f"{flag} is not allowed with {other}, {why}")


def _shown(params: Any) -> list[str]:
    """The tuned parameters as printed, angles in degrees; fixed gains also as simulate flags."""
    import math

    from wmr_jax._src.model.params import Gains
    from wmr_jax._src.report.tuning import SYMBOLS
    from wmr_jax._src.tuning.saved import tuned_json

    def fmt(name: str, value: Any) -> str:
        symbol, unit = SYMBOLS[name]
        to_unit = math.degrees if name == "phi_m" else float
        if isinstance(value, list):
            text = "[" + ", ".join(f"{to_unit(x):.3g}" for x in value) + "]"
        else:
            text = f"{to_unit(value):.4g}"
        return f"{symbol}={text}{'' if unit in ('', '°') else ' '}{unit}"

    values = tuned_json(params)
    lines = ["  ".join(fmt(k, v) for k, v in values.items() if k in SYMBOLS)]
    if isinstance(params, Gains):
        lines.append("as simulate flags: " + " ".join(flags.gain_flag_values(params)))
    return lines


def _compare(out: Path, args: Any, robot: Any) -> int:
    from wmr_jax._src.report.tuning import comparison_table
    from wmr_jax._src.tuning.compare import run_comparison

    # Each problem over the robot's horizon, as a single tuning run has it.
    schedule = _robot_horizon(args, _config_from(args, problem="schedule"), robot)
    configs = {"schedule": schedule}
    if not args.schedule:  # both problems, unless --schedule asks for the schedule alone
        fixed = _config_from(args, problem="fixed").replace(horizon=schedule.horizon)
        configs = {"fixed": fixed.validate(), **configs}
    rows = run_comparison(out, configs, robot=robot, resume=args.resume, progress=print)
    print(comparison_table(rows), end="")
    print(f"-> {out / 'compare.json'}, {out / 'compare.md'}")
    return 0


def _robot_horizon(args: Any, config: Any, robot: Any) -> Any:
    """The config with ``robot``'s studies' horizon unless ``--horizon`` is given (said)."""
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.sim.poses import HORIZON_S

    config = config.for_robot(Robot() if robot is None else robot)
    if args.horizon is None and config.horizon != HORIZON_S:
        print(
            f"horizon {config.horizon:g} s for this robot (the paper robot's {HORIZON_S:g} s, "
            "stretched as its wheels need; --horizon sets another)"
        )
    return config


def run(args: Any) -> int:
    """Run ``wmr-jax tune``; return the exit status."""
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.model.robots import describe_robot

    _check_modes(args)
    if args.compare:  # before JAX starts: CPU time then counts the work (search.one_core)
        from wmr_jax._src.tuning.search import one_core

        one_core()
    if args.robust:
        from wmr_jax._src.cli import tune_robust

        return tune_robust.run(args)
    out = flags.output_dir("--out", args.out)
    config = _config_from(args, problem="schedule" if args.schedule else "fixed")
    given = flags.robot_from(args.robot)
    if given is not None and given.note:
        print(given.note)
    robot = None if given is None else given.robot
    if args.compare:
        return _compare(out, args, robot)
    config = _robot_horizon(args, config, robot)
    from wmr_jax._src.report.tuning import evaluation_table
    from wmr_jax._src.tuning import run as tuning_run

    if args.resume and tuning_run.finished(out, config, robot):
        print(
            f"--resume: {out} holds this run finished (tuned_gains.json, evaluation.json); "
            "nothing to resume. Without --resume it tunes again from the start"
        )
        return 0
    result = tuning_run.tune(out, config, robot=robot, resume=args.resume)
    robot = Robot() if robot is None else robot
    kind = "gain schedule" if config.problem == "schedule" else "gains"
    print(f"tuned {kind} ({config.velocity} loop) -> {out / 'tuned_gains.json'}")
    for line in _shown(result.gains):
        print("  " + line)
    print(f"  for the robot {describe_robot(robot)}")
    print(
        f"held-out evaluation, {config.eval_poses} poses (docs/model.md §6), hard law "
        f"-> {out / 'evaluation.json'}"
    )
    bounds = tuning_run.held_out_bounds(config, robot)
    print(evaluation_table(result.evaluation, bounds), end="")
    search = result.search
    extra = "" if search is None else f"; random search {search.candidates} candidates"
    kept = f"kept iteration {result.best_iteration} (best validation score)"
    print(f"tuning CPU time {result.tune_cpu_s:.1f} s{extra}; {kept}")
    if result.note is not None:
        print(result.note)
    print(f"curve -> {out / 'tuning_curve.png'}")
    return 0
