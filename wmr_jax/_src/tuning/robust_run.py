"""A robust tuning run with its files, and the resumable robust comparison.

``save_tuned`` writes the tuned loop as soon as the iterations end,
``write_evaluation`` the hard-law table under the standard conditions
(``robust_evaluation.json`` and ``.md``), and ``run_comparison`` runs seeds
0–2 of ``tune_robust`` with random search and CMA-ES into
``robust_compare.json`` and ``.md``, each seed written as it finishes and
kept by a resumed comparison of the same settings, robot and code.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wmr_jax._src import io
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.tuning import robust, trainer
from wmr_jax._src.tuning.robust import RobustConfig

__all__ = [
    "COLUMNS",
    "COMPARE_SEEDS",
    "described",
    "run_comparison",
    "save_tuned",
    "write_evaluation",
]

COLUMNS = ["condition", "gains", "feedback", "success", "mean arrival s", "median arrival s"]
COMPARE_SEEDS = (0, 1, 2)
COMPARE_FORMAT = 2


def described(config: RobustConfig) -> str:
    """What ``config`` tunes, in words: the law and its feedback."""
    law = "7 fixed gains" if config.law == "fixed" else f"gain schedule ({config.knots} knots)"
    sensing = "raw feedback" if config.estimator is None else f"the {config.estimator}"
    noise = f"pose noise {config.noise_xy:g} cm, {config.noise_theta:g}°"
    return f"{law} with {sensing}, for {noise}"


def save_tuned(out: Path, loop: Any, losses: list[float], robot: Robot) -> None:
    """Write ``tuned_gains.json`` (the loop and its robot) and ``robust_loss.json``.

    Removes the files that judged the gains it replaces.
    """
    from wmr_jax._src.tuning.saved import tuned_json, write_tuned

    write_tuned(out, tuned_json(loop, robot=robot, tuning="robust"))
    io.atomic_write_json(out / "robust_loss.json", {"loss": losses})


def write_evaluation(out: Path, config: RobustConfig, robot: Robot, result: Any) -> str:
    """Write ``robust_evaluation.json`` and ``.md`` of a robust result; return the table."""
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.report.robustness import robustness_table

    record = {
        "config": dataclasses.asdict(config),
        "robot": robot_json(robot),
        "tune_wall_s": result.tune_wall_s,
        "law": "hard (temperature None)",
        # The sensor tuned for: the training's noise up to twice it, the table's at it.
        "noise": {"xy cm": config.noise_xy, "theta degrees": config.noise_theta},
        "rows": result.rows,
        # The iterate kept: the best hard-law score on the validation poses.
        **trainer.verdict(result, config.validation_poses),
    }
    io.atomic_write_json(out / "robust_evaluation.json", record)
    table = robustness_table(result.rows, COLUMNS)
    io.atomic_write_text(out / "robust_evaluation.md", table)
    return table


def _kept_rows(path: Any, settings: dict[str, Any], resume: bool) -> list[dict[str, Any]]:
    """The rows of an earlier ``--compare`` of the same settings (``--resume``), else none."""
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
        isinstance(r, dict) and r.get("seed") in COMPARE_SEEDS for r in rows
    )
    if not good:
        raise ValueError(f"--resume: {str(path)!r} has malformed rows; allowed: another --out")
    return rows


def run_comparison(
    out: Path,
    config: RobustConfig,
    *,
    robot: Robot | None = None,
    resume: bool = False,
    progress: Callable[[str], Any] | None = print,
) -> list[dict[str, Any]]:
    """Gradient, CMA-ES and random search at equal wall time, seeds 0–2; each seed kept.

    The settings, the robot and the code version are recorded with the rows:
    a resumed comparison keeps only rows of the same three.

    Returns:
        The rows (kept and new), also written to ``robust_compare.json`` and ``.md``.
    """
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.provenance import code_version
    from wmr_jax._src.report.tuning import robust_comparison_table

    robot = validate_one_robot(robot, "tuning")
    path = out / "robust_compare.json"
    settings = {
        "format": COMPARE_FORMAT,
        "config": dataclasses.asdict(config),
        "robot": robot_json(robot),
        "code": code_version(),  # rows of another law are not this comparison's
    }
    settings = json.loads(json.dumps(settings))  # as it reads back from the file
    rows = _kept_rows(path, settings, resume)
    if not resume:  # a new comparison: nothing of an earlier one stays beside its rows
        for stale in (path, out / "robust_compare.md"):
            stale.unlink(missing_ok=True)
    done = {row["seed"] for row in rows}
    say = progress if progress is not None else (lambda _line: None)
    for seed in COMPARE_SEEDS:
        if seed in done:
            say(f"seed {seed}: kept from {path}")
            continue
        say(f"seed {seed}: tuning the {described(config)}, then the searches")
        config_seed = dataclasses.replace(config, seed=seed, compare=True)
        result = robust.tune_robust(config_seed, robot=robot)
        budget = result.tune_wall_s
        counts = {"gradient": config.iters, **{m: n for m, (_, n) in result.searches.items()}}
        for row in result.rows:
            if row["gains"] == "paper":
                continue
            method = "gradient" if row["gains"] == "robust-tuned" else row["gains"]
            rows.append(
                {**row, "method": method, "seed": seed, "budget_s": budget,
                 "candidates": counts[method]}
            )  # fmt: skip
        # Sealed with a checksum: --resume keeps only what this wrote.
        io.atomic_write_json(path, io.sealed({"settings": settings, "rows": rows}))
    io.atomic_write_text(out / "robust_compare.md", robust_comparison_table(rows))
    return rows
