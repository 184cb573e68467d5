"""A tuning run with its files: checkpoints, ``tuned_gains.json``, ``evaluation.json``, the curve.

A checkpoint is an ``io.save_arrays`` file of ``state_arrays`` with the run's
identity (``run_identity``) beside it: one of other settings, another robot,
other code or another format (``CHECKPOINT_FORMAT``) is refused, never read.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src import io
from wmr_jax._src.checks import check_bool, check_callable, check_folder
from wmr_jax._src.model.params import Robot, check_feasible, validate_robot
from wmr_jax._src.model.robots import ROBOT_UNITS, robot_json
from wmr_jax._src.report.progress import bar as tqdm
from wmr_jax._src.studies.optimal import time_bounds
from wmr_jax._src.tuning import trainer, training
from wmr_jax._src.tuning.evaluation import held_out_poses, report_ratios
from wmr_jax._src.tuning.saved import tuned_json, write_tuned

CHECKPOINT_NAME = "checkpoint.npz"
CHECKPOINT_FORMAT = 4


def load_checkpoint(path: Path, fresh: Any, identity: dict[str, Any]) -> Any:
    """Restore a checkpoint into ``fresh``'s structure; refuse a damaged one or another run's."""
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
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(
            f"--resume: checkpoint {path} has an unknown format (format = "
            f"{meta.get('format')!r:.40}; allowed: {CHECKPOINT_FORMAT}); {advice}"
        )
    saved = meta.get("identity")
    if not isinstance(saved, dict) or not all(
        isinstance(saved.get(key), dict) for key in ("config", "robot")
    ):
        raise ValueError(
            f"--resume: checkpoint {path} has metadata of the wrong shape (identity = "
            f"{saved!r:.60}; allowed: an object with a 'config' and a 'robot' object); {advice}"
        )
    # Compare as JSON, the way the identity was stored.
    now = json.loads(json.dumps(identity))
    if saved != now:
        there, here = saved["config"], now["config"]
        iters = there.keys() == here.keys() and there.get("iters") != here.get("iters")
        why = (
            " (the step size and the temperature anneal over all the iterations: another "
            "number of them is another run)"
            if iters
            else ""
        )
        raise ValueError(
            f"--resume: checkpoint {path} is of another run "
            f"({trainer.differences(saved, now)}){why}; "
            "allowed: the same settings, or a fresh --out"
        )
    try:
        return trainer.restore_state(arrays, fresh)
    except ValueError as err:
        raise ValueError(f"--resume: checkpoint {path}: {err}; {advice}") from None


def save_checkpoint(path: Path, state: Any, identity: dict[str, Any]) -> None:
    """Write ``state`` with the run's identity to ``path``, checksummed and atomically."""
    io.save_arrays(
        path, trainer.state_arrays(state), {"format": CHECKPOINT_FORMAT, "identity": identity}
    )


def resumed_state(
    checkpoint: Path, fresh: Callable[[], Any], identity: dict[str, Any], say: Callable = print
) -> Any:
    """``--resume``: the state ``checkpoint`` holds, in ``fresh()``'s structure; else ``None``.

    Either is said in one line: a mistyped ``--out`` would otherwise start over without a word.
    """
    if not checkpoint.exists():
        where = checkpoint.parent
        say(f"--resume: no {CHECKPOINT_NAME} in {where}; starting from the first iteration")
        return None
    state = load_checkpoint(checkpoint, fresh(), identity)
    say(f"--resume: continuing after iteration {state.iteration} of {checkpoint}")
    return state


def checkpointing(
    checkpoint: Path, identity: dict[str, Any], every: int, iters: int
) -> Callable[[Any], None]:
    """A progress callback that saves the state every ``every`` iterations and at the last."""

    def save(state: Any) -> None:
        if state.iteration % every == 0 or state.iteration == iters:
            save_checkpoint(checkpoint, state, identity)

    return save


def finished(out: Path, config: Any, robot: Any) -> bool:
    """Whether ``out`` holds this run finished, so that resuming it would redo nothing new.

    That is: its checkpoint is of the same run and at its last iteration, an
    ``evaluation.json`` of the same settings and robot was written after it (a run
    stopped in its random search or evaluation has none newer, and is resumed), and
    its ``tuned_gains.json`` is there.
    """
    robot = validate_robot(Robot() if robot is None else robot)
    config = config.for_robot(robot)
    checkpoint, report = out / CHECKPOINT_NAME, out / "evaluation.json"
    try:
        if report.stat().st_mtime_ns < checkpoint.stat().st_mtime_ns:
            return False
        arrays, meta = io.load_arrays(checkpoint)
        saved = json.loads(report.read_text())
        iteration = int(np.asarray(arrays.get("iteration", -1)))
    except (OSError, TypeError, ValueError):  # a damaged file among them
        return False  # resuming says what is wrong with them
    identity = training.run_identity(config, robot)
    return (
        isinstance(meta, dict)
        and meta.get("format") == CHECKPOINT_FORMAT
        and meta.get("identity") == identity
        and iteration == config.iters
        and isinstance(saved, dict)
        and isinstance(saved.get("config"), dict)
        and trainer.identity_config(saved["config"]) == trainer.identity_config(config)
        and saved.get("robot") == json.loads(json.dumps(robot_json(robot)))
        and (out / "tuned_gains.json").exists()
    )


