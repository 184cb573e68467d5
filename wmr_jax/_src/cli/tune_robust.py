"""``wmr-jax tune --robust``: controller and estimator tuned together (docs/model.md §7, §9).

Called by ``wmr-jax tune`` with its parsed flags (``out``, ``seed``,
``iters``, ``poses``, ``velocity``, ``resume``, ``fixed``, ``estimator``,
``knots``, ``compare``). By default the gain schedule and the estimator are
tuned together (``--fixed``: the 7 fixed gains with raw feedback, as before
estimators). Writes ``tuned_gains.json`` (controller, parameters,
estimator and robot, which ``load_tuned`` reads whole), ``robust_evaluation.json``
and ``.md`` (the hard-law table under the standard conditions, each with ±3 %
wheel mismatch, and the model robot) and ``robust_loss.json`` (the loss per
iteration). With ``--compare`` it runs seeds 0–2 instead, each with random
search and CMA-ES given the tuning's wall time, into
``robust_compare.json`` and ``.md`` (each seed written as it finishes;
``--resume`` keeps them). ``--robot`` tunes and judges on that robot, over
its horizon (``robustness.study_horizon``).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["run"]

_COLUMNS = ["condition", "gains", "feedback", "success", "mean arrival s", "median arrival s"]
_COMPARE_SEEDS = (0, 1, 2)
_COMPARE_FORMAT = 1
_NONE = ("none", "raw")


def _counts(args: Any) -> tuple[int, int]:
    """``--iters`` and ``--poses``, or the robust tuner's own defaults where not given."""
    from wmr_jax._src.tuning.robust import RobustConfig

    robust = RobustConfig()
    counts = []
    for flag, name in (("--iters", "iters"), ("--poses", "poses")):
        value = getattr(args, name, None)
        counts.append(getattr(robust, name) if value is None else flags.positive_int(flag, value))
    return counts[0], counts[1]


def _estimator(args: Any) -> Any:
    """The ``--estimator`` name (``None`` for raw feedback); ``--fixed`` defaults to raw."""
    from wmr_jax._src.sensing.estimators import ESTIMATORS
    from wmr_jax._src.tuning.robust import RobustConfig

    value = getattr(args, "estimator", None)
    if value is None:
        return None if getattr(args, "fixed", False) else RobustConfig().estimator
    if value in _NONE:
        return None
    if value not in ESTIMATORS:
        allowed = ", ".join([*ESTIMATORS, "none"])
        raise ValueError(f"--estimator {value!r} is not allowed; allowed: {allowed}")
    return value


def config_from(args: Any) -> Any:
    """The ``RobustConfig`` of the flags, each checked (one line naming a bad one)."""
    from wmr_jax._src.tuning.problems import MAX_TUNED_KNOTS
    from wmr_jax._src.tuning.robust import RobustConfig

    seed = getattr(args, "seed", None)
    seed = flags.positive_int("--seed", 0 if seed is None else seed, 0, 2**32 - 1)
    iters, poses = _counts(args)
    velocity = getattr(args, "velocity", None)
    if velocity is not None and flags.velocity_loop(velocity) != "ideal":
        raise ValueError(
            f"--velocity {velocity!r} is not allowed with --robust; allowed: ideal "
            "(the robust loss mixes both loops itself)"
        )
    fixed = bool(getattr(args, "fixed", False))
    changes: dict[str, Any] = {
        "iters": iters,
        "poses": poses,
        "seed": seed,
        "problem": "fixed" if fixed else "schedule",
        "estimator": _estimator(args),
        "compare": False,
    }
    knots = getattr(args, "knots", None)
    if knots is not None:
        if fixed:
            raise ValueError("--knots is not allowed with --fixed, which tunes no tables")
        changes["knots"] = flags.positive_int("--knots", knots, 2, MAX_TUNED_KNOTS)
    return RobustConfig(**changes).validate()


def _described(config: Any) -> str:
    law = "7 fixed gains" if config.problem == "fixed" else f"gain schedule ({config.knots} knots)"
    sensing = "raw feedback" if config.estimator is None else f"the {config.estimator}"
    return f"{law} with {sensing}"


def _robot(args: Any) -> tuple[Any, dict[str, Any]]:
    """The robot of ``--robot`` (the paper robot if not given), and the arguments that pass it on.

    The note of a YAML is printed first. Only another robot than the
    paper's is handed on (``tune_robust``'s default is the paper robot).
    """
    from wmr_jax._src.params import Robot
    from wmr_jax._src.robots import same_robot

    given = flags.robot_from(getattr(args, "robot", None))
    if given is not None and given.note:
        print(given.note)
    robot = Robot() if given is None else given.robot
    return robot, ({} if same_robot(robot, Robot()) else {"robot": robot})


