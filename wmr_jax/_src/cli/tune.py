"""``wmr-jax tune``: tune gains by gradient descent under k_r + L k_θ ≤ V_max.

The engine (``wmr_jax.tuning.train``) writes nothing; this command shows a
progress bar, checkpoints from the engine's progress callback, and writes
``tuned_gains.json``, ``random_search_gains.json``, ``evaluation.json`` and
``tuning_curve.png``. ``tune`` is the same as a function.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["CHECKPOINT_NAME", "SUBCOMMANDS", "tune"]

CHECKPOINT_NAME = "checkpoint.npz"
_CHECKPOINT_FORMAT = 2  # 1: the unchecked .npz before the checksummed files


# ---------------------------------------------------------------- checkpoints


def _save_checkpoint(path: Path, state: Any, identity: dict[str, Any]) -> None:
    from wmr_jax._src import io, tuning

    meta = {"format": _CHECKPOINT_FORMAT, "identity": identity}
    io.save_arrays(path, tuning.state_arrays(state), meta)


def _load_checkpoint(path: Path, fresh: Any, identity: dict[str, Any]) -> Any:
    """Restore a checkpoint into the structure of ``fresh``.

    Raises:
        ValueError: one line, if it is damaged or belongs to another run.
    """
    import json

    from wmr_jax._src import io, tuning

    advice = "remove it to start over"
    try:
        arrays, meta = io.load_arrays(path)
    except io.DamagedFileError as err:
        raise ValueError(f"--resume: checkpoint {' '.join(str(err).split())}; {advice}") from None
    if not isinstance(meta, dict):
        raise ValueError(
            f"--resume: checkpoint {path} has metadata of the wrong shape ({meta!r:.60}; "
            f"allowed: an object with 'format' and 'identity'); {advice}"
        )
    if meta.get("format") != _CHECKPOINT_FORMAT:
        raise ValueError(
            f"--resume: checkpoint {path} has an unknown format (format = "
            f"{meta.get('format')!r:.40}; allowed: {_CHECKPOINT_FORMAT}); {advice}"
        )
    saved = meta.get("identity")
    shape = {"config": dict, "robot": dict}
    if not isinstance(saved, dict) or not all(
        isinstance(saved.get(key), kind) for key, kind in shape.items()
    ):
        raise ValueError(
            f"--resume: checkpoint {path} has metadata of the wrong shape (identity = "
            f"{saved!r:.60}; allowed: an object with a 'config' and a 'robot' object); {advice}"
        )
    # Compare as JSON, the way the identity was stored.
    now = json.loads(json.dumps(identity))
    if saved != now:
        raise ValueError(
            f"--resume: checkpoint {path} is of another run "
            f"({tuning.run_difference(meta.get('identity'), now)}); "
            "allowed: the same settings, or a fresh --out"
        )
    try:
        return tuning.restore_state(arrays, fresh)
    except ValueError as err:
        raise ValueError(f"--resume: checkpoint {path}: {err}; {advice}") from None


# ---------------------------------------------------------------- the run


def _progress(
    config: Any, checkpoint: Path, identity: dict[str, Any], bar: Any, user_fn: Callable | None
) -> Callable[[Any], None]:
    """The training's progress callback: the bar, the checkpoint, then the caller's."""

    def report(state: Any) -> None:
        bar.update(1)
        bar.set_postfix(
            loss=f"{state.losses[-1]:.3f}s", T=f"{state.temperatures[-1]:.3g}", refresh=False
        )
        last = state.iteration == config.iters
        if last or state.iteration % config.checkpoint_every == 0:
            _save_checkpoint(checkpoint, state, identity)
        if last:
            bar.close()  # before the random search and the evaluation
        if user_fn is not None:
            user_fn(state)

    return report


def held_out_bounds(config: Any, robot: Any) -> Any:
    """The time-optimal yardsticks (docs/model.md §8) of the held-out poses of ``config``."""
    from wmr_jax._src.optimal import time_bounds
    from wmr_jax._src.tuning.evaluation import held_out_poses

    refs = held_out_poses(config.eval_poses, config.eval_seed)
    return time_bounds(refs, robot=robot, dt=config.dt)


def _write_results(
    out: Path, config: Any, robot: Any, result: Any, resumed_at: int | None = None
) -> None:
    """Write the parameters, the evaluation and the tuning curve of ``result`` to ``out``.

    ``resumed_at``: the iteration this session resumed from (``None``: it ran
    them all); recorded beside the wall times, which count every session's
    compilation.

    Raises:
        ValueError: one line, if the tuned parameters are not all finite
            (nothing is written then).
    """
    from wmr_jax._src import io
    from wmr_jax._src.params import check_feasible
    from wmr_jax._src.report.tuning import tuning_curve
    from wmr_jax._src.robots import ROBOT_UNITS, robot_json
    from wmr_jax._src.tuning.evaluation import report_ratios, wheel_speed_ok
    from wmr_jax._src.tuning.saved import tuned_json, write_tuned

    # Each file records the robot: its gains are tuned within that robot's wheel budget.
    tuned = tuned_json(result.gains, robot=robot, tuning="nominal")
    search = result.search
    searched = None if search is None else tuned_json(search.gains, robot=robot, tuning="nominal")
    write_tuned(out, tuned)  # and drops the files that judged the gains it replaces
    if searched is not None:
        io.atomic_write_json(out / "random_search_gains.json", searched)
    paper = result.evaluation["paper_feasible"].mean_arrival
    bounds = held_out_bounds(config, robot)
    rows = {name: dict(ev._asdict()) for name, ev in result.evaluation.items()}
    for name, row in rows.items():
        # A ratio that needs a run that never arrived is null, with the reason beside it.
        row.update(report_ratios(row["mean_arrival"], bounds, paper))
        row["peak_wheel_speed_ok"] = wheel_speed_ok(result.evaluation[name], robot)
    report = {
        "problem": result.problem,
        "velocity": config.velocity,
        "held_out_poses": config.eval_poses,
        "horizon_s": config.horizon,
        "law": "hard (temperature None)",
        "rows": rows,
        "tuned_gains": tuned,
        # Fixed gains: k_r + L k_θ ≤ V_max; a schedule meets |v| + L|ω| ≤ V_max by construction.
        "feasible": result.problem != "fixed" or bool(check_feasible(result.gains, robot)),
        # Every row's; each row says its own (peak_wheel_speed_ok there).
        "peak_wheel_speed_ok": all(row["peak_wheel_speed_ok"] for row in rows.values()),
        "robot": robot_json(robot),
        "robot_units": dict(ROBOT_UNITS),
        "wall_time_s": {
            "tuning": result.tune_wall_s,
            "random_search": None if search is None else search.wall_s,
        },
        # Each session compiles the step again: a resumed run's tuning time
        # (the random search's budget) holds one more compilation per resume.
        "resumed_at_iteration": resumed_at,
        "random_search_candidates": None if search is None else search.candidates,
        # The iterate kept: the best hard-law score on the validation poses.
        "best_iteration": result.best_iteration,
        "validation": {
            "poses": config.validation_poses,
            "scored_at": [int(i) for i in result.history["validated_at"]],
            "score_s": [float(v) for v in result.history["validation"]],
        },
        "no_better_than_baseline": result.note is not None,
        "note": result.note,
        "config": config.as_dict(),
    }
    io.atomic_write_json(out / "evaluation.json", report)
    tuning_curve(
        out / "tuning_curve.png", result.history, velocity=config.velocity, problem=result.problem
    )


def tune(
    out_dir: str | os.PathLike,
    config: Any = None,
    *,
    robot: Any = None,
    resume: bool = False,
    progress: bool = True,
    progress_fn: Callable[[Any], Any] | None = None,
) -> Any:
    """Run ``wmr_jax.tuning.train`` and write its results and checkpoints to ``out_dir``.

    Files in ``out_dir``: ``tuned_gains.json`` (the controller, the kind,
    the parameters and the robot; ``wmr_jax.load_tuned`` reads it; the
    files that judged the gains it replaces, ``saved.JUDGING_TUNED``, are
    removed when it is written),
    ``evaluation.json``, ``tuning_curve.png``,
    ``random_search_gains.json`` and ``checkpoint.npz`` (checksummed, written
    atomically every ``config.checkpoint_every`` iterations and at the end).

    Args:
        out_dir: output folder (created if needed).
        config: a ``TuneConfig``; default ``TuneConfig()``.
        robot: robot parameters; default ``Robot()``.
        resume: continue from ``out_dir/checkpoint.npz`` if present (it must
            come from the same settings); the result is the same as that of
            an uninterrupted run. Without it, any checkpoint is overwritten.
        progress: show a progress bar with the loss.
        progress_fn: called with the ``TrainState`` after each iteration,
            after the checkpoint; an exception it raises stops the run (the
            checkpoint of the last ``checkpoint_every`` boundary stays).

    Returns:
        The ``TuneResult`` of ``train``.

    Raises:
        ValueError: one line, for bad settings or a damaged checkpoint or one
            of another run.
    """
    from tqdm.auto import tqdm

    from wmr_jax._src import io, tuning
    from wmr_jax._src.checks import check_bool, check_callable, check_folder
    from wmr_jax._src.params import Robot, validate_robot
    from wmr_jax._src.tuning.training import checked_config

    out = check_folder("out_dir", out_dir)
    check_bool("resume", resume)
    check_bool("progress", progress)
    check_callable("progress_fn", progress_fn)
    config = checked_config(config)
    io.remove_stale_temporaries(out)
    robot = Robot() if robot is None else robot
    identity = tuning.run_identity(config, robot)
    state = tuning.init_state(config, robot)
    checkpoint = out / CHECKPOINT_NAME
    if resume and checkpoint.exists():
        state = _load_checkpoint(checkpoint, state, identity)
    elif resume:  # a mistyped --out would otherwise start over without a word
        print(f"--resume: no {CHECKPOINT_NAME} in {out}; starting from the first iteration")
    bar = tqdm(
        total=config.iters,
        initial=state.iteration,
        desc=f"tune ({config.velocity})",
        disable=not progress,
        dynamic_ncols=True,
    )
    report = _progress(config, checkpoint, identity, bar, progress_fn)
    search_bar = tqdm(
        desc="random search (same wall time)",
        unit=" candidates",
        disable=not (progress and config.random_search),
        dynamic_ncols=True,
    )
    eval_bar = tqdm(total=3, desc="hard-law evaluation", disable=not progress, dynamic_ncols=True)
    try:
        result = tuning.train(
            config,
            robot=robot,
            state=state,
            progress_fn=report,
            search_progress=search_bar.update,
            eval_progress=lambda _name: (search_bar.close(), eval_bar.update(1)),
        )
    finally:
        bar.close()
        search_bar.close()
        eval_bar.close()
    # The robot as given, not rounded to the session's float32: the file
    # records it, and a preset read back must still be that preset.
    resumed_at = state.iteration if state.iteration else None
    _write_results(out, config, validate_robot(robot), result, resumed_at)
    return result


# ---------------------------------------------------------------- the command

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
    from wmr_jax._src.tuning.robust import RobustConfig
    from wmr_jax._src.tuning.training import TuneConfig

    defaults = TuneConfig()
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    for flag, field, metavar, text in _FLAGS:
        # None stands for "not given": --schedule and --robust have defaults of their own.
        default = getattr(defaults, field)
        if field in ("iters", "poses"):
            robust = getattr(RobustConfig(), field)
            scheduled = getattr(TuneConfig.for_problem("schedule"), field)
            default = f"{default}, {scheduled} with --schedule, {robust} with --robust"
        parser.add_argument(flag, metavar=metavar, help=f"{text} (default: {default})")
    parser.add_argument(
        "--no-random-search",
        action="store_true",
        help="skip the random-search baseline (same wall time as the tuning)",
    )
    flags.add_robot_flag(parser)
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue from DIR/checkpoint.npz (same settings) instead of starting over; "
        "with --compare, keep the seeds DIR/compare.json already holds",
    )
    parser.add_argument(
        "--schedule",
        action="store_true",
        help="tune the gain-scheduled law (35 parameters by default, docs/model.md §3.9) "
        "instead of the "
        "7 fixed gains, with the schedule's own defaults for --iters, the step and the "
        "annealing (wmr_jax.tuning.TuneConfig.for_problem)",
    )
    parser.add_argument(
        "--knots",
        metavar="K",
        help="with --schedule: knots per table, 3K + 5 parameters (default: 10, 35 "
        "parameters; at most 60, whose gradient takes 40 s and 2.4 GB to compile)",
    )
    parser.add_argument(
        "--robust",
        action="store_true",
        help="tune the gain schedule and a pose estimator together for robustness to noise, "
        "latency and a robot unlike its model (docs/model.md §7, §9); with --compare, "
        "gradient against CMA-ES and random search at equal wall time, seeds 0-2",
    )
    parser.add_argument(
        "--fixed",
        action="store_true",
        help="with --robust: tune the 7 fixed gains with raw feedback instead",
    )
    parser.add_argument(
        "--estimator",
        metavar="NAME",
        help="with --robust: the estimator tuned with the law: ekf, observer or none "
        "(raw feedback) (default: ekf; none with --fixed)",
    )
    parser.add_argument(
        "--compare",
        action="store_true",
        help="instead of tuning once, compare gradient, CMA-ES and random search at equal "
        "wall time, fixed gains and schedules (with --schedule: the schedule only), seeds "
        "0-2, into DIR/compare.{json,md}",
    )
    parser.add_argument(
        "--gradient-cost",
        action="store_true",
        help="instead of tuning, measure the gradient's time and peak memory "
        "(4096 poses x 150 steps, with and without remat) into DIR/gradient_cost.json",
    )


def _config_from(args: Any, *, schedule: bool) -> Any:
    """The ``TuneConfig`` of the flags, each checked (one line naming a bad one)."""
    from wmr_jax._src.poses import MAX_SAMPLES
    from wmr_jax._src.tuning.problems import MAX_TUNED_KNOTS
    from wmr_jax._src.tuning.training import TuneConfig

    base = TuneConfig.for_problem("schedule" if schedule else "fixed")

    def given(name: str) -> Any:
        # A flag left alone keeps the problem's default.
        value = getattr(args, name)
        return getattr(base, name) if value is None else value

    config = base.replace(
        velocity=flags.velocity_loop(given("velocity")),
        iters=flags.positive_int("--iters", given("iters"), 1),
        poses=flags.positive_int("--poses", given("poses"), 1, MAX_SAMPLES),
        seed=flags.positive_int("--seed", given("seed"), 0, 2**32 - 1),
        horizon=flags.number("--horizon", given("horizon"), low=0.0, closed=False, unit="s"),
        eval_poses=flags.positive_int("--eval-poses", given("eval_poses"), 1, MAX_SAMPLES),
        checkpoint_every=flags.positive_int("--checkpoint-every", given("checkpoint_every"), 1),
        random_search=not args.no_random_search,
    )
    if schedule and args.knots is not None:
        knots = flags.positive_int("--knots", args.knots, 2, MAX_TUNED_KNOTS)
        config = config.replace(knots=knots)
    return config.validate()  # the horizon against dt, before any work


def _check_modes(args: Any) -> None:
    """Refuse flags the chosen mode would ignore (one line naming them)."""
    for name in ("fixed", "estimator"):
        if getattr(args, name) not in (None, False) and not args.robust:
            raise ValueError(f"--{name} is not allowed without --robust, whose problem it sets")
    if args.robust:
        # --robust --compare is the robust comparison; --knots sizes its schedule.
        unused = ("schedule", "horizon", "eval_poses", "checkpoint_every", "no_random_search")
        if args.gradient_cost:
            raise ValueError("--robust is not allowed with --gradient-cost; allowed: one of them")
        for name in unused:
            if getattr(args, name) not in (None, False):
                flag = f"--{name.replace('_', '-')}"
                raise ValueError(f"{flag} is not allowed with --robust, which does not use it")
        return
    modes = [m for m in ("robust", "compare", "gradient_cost") if getattr(args, m)]
    if len(modes) > 1:
        a, b = (f"--{m.replace('_', '-')}" for m in modes[:2])
        raise ValueError(f"{a} is not allowed with {b}; allowed: one of them")
    mode = modes[0] if modes else None
    if args.knots is not None and not args.schedule:
        raise ValueError("--knots is not allowed without --schedule, whose tables it sizes")
    unused = {
        "compare": ("seed", "checkpoint_every", "no_random_search"),
        "gradient_cost": (*(field for _, field, _, _ in _FLAGS), "schedule", "resume", "robot"),
    }.get(mode, ())
    for name in unused:
        if getattr(args, name) not in (None, False):
            flag, other = f"--{name.replace('_', '-')}", f"--{mode.replace('_', '-')}"
            raise ValueError(f"{flag} is not allowed with {other}, which does not use it")


def _gradient_cost(out: Path) -> int:
    from wmr_jax._src import io, tuning

    costs = [tuning.gradient_cost(remat=remat) for remat in (True, False)]
    io.atomic_write_json(out / "gradient_cost.json", [c._asdict() for c in costs])
    for c in costs:
        print(
            f"{c.poses} poses x {c.steps} steps, remat={c.remat}: forward {c.forward_s:.3f} s, "
            f"gradient {c.gradient_s:.3f} s ({c.gradient_s / c.forward_s:.1f}x); peak memory "
            f"forward {c.forward_peak_bytes / 2**20:.1f} MiB, "
            f"gradient {c.gradient_peak_bytes / 2**20:.1f} MiB"
        )
    return 0


# How tune prints each parameter: its symbol and the unit a person types it in
# (Φ_m in degrees, as simulate's --phi-m takes it; the files hold radians).
_PRINTED = {
    "kr": ("k_r", "cm/s"),
    "k_theta": ("k_θ", "rad/s"),
    "k_turn": ("k_turn", "rad/s"),
    "phi_m": ("Φ_m", "°"),
    "r_m": ("R_m", "cm"),
    "r_a": ("R_a", "cm"),
    "r_e": ("R_e", "cm"),
    "alpha": ("α", ""),
    "v_max": ("V_max", "cm/s"),
    "half_track": ("L", "cm"),
}


def _shown(params: Any) -> list[str]:
    """The tuned parameters as printed: each with its unit, angles in degrees.

    Fixed gains come with a second line, the ``wmr-jax simulate`` flags that
    give them (to six digits); a schedule's tables are lists of 3 significant
    digits.
    """
    import math

    from wmr_jax._src.params import Gains
    from wmr_jax._src.tuning.saved import tuned_json

    def fmt(name: str, value: Any) -> str:
        symbol, unit = _PRINTED[name]
        to_unit = math.degrees if name == "phi_m" else float
        if isinstance(value, list):
            text = "[" + ", ".join(f"{to_unit(x):.3g}" for x in value) + "]"
        else:
            text = f"{to_unit(value):.4g}"
        return f"{symbol}={text}{'' if unit in ('', '°') else ' '}{unit}"

    values = tuned_json(params)
    lines = ["  ".join(fmt(k, v) for k, v in values.items() if k in _PRINTED)]
    if isinstance(params, Gains):
        lines.append("as simulate flags: " + " ".join(flags.gain_flag_values(params)))
    return lines


_COMPARE_SEEDS = (0, 1, 2)
_COMPARE_FORMAT = 1


def _compare_rows(
    out: Path, settings: dict[str, Any], resume: bool, problems: dict[str, int]
) -> list[dict[str, Any]]:
    """The rows of ``out/compare.json`` to keep (``--resume``), after checking they are ours.

    Checked whole before anything runs: a file of another comparison, or one
    whose shape is not what ``--compare`` writes, is refused in one line.
    """
    import json

    from wmr_jax._src import io
    from wmr_jax._src.tuning.compare import _json_type, saved_rows

    record, manifest = out / "compare.json", out / "compare_settings.json"
    if not (resume and record.exists()):
        # A new comparison: an earlier one's rows, which record no settings of
        # their own, must not stay beside these settings for a --resume to keep.
        for stale in (record, out / "compare.md"):
            stale.unlink(missing_ok=True)
        io.atomic_write_json(manifest, settings)
        return []
    advice = "allowed: the same settings, or a fresh --out"
    texts = {}
    for path in (manifest, record):
        try:
            texts[path] = json.loads(
                path.read_text(encoding="utf-8"), object_pairs_hook=io.json_object_once
            )
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
            reason = " ".join(str(err).split())
            raise ValueError(f"--resume: {path} cannot be read ({reason}); {advice}") from None
    saved, rows = texts[manifest], texts[record]
    if not isinstance(saved, dict):
        raise ValueError(
            f"--resume: {manifest} is a JSON {_json_type(saved)}; allowed: an object (the "
            f"settings wmr-jax tune --compare writes), or a fresh --out"
        )
    if saved != settings:
        diff = _settings_difference(saved, settings)
        raise ValueError(f"--resume: {record} is of another comparison ({diff}); {advice}")
    try:
        if isinstance(rows, list):  # values changed since they were written are not kept
            rows = [io.unsealed(row, f"{record} row {i}") for i, row in enumerate(rows)]
        return saved_rows(rows, str(record), problems, tuple(settings["seeds"]))
    except ValueError as err:
        raise ValueError(f"--resume: {err}; remove it, or use a fresh --out") from None


def _settings_difference(saved: Any, now: dict[str, Any]) -> str:
    """Name the problems whose settings differ between two ``compare_settings.json``."""
    from wmr_jax._src.tuning import run_difference

    saved_configs = saved.get("configs", {}) if isinstance(saved, dict) else {}
    saved_configs = saved_configs if isinstance(saved_configs, dict) else {}
    parts = [
        f"{name}: {run_difference({'config': saved_configs.get(name)}, {'config': config})}"
        if name in saved_configs
        else f"{name}: not compared there"
        for name, config in now["configs"].items()
        if saved_configs.get(name) != config
    ]
    parts += [f"{name}: not compared now" for name in saved_configs if name not in now["configs"]]
    saved_robot = saved.get("robot") if isinstance(saved, dict) else None
    if saved_robot != now.get("robot"):
        parts.append(
            f"robot: {_robot_text(saved_robot)} there, {_robot_text(now.get('robot'))} now"
        )
    saved_code = saved.get("code") if isinstance(saved, dict) else None
    if saved_code != now.get("code"):
        was = saved_code or "code from before code versions were recorded"
        parts.append(f"computed by wmr_jax {was}, this is {now.get('code')}")
    return "; ".join(parts) or "its format or seeds differ"


def _robot_text(values: Any) -> str:
    """A ``compare_settings.json`` robot in words (none recorded: the paper robot)."""
    from wmr_jax._src.robots import describe_robot, robot_from_values

    if values is None:
        return "paper"
    try:
        return describe_robot(robot_from_values(values, "robot"))
    except ValueError:
        return "a damaged robot entry"


def _compare(out: Path, args: Any, robot: Any) -> int:
    import json

    from wmr_jax._src import io
    from wmr_jax._src.params import Robot
    from wmr_jax._src.provenance import code_version
    from wmr_jax._src.report.tuning import comparison_table
    from wmr_jax._src.robots import robot_json, same_robot
    from wmr_jax._src.tuning.compare import compare

    # Each problem over the robot's horizon, as a single tuning run has it.
    schedule = _config_from(args, schedule=True)
    configs = {"schedule": _robot_horizon(args, schedule, robot)}
    if not args.schedule:  # both problems, unless --schedule asks for the schedule alone
        fixed = _config_from(args, schedule=False)
        if configs["schedule"].horizon != schedule.horizon:  # stretched (and said) above
            fixed = fixed.replace(horizon=configs["schedule"].horizon).validate()
        configs = {"fixed": fixed, **configs}
    settings = {
        "format": _COMPARE_FORMAT,
        "seeds": list(_COMPARE_SEEDS),
        "configs": {name: config.as_dict() for name, config in configs.items()},
        # Rows computed by other code (the law, the loss, an optimiser) are not mixed in.
        "code": code_version(),
    }
    # Only a --robot is handed on (compare's default is the paper robot), and
    # only another robot than the paper's is part of the settings: comparisons
    # saved before robots were named still resume.
    on_robot = {} if robot is None else {"robot": robot}
    if robot is not None and not same_robot(robot, Robot()):
        settings["robot"] = robot_json(robot)
    settings = json.loads(json.dumps(settings))  # as it reads back from the file
    problems = {name: config.problem.dim for name, config in configs.items()}
    rows = _compare_rows(out, settings, args.resume, problems)
    # Each (problem, seed) is written as soon as its three methods are done, so
    # an interrupted comparison keeps them and --resume runs only the rest.
    done = {(row["problem"], row["seed"]) for row in rows}
    for name, config in configs.items():
        for seed in _COMPARE_SEEDS:
            if (name, seed) in done:
                print(f"{name} seed {seed}: kept from {out / 'compare.json'}")
                continue
            rows += compare(
                seeds=(seed,),
                problems=(name,),
                configs={name: config},
                progress=print,
                **on_robot,
            )
            # Each row sealed with a checksum: --resume keeps only what this wrote.
            io.atomic_write_json(out / "compare.json", [io.sealed(row) for row in rows])
    table = comparison_table(rows)
    io.atomic_write_text(out / "compare.md", table)
    print(table, end="")
    print(f"-> {out / 'compare.json'}, {out / 'compare.md'}")
    return 0


def _robot_horizon(args: Any, config: Any, robot: Any) -> Any:
    """The config with the horizon of ``robot`` where ``--horizon`` is not given; said.

    The paper's 6 s is the paper robot's; a slower robot, whose wheels cannot
    follow the paper's feasible gains, gets the studies' stretched horizon
    (``studies.study_horizon``), so that its yardstick row can arrive at all.
    """
    from wmr_jax._src.robustness import study_horizon

    if robot is None or args.horizon is not None or args.gradient_cost:
        return config
    horizon = study_horizon(robot)
    if horizon != config.horizon:
        print(
            f"horizon {horizon:g} s for this robot (the paper robot's {config.horizon:g} s, "
            "stretched as its wheels need; --horizon sets another)"
        )
        config = config.replace(horizon=horizon).validate()
    return config


def run(args: Any) -> int:
    """Run ``wmr-jax tune``; return the exit status."""
    from wmr_jax._src.params import Robot
    from wmr_jax._src.robots import describe_robot

    _check_modes(args)
    if args.robust:
        from wmr_jax._src.cli import tune_robust

        return tune_robust.run(args)
    out = flags.output_dir("--out", args.out)
    config = _config_from(args, schedule=args.schedule)
    if args.gradient_cost:
        return _gradient_cost(out)
    given = flags.robot_from(args.robot)
    if given is not None and given.note:
        print(given.note)
    robot = None if given is None else given.robot
    if args.compare:
        return _compare(out, args, robot)
    config = _robot_horizon(args, config, robot)
    from wmr_jax._src.report.tuning import evaluation_table

    result = tune(out, config, robot=robot, resume=args.resume)
    robot = Robot() if robot is None else robot
    kind = "gain schedule" if config.schedule else "gains"
    print(f"tuned {kind} ({config.velocity} loop) -> {out / 'tuned_gains.json'}")
    for line in _shown(result.gains):
        print("  " + line)
    print(f"  for the robot {describe_robot(robot)}")
    print(
        f"held-out evaluation, {config.eval_poses} poses (docs/model.md §6), hard law "
        f"-> {out / 'evaluation.json'}"
    )
    bounds = held_out_bounds(config, robot)
    print(evaluation_table(result.evaluation, bounds), end="")
    search = result.search
    extra = "" if search is None else f"; random search {search.candidates} candidates"
    kept = f"kept iteration {result.best_iteration} (best validation score)"
    print(f"tuning wall time {result.tune_wall_s:.1f} s{extra}; {kept}")
    if result.note is not None:
        print(result.note)
    print(f"curve -> {out / 'tuning_curve.png'}")
    return 0


SUBCOMMANDS = {
    "tune": {
        "help": "tune gains by gradient descent under k_r + L k_theta <= V_max",
        "add_arguments": add_arguments,
        "run": run,
    },
}
