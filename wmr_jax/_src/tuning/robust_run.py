"""A robust tuning run with its files, and the resumable robust comparison."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wmr_jax._src import io
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.model.robots import robot_json
from wmr_jax._src.tuning import robust, trainer
from wmr_jax._src.tuning.compare import (
    COMPARE_SEEDS,
    comparison_settings,
    minimised,
    resumable,
)
from wmr_jax._src.tuning.evaluation import EVAL_SEED, held_out_poses, poses_digest
from wmr_jax._src.tuning.robust import RobustConfig
from wmr_jax._src.tuning.run import CHECKPOINT_NAME, checkpointing, resumed_state
from wmr_jax._src.tuning.saved import tuned_json, write_tuned

COLUMNS = ["condition", "gains", "feedback", "success", "mean arrival s", "median arrival s"]


def described(config: RobustConfig) -> str:
    """What ``config`` tunes, in words: the law and its feedback."""
    law = "7 fixed gains" if config.law == "fixed" else f"gain schedule ({config.knots} knots)"
    sensing = "raw feedback" if config.estimator is None else f"the {config.estimator}"
    noise = f"pose noise {config.noise_xy:g} cm, {config.noise_theta:g}°"
    return f"{law} with {sensing}, for {noise}"


def tune(
    out: Path,
    config: RobustConfig,
    robot: Robot,
    *,
    resume: bool = False,
    checkpoint_every: int | None = None,
    progress_fn: Callable[[Any], Any] | None = None,
    say: Callable[[str], Any] = print,
) -> tuple[Any, str]:
    """``tune_robust`` of a checked ``config`` with its files in ``out``; the result and its table.

    A checkpoint every ``checkpoint_every`` iterations (``None``:
    ``trainer.CHECKPOINT_EVERY``) and at the last (``checkpoint.npz``), ``tuned_gains.json`` and
    ``robust_loss.json`` once tuned, then ``robust_evaluation.{json,md}``.
    ``resume``: continue from the checkpoint, which must be of the same
    settings, robot and code; the iterations go on bit for bit, and what
    follows them (the hybrid's polish, the searches) runs whole.
    """
    robot = validate_one_robot(robot, "tuning")
    run, checkpoint, state = trainer.run_text(config, robot), out / CHECKPOINT_NAME, None
    identity = json.loads(run)
    if resume:

        def fresh() -> Any:  # built only to restore into: the problem costs some draws
            return trainer.start_state(robust.robust_problem(config, robot), run)

        state = resumed_state(checkpoint, fresh, identity, say)
    every = trainer.CHECKPOINT_EVERY if checkpoint_every is None else checkpoint_every
    save = checkpointing(checkpoint, identity, every, config.iters)

    def progress(state: Any) -> None:
        save(state)
        if progress_fn is not None:
            progress_fn(state)

    def keep(loop: Any, losses: list[float]) -> None:
        # Written before the evaluation: an interruption there loses no tuning.
        write_tuned(out, tuned_json(loop, robot=robot, tuning="robust"))
        io.atomic_write_json(out / "robust_loss.json", {"loss": losses})
        say(f"tuned_gains.json, robust_loss.json -> {out} (now judging them)")

    result = robust.tune_robust(
        config, robot=robot, state=state, progress_fn=progress, on_tuned=keep
    )
    resumed_at = state.iteration if state is not None and state.iteration else None
    return result, write_evaluation(out, config, robot, result, resumed_at)


def write_evaluation(
    out: Path, config: RobustConfig, robot: Robot, result: Any, resumed_at: int | None = None
) -> str:
    """Write ``robust_evaluation.json`` and ``.md`` of a robust result; return the table.

    ``resumed_at``: the iteration the tuning resumed from (``None``: it ran them all).
    """
    from wmr_jax._src.report.robustness import robustness_table

    record = {
        "config": dataclasses.asdict(config),
        "robot": robot_json(robot),
        "tune_cpu_s": result.tune_cpu_s,
        # A resumed run's CPU time holds one more compilation per resume.
        "resumed_at_iteration": resumed_at,
        "law": "hard (temperature None)",
        # The sensor tuned for: the training's noise up to twice it, the table's at it.
        "noise": {"xy cm": config.noise_xy, "theta degrees": config.noise_theta},
        "rows": result.rows,
        **trainer.verdict(result, config.validation_poses),
    }
    io.atomic_write_json(out / "robust_evaluation.json", record)
    table = robustness_table(result.rows, COLUMNS)
    io.atomic_write_text(out / "robust_evaluation.md", table)
    return table


def finished(out: Path, config: RobustConfig, robot: Robot) -> bool:
    """Whether ``out`` holds this robust run finished (``--resume`` then redoes nothing).

    Raises:
        ValueError: one line, if ``out``'s ``robust_evaluation.json`` is of other
            settings or another robot, naming what differs.
    """
    path = out / "robust_evaluation.json"
    if not path.exists():
        return False
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"--resume: {str(path)!r} cannot be read: {err}") from None
    now = json.loads(json.dumps({"config": dataclasses.asdict(config), "robot": robot_json(robot)}))
    saved = saved if isinstance(saved, dict) else {}
    mine = {key: saved.get(key) for key in now}
    if mine != now:
        raise ValueError(
            f"--resume: {str(path)!r} is of another run ({trainer.differences(mine, now)}); "
            "allowed: the same settings, or another --out"
        )
    return (out / "tuned_gains.json").exists()


def compare_seed(config: RobustConfig, seed: int, robot: Robot) -> list[dict[str, Any]]:
    """One seed of the robust comparison: ``tune_robust`` with its searches, as rows.

    One row per method and condition (the paper's gains left out): the
    ``standard_conditions`` row with ``method``, ``seed``, ``budget_s`` (the
    gradient's CPU time), ``price`` (candidates one iteration costs:
    ``config.price``, else ``robust.iteration_price``), ``measured_price``
    (as measured), ``budget_candidates`` (every search's
    budget), ``candidates`` (gradient: iterations), ``cpu_s``, ``wall_s``,
    ``per_cpu_s``, ``minimises``, ``held_out`` (``poses_digest``) and
    ``loadavg`` (1-minute load average).
    """
    held_out = poses_digest(held_out_poses(config.eval_poses, EVAL_SEED))
    config_seed = dataclasses.replace(config, seed=seed, compare=True)
    tuned_at: list[float] = []
    began = time.perf_counter()
    result = robust.tune_robust(
        config_seed,
        robot=robot,
        on_tuned=lambda *_, at=tuned_at: at.append(time.perf_counter()),
    )
    budget = result.tune_cpu_s  # process CPU time (trainer.iterate counts it so)
    spent = {"gradient": (config.iters, budget, tuned_at[0] - began)}
    spent.update({m: tuple(s[1:]) for m, s in result.searches.items()})
    rows = []
    for row in result.rows:
        if row["gains"] == "paper":
            continue
        method = "gradient" if row["gains"] == "robust-tuned" else row["gains"]
        candidates, cpu, wall = spent[method]
        rows.append(
            {**row, "method": method, "seed": seed, "budget_s": budget,
             "price": result.budget["price"],
             "measured_price": result.budget["measured_price"],
             "budget_candidates": result.budget["candidates"], "candidates": candidates,
             "cpu_s": cpu, "wall_s": wall,
             "per_cpu_s": candidates / cpu if cpu > 0 else None,
             "minimises": minimised(config, method), "held_out": held_out,
             "loadavg": os.getloadavg()[0]}
        )  # fmt: skip
    return rows


def run_comparison(
    out: Path,
    config: RobustConfig,
    *,
    robot: Robot | None = None,
    resume: bool = False,
    progress: Callable[[str], Any] | None = print,
) -> list[dict[str, Any]]:
    """Gradient, CMA-ES and random search at equal compute, seeds 0–2 (``compare_seed``).

    Returns the rows (kept and new), also written to ``robust_compare.{json,md}``,
    each seed kept as ``compare.resumable`` keeps a run.
    """
    from wmr_jax._src.report.tuning import robust_comparison_table

    robot = validate_one_robot(robot, "tuning")
    say = progress if progress is not None else (lambda _line: None)

    def seed_rows(seed: int) -> list[dict[str, Any]]:
        say(f"seed {seed}: tuning the {described(config)}, then the searches")
        return compare_seed(config, seed, robot)

    return resumable(
        out / "robust_compare.json",
        comparison_settings(robot, config=dataclasses.asdict(config)),
        {f"seed {seed}": (seed,) for seed in COMPARE_SEEDS},
        seed_rows,
        run_of=lambda row: f"seed {row['seed']}",
        check=_checked_rows,
        table=robust_comparison_table,
        resume=resume,
        progress=progress,
    )


def _checked_rows(rows: Any, where: str) -> list[dict[str, Any]]:
    """The rows of a saved robust comparison, if each is an object of one of its seeds."""
    if not isinstance(rows, list) or not all(
        isinstance(r, dict) and r.get("seed") in COMPARE_SEEDS for r in rows
    ):
        raise ValueError(f"{where} has malformed rows")
    return rows
