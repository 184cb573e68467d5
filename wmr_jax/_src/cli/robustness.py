"""``wmr-jax robustness``: Monte Carlo of noise, model mismatch and latency (docs/model.md §7)."""

from __future__ import annotations

from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["SUBCOMMANDS"]

# The columns printed after the run (robustness.md has them all).
_PRINTED = ["condition", "controller", "noise xy cm", "success", "median arrival s"]


def add_study_flags(parser: Any) -> None:
    """Add ``--out``, ``--controller`` and ``--velocity``, the flags every study command has."""
    from wmr_jax._src.controllers import registered_names

    known = ", ".join(registered_names())
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help=f"controllers to run (repeatable; if omitted, every registered one: {known})",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax robustness``."""
    add_study_flags(parser)
    parser.add_argument("--seed", default=0, metavar="N", help="PRNG seed, an integer >= 0")
    parser.add_argument("--runs", default=256, metavar="N", help="runs per noise level")
    parser.add_argument(
        "--float32", action="store_true", help="compute in float32 instead of float64"
    )


def run(args: Any) -> int:
    """Run ``wmr-jax robustness``; return the exit status."""
    out = flags.output_dir("--out", args.out)
    seed = flags.positive_int("--seed", args.seed, 0)
    n_runs = flags.positive_int("--runs", args.runs, 1)
    names = flags.controller_names(args.controller)
    velocity = flags.velocity_loop(args.velocity)

    from wmr_jax._src.report.robustness import write_robustness
    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.robustness import robustness_study

    rows = robustness_study(
        seed=seed, controller_names=names, n_runs=n_runs, velocity=velocity, x64=not args.float32
    )
    write_robustness(out, rows, seed=seed, velocity=velocity, n_runs=n_runs)
    print(f"robustness -> {out}/robustness.png, robustness.md, robustness.json")
    print(markdown_table(rows, _PRINTED), end="")
    return 0


SUBCOMMANDS = {
    "robustness": {
        "help": "Monte Carlo of noise, model mismatch and latency",
        "add_arguments": add_arguments,
        "run": run,
    },
}
