"""``wmr-jax compare``: every controller over the same random docs/model.md §6 poses."""

from __future__ import annotations

from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax compare``."""
    from wmr_jax._src.cli.sweep import _flags as sweep_flags
    from wmr_jax._src.studies.maps import COMPARISON_RUNS, DEFAULT_CHUNK

    parser.description = (
        "Compare the controllers over random docs/model.md §6 poses (not the grid of "
        "`wmr-jax sweep`); the runs, each with its published gains: " + "; ".join(COMPARISON_RUNS)
    )
    parser.add_argument("--out", default="results/compare", metavar="DIR", help="output folder")
    parser.add_argument("--poses", default=200_000, metavar="N", help="random reference poses")
    parser.add_argument("--seed", default=0, metavar="S", help="seed of wmr_jax.sample_poses")
    shared = sweep_flags()
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        metavar="NAME",
        help="also compare these registered controllers, repeatable, each with its default "
        "gains (a law of one's own, docs/custom_controller.md)",
    )
    parser.add_argument("--velocity", **shared["--velocity"])
    parser.add_argument("--horizon", **shared["--horizon"])
    parser.add_argument("--chunk", default=DEFAULT_CHUNK, metavar="N", help="poses per call")
    parser.add_argument("--no-progress", **shared["--no-progress"])
    parser.add_argument("--float32", **shared["--float32"])
    flags.add_robot_flag(parser)


def run(args: Any) -> int:
    """Run ``wmr-jax compare``; return the exit status."""
    from wmr_jax._src.cli.sweep import study_settings
    from wmr_jax._src.report.maps import comparison_table, save_comparison
    from wmr_jax._src.studies.maps import compare_controllers

    out = flags.output_dir("--out", args.out)
    n_poses = flags.positive_int("--poses", args.poses)
    seed = flags.positive_int("--seed", args.seed, 0, 2**32 - 1)
    also = flags.controller_names(args.controller) if args.controller else ()
    given, settings = study_settings(args)
    with flags.as_flags({"horizon": "--horizon", "also": "--controller"}):
        comparison = compare_controllers(n_poses, seed=seed, also=also, **settings)
    if given is not None:
        comparison["robot_label"] = given.label  # the preset's name or the file
    save_comparison(out, comparison)
    print(
        f"{comparison['poses']:,} random poses (seed {comparison['seed']}) -> {out}/comparison.md"
    )
    print(comparison_table(comparison["rows"]), end="")
    over = [row["controller"] for row in comparison["rows"] if row["over V_max"] > 0]
    if over and settings["velocity"] == "ideal":
        v_max = comparison["robot"]["v_max"]
        print(
            f"note: {len(over)} of the {len(comparison['rows'])} rows have runs over V_max = "
            f"{v_max:g} cm/s: the ideal loop follows each wheel command as asked; --velocity "
            "nonideal holds each wheel within V_max (docs/model.md §4.3)"
        )
    return 0