def _progress(
    config: Any, checkpoint: Path, identity: dict[str, Any], bar: Any, user_fn: Callable | None
) -> Callable[[Any], None]:
    """The training's progress callback: the bar, the checkpoint, then the caller's."""
    save = checkpointing(checkpoint, identity, config.checkpoint_every, config.iters)

    def report(state: Any) -> None:
        bar.update(1)
        bar.set_postfix(
            loss=f"{state.losses[-1]:.3f}s", T=f"{state.temperatures[-1]:.3g}", refresh=False
        )
        save(state)
        if state.iteration == config.iters:
            bar.close()  # before the random search and the evaluation
        if user_fn is not None:
            user_fn(state)

    return report


def held_out_bounds(config: Any, robot: Any) -> Any:
    """The time-optimal yardsticks (docs/model.md §8) of the held-out poses of ``config``."""
    refs = held_out_poses(config.eval_poses, config.eval_seed)
    return time_bounds(refs, robot=robot, dt=config.dt)


def write_results(
    out: Path, config: Any, robot: Any, result: Any, resumed_at: int | None = None
) -> None:
    """Write the parameters, the evaluation and the tuning curve of ``result`` to ``out``.

    ``resumed_at``: the iteration this run resumed from (``None``: it ran them all).

    Raises:
        ValueError: one line, if the tuned parameters are not all finite
            (nothing is written then).
    """
    from wmr_jax._src.report.tuning import tuning_curve

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
    for row in rows.values():
        row.update(report_ratios(row["mean_arrival"], bounds, paper))
        row["peak_wheel_speed_ok"] = row["peak_wheel_speed"] <= float(robot.v_max) * (1 + 1e-6)
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
        "peak_wheel_speed_ok": all(row["peak_wheel_speed_ok"] for row in rows.values()),
        "robot": robot_json(robot),
        "robot_units": dict(ROBOT_UNITS),
        "cpu_time_s": {
            "tuning": result.tune_cpu_s,
            "random_search": None if search is None else search.cpu_s,
        },
        # A resumed run's tuning time holds one more compilation per resume.
        "resumed_at_iteration": resumed_at,
        "random_search_candidates": None if search is None else search.candidates,
        **trainer.verdict(result, config.validation_poses),
        "config": config.as_dict(),
    }
    io.atomic_write_json(out / "evaluation.json", report)
    tuning_curve(
        out / "tuning_curve.png",
        result.history,
        velocity=config.velocity,
        problem=result.problem,
        robot=robot,
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

    Files in ``out_dir``: ``tuned_gains.json`` (``wmr_jax.load_tuned`` reads
    it), ``evaluation.json``, ``tuning_curve.png``, ``random_search_gains.json``
    and ``checkpoint.npz`` (every ``config.checkpoint_every`` iterations).

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
    out = check_folder("out_dir", out_dir)
    check_bool("resume", resume)
    check_bool("progress", progress)
    check_callable("progress_fn", progress_fn)
    config = trainer.checked_config(config, training.TuneConfig)
    io.remove_stale_temporaries(out)
    # The robot as given, not rounded to the session's float32: the files
    # record it, and a preset read back must still be that preset.
    robot = validate_robot(Robot() if robot is None else robot)
    config = config.for_robot(robot)  # the horizon its files record
    identity = training.run_identity(config, robot)
    fresh = training.init_state(config, robot)
    checkpoint = out / CHECKPOINT_NAME
    state = resumed_state(checkpoint, lambda: fresh, identity) if resume else None
    state = fresh if state is None else state
    # The progress bars: the iterations, the random search, the evaluation.
    bar = tqdm(
        total=config.iters,
        initial=state.iteration,
        desc=f"tune ({config.velocity})",
        disable=not progress,
        dynamic_ncols=True,
    )
    search_bar = tqdm(
        desc="random search (same CPU time)",
        unit=" candidates",
        disable=not (progress and config.random_search),
        dynamic_ncols=True,
    )
    eval_bar = tqdm(total=3, desc="hard-law evaluation", disable=not progress, dynamic_ncols=True)
    report = _progress(config, checkpoint, identity, bar, progress_fn)
    try:
        result = training.train(
            config,
            robot=robot,
            state=state,
            progress_fn=report,
            search_progress=search_bar.update,
            eval_progress=lambda _name: (search_bar.close(), eval_bar.update(1)),
        )
    finally:
        for each in (bar, search_bar, eval_bar):
            each.close()
    write_results(out, config, robot, result, state.iteration or None)
    return result
