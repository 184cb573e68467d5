"""``wmr-jax compare``: every controller over the same random docs/model.md §6 poses.

Runs ``wmr_jax.studies.compare_controllers`` (``sample_poses(--seed,
--poses)``; Shim–Sung with the paper's gains, each baseline with its
published gains and also with its other driving mode) on the robot of
``--robot``, writes ``comparison.md`` and ``comparison.json`` (which records
the robot) into ``--out`` and prints the table docs/maps.md shows. ``wmr-jax
sweep`` is the grid map, not these random poses.
"""

from __future__ import annotations

from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["SUBCOMMANDS"]


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax compare``."""
    from wmr_jax._src.studies.maps import COMPARISON_RUNS, DEFAULT_CHUNK

    parser.description = (
        "Compare the controllers over random docs/model.md §6 poses (not the grid of "
        "`wmr-jax sweep`); the runs, each with its published gains: " + "; ".join(COMPARISON_RUNS)
    )
    parser.add_argument("--out", default="results/compare", metavar="DIR", help="output folder")
    parser.add_argument("--poses", default=200_000, metavar="N", help="random reference poses")
    parser.add_argument("--seed", default=0, metavar="S", help="seed of wmr_jax.sample_poses")
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument(
        "--horizon",
        default=None,
        metavar="S",
        help="simulated time per run, s (default: the paper robot's 6 s, docs/model.md §6; "
        "for a --robot whose wheels cannot follow the paper's feasible gains, 60 + 10 L > "
        "v_max, 6 s × (60 + 10 L) / v_max rounded up to 0.1 s, as those gains are scaled to fit; "
        "printed with the robot)",
    )
    parser.add_argument("--chunk", default=DEFAULT_CHUNK, metavar="N", help="poses per call")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--float32",
        action="store_true",
        help="compute in float32, JAX's default (default: float64)",
    )
    flags.add_robot_flag(parser)


def run(args: Any) -> int:
    """Run ``wmr-jax compare``; return the exit status."""
    from wmr_jax._src.cli.sweep import robot_and_horizon
    from wmr_jax._src.report.maps import comparison_table, save_comparison
    from wmr_jax._src.studies.maps import compare_controllers

    out = flags.output_dir("--out", args.out)
    n_poses = flags.positive_int("--poses", args.poses)
    seed = flags.positive_int("--seed", args.seed, 0, 2**32 - 1)
    velocity = flags.velocity_loop(args.velocity)
    chunk = flags.positive_int("--chunk", args.chunk)
    given, robot, horizon = robot_and_horizon(args)
    with flags.as_flags({"horizon": "--horizon"}):
        comparison = compare_controllers(
            n_poses,
            seed=seed,
            velocity=velocity,
            chunk=chunk,
            progress=not args.no_progress,
            x64=not args.float32,
            robot=robot,
            horizon=horizon,
        )
    if given is not None:
        comparison["robot_label"] = given.label  # the preset's name or the file
    save_comparison(out, comparison)
    print(
        f"{comparison['poses']:,} random poses (seed {comparison['seed']}) -> {out}/comparison.md"
    )
    print(comparison_table(comparison["rows"]), end="")
    return 0


SUBCOMMANDS = {
    "compare": {
        "help": "compare the controllers over random poses (the table of docs/maps.md)",
        "add_arguments": add_arguments,
        "run": run,
    },
}
