"""``wmr-jax tune --robust``: fixed gains tuned through the disturbances of docs/model.md §7.

Called by ``wmr-jax tune`` with its parsed flags (``out``, ``seed``,
``iters``, ``poses``, ``velocity``, ``resume``). Writes ``tuned_gains.json``
(the ``Gains`` field names and ``"controller": "shim-sung"``),
``robust_evaluation.json`` and ``robust_evaluation.md`` (the hard-law table
under the standard conditions, with random search and CMA-ES given the same
wall time) and ``robust_loss.json`` (the loss per iteration).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["run"]

_COLUMNS = ["condition", "gains", "success", "mean arrival s", "median arrival s"]


def _counts(args: Any) -> tuple[int, int]:
    """``--iters`` and ``--poses``, or the robust tuner's own defaults where not given."""
    from wmr_jax._src.tuning.robust import RobustConfig

    robust = RobustConfig()
    counts = []
    for flag, name in (("--iters", "iters"), ("--poses", "poses")):
        value = getattr(args, name, None)
        counts.append(getattr(robust, name) if value is None else flags.positive_int(flag, value))
    return counts[0], counts[1]


def run(args: Any) -> int:
    """Run ``wmr-jax tune --robust``; return the exit status."""
    out = flags.output_dir("--out", getattr(args, "out", None))
    seed = getattr(args, "seed", None)
    seed = flags.positive_int("--seed", 0 if seed is None else seed, 0, 2**32 - 1)
    iters, poses = _counts(args)
    velocity = getattr(args, "velocity", None)
    if velocity is not None and flags.velocity_loop(velocity) != "ideal":
        raise ValueError(
            f"--velocity {velocity!r} is not allowed with --robust; allowed: ideal "
            "(the robust loss mixes both loops itself)"
        )

    from wmr_jax._src import io
    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.tuning.parametrisation import gains_as_dict
    from wmr_jax._src.tuning.robust import RobustConfig, tune_robust
    from wmr_jax._src.tuning.saved import tuned_json

    if getattr(args, "resume", False):
        print("tune --robust keeps no checkpoint: --resume runs it again from the start")
    config = RobustConfig(iters=iters, poses=poses, seed=seed)

    def progress(i: int, loss: float) -> None:
        if i == 1 or i % 25 == 0 or i == iters:
            print(f"iteration {i}/{iters}: loss {loss:.3f} s", flush=True)

    def keep(gains: Any, losses: list[float]) -> None:
        # Written before the searches and the evaluation: an interruption there
        # loses no tuning.
        io.atomic_write_json(out / "tuned_gains.json", tuned_json(gains))
        io.atomic_write_json(out / "robust_loss.json", {"loss": losses})
        print(f"tuned_gains.json, robust_loss.json -> {out} (now judging them)", flush=True)

    result = tune_robust(config, progress_fn=progress, on_tuned=keep)
    searches = {
        m: {**gains_as_dict(g), "candidates": n} for m, (g, n) in result["searches"].items()
    }
    record = {
        "config": dataclasses.asdict(config),
        "tune_wall_s": result["tune_wall_s"],
        "searches": searches,
        "law": "hard (temperature None)",
        "rows": result["rows"],
    }
    io.atomic_write_json(out / "robust_evaluation.json", record)
    table = markdown_table(result["rows"], _COLUMNS)
    io.atomic_write_text(out / "robust_evaluation.md", table)
    print(f"robust_evaluation.md/json -> {out}")
    print(table, end="")
    return 0