def run(args: Any) -> int:
    """Run ``wmr-jax tune --robust``; return the exit status."""
    out = flags.output_dir("--out", getattr(args, "out", None))
    config = config_from(args)
    robot, on_robot = _robot(args)
    if getattr(args, "compare", False):
        return _compare(out, config, on_robot, resume=bool(getattr(args, "resume", False)))

    from wmr_jax._src import io
    from wmr_jax._src.report.robustness import robustness_table
    from wmr_jax._src.robots import describe_robot, robot_json
    from wmr_jax._src.robustness import study_horizon
    from wmr_jax._src.tuning.robust import tune_robust
    from wmr_jax._src.tuning.saved import tuned_json, write_tuned

    if getattr(args, "resume", False):
        print("tune --robust keeps no checkpoint: --resume runs it again from the start")
    print(
        f"tuning the {_described(config)} through the disturbances on the robot "
        f"{describe_robot(robot)}, horizon {study_horizon(robot):g} s",
        flush=True,
    )

    def progress(i: int, loss: float) -> None:
        if i == 1 or i % 25 == 0 or i == config.iters:
            print(f"iteration {i}/{config.iters}: loss {loss:.3f} s", flush=True)

    def keep(loop: Any, losses: list[float]) -> None:
        # Written before the evaluation: an interruption there loses no tuning.
        # (Removing the files that judged the gains it replaces.)
        write_tuned(out, tuned_json(loop, robot=robot, tuning="robust"))
        io.atomic_write_json(out / "robust_loss.json", {"loss": losses})
        print(f"tuned_gains.json, robust_loss.json -> {out} (now judging them)", flush=True)

    result = tune_robust(config, progress_fn=progress, on_tuned=keep, **on_robot)
    record = {
        "config": dataclasses.asdict(config),
        "robot": robot_json(robot),
        "tune_wall_s": result["tune_wall_s"],
        "law": "hard (temperature None)",
        "rows": result["rows"],
        # The iterate kept: the best hard-law score on the validation poses.
        "best_iteration": result["best_iteration"],
        "validation": {
            "poses": config.validation_poses,
            "scored_at": [int(i) for i in result["history"]["validated_at"]],
            "score_s": [float(v) for v in result["history"]["validation"]],
        },
        "no_better_than_baseline": result["note"] is not None,
        "note": result["note"],
    }
    io.atomic_write_json(out / "robust_evaluation.json", record)
    table = robustness_table(result["rows"], _COLUMNS)
    io.atomic_write_text(out / "robust_evaluation.md", table)
    print(f"robust_evaluation.md/json -> {out}")
    print(table, end="")
    kept = f"kept iteration {result['best_iteration']} (best validation score)"
    print(f"tuning wall time {result['tune_wall_s']:.1f} s; {kept}")
    if result["note"] is not None:
        print(result["note"])
    return 0


def _kept_rows(path: Any, settings: dict[str, Any], resume: bool) -> list[dict[str, Any]]:
    """The rows of an earlier ``--compare`` of the same settings (``--resume``), else none."""
    from wmr_jax._src import io

    if not resume or not path.exists():
        return []
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"--resume: {str(path)!r} cannot be read: {err}") from None
    if not isinstance(saved, dict) or saved.get("settings") != settings:
        theirs = saved.get("settings") if isinstance(saved, dict) else None
        theirs = theirs if isinstance(theirs, dict) else {}
        keys = [*settings, *(k for k in theirs if k not in settings)]
        differ = [k for k in keys if theirs.get(k) != settings.get(k)]
        raise ValueError(
            f"--resume: {str(path)!r} holds another comparison (other {', '.join(differ)}); "
            "allowed: the same flags and code as the run that wrote it, or another --out"
        )
    try:  # values changed since they were written are not kept
        saved = io.unsealed(saved, repr(str(path)))
    except ValueError as err:
        raise ValueError(f"--resume: {err}; allowed: remove it, or another --out") from None
    rows = saved.get("rows")
    good = isinstance(rows, list) and all(
        isinstance(r, dict) and r.get("seed") in _COMPARE_SEEDS for r in rows
    )
    if not good:
        raise ValueError(f"--resume: {str(path)!r} has malformed rows; allowed: another --out")
    return rows


def _compare(out: Any, config: Any, on_robot: dict[str, Any], *, resume: bool) -> int:
    """Gradient, CMA-ES and random search at equal wall time, seeds 0–2; each seed kept.

    ``on_robot``: ``{"robot": Robot}`` for another robot than the paper's,
    which is then part of the settings, with the code version: rows of
    other code (comparisons saved before it was recorded included) are not
    resumed.
    """
    from wmr_jax._src import io
    from wmr_jax._src.provenance import code_version
    from wmr_jax._src.report.tuning import robust_comparison_table
    from wmr_jax._src.robots import robot_json
    from wmr_jax._src.tuning.robust import evosax_available, tune_robust

    if not evosax_available():
        print(
            "CMA-ES skipped: evosax is not installed (pip install 'wmr_jax[search]'); "
            "comparing the gradient with random search only"
        )
    path = out / "robust_compare.json"
    settings = {
        "format": _COMPARE_FORMAT,
        "config": dataclasses.asdict(config),
        "code": code_version(),  # rows of another law are not this comparison's
    }
    if on_robot:
        settings["robot"] = robot_json(on_robot["robot"])
    settings = json.loads(json.dumps(settings))  # as it reads back from the file
    rows = _kept_rows(path, settings, resume)
    if not resume:  # a new comparison: nothing of an earlier one stays beside its rows
        for stale in (path, out / "robust_compare.md"):
            stale.unlink(missing_ok=True)
    done = {row["seed"] for row in rows}
    for seed in _COMPARE_SEEDS:
        if seed in done:
            print(f"seed {seed}: kept from {path}")
            continue
        print(f"seed {seed}: tuning the {_described(config)}, then the searches", flush=True)
        result = tune_robust(dataclasses.replace(config, seed=seed, compare=True), **on_robot)
        budget = result["tune_wall_s"]
        counts = {"gradient": config.iters, **{m: n for m, (_, n) in result["searches"].items()}}
        for row in result["rows"]:
            if row["gains"] == "paper":
                continue
            method = "gradient" if row["gains"] == "robust-tuned" else row["gains"]
            rows.append(
                {**row, "method": method, "seed": seed, "budget_s": budget,
                 "candidates": counts[method]}
            )  # fmt: skip
        # Sealed with a checksum: --resume keeps only what this wrote.
        io.atomic_write_json(path, io.sealed({"settings": settings, "rows": rows}))
    table = robust_comparison_table(rows)
    io.atomic_write_text(out / "robust_compare.md", table)
    print(table, end="")
    print(f"-> {path}, {out / 'robust_compare.md'}")
    return 0
