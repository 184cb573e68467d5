"""``wmr-jax waypoints``: consecutive motions through a chain of waypoints."""

from __future__ import annotations

import math
from typing import Any

from wmr_jax._src.cli import flags
from wmr_jax._src.cli.robustness import add_study_flags

__all__ = ["SUBCOMMANDS"]


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax waypoints``."""
    add_study_flags(parser)
    parser.add_argument("--steps", default=450, metavar="N", help="control periods of each run")
    parser.add_argument("--pass-tol", default=5.0, metavar="CM", help="pass-through distance, cm")
    parser.add_argument(
        "--pass-tol-deg",
        default=30.0,
        metavar="DEG",
        help="pass-through heading tolerance, degrees, <= 90 (90 ignores the heading)",
    )


def run(args: Any) -> int:
    """Run ``wmr-jax waypoints``; return the exit status."""
    out = flags.output_dir("--out", args.out)
    pass_deg = flags.number(
        "--pass-tol-deg", args.pass_tol_deg, low=0.0, high=90.0, closed=False, unit="degrees"
    )
    settings = {
        "controller_names": flags.controller_names(args.controller),
        "velocity": flags.velocity_loop(args.velocity),
        "steps": flags.positive_int("--steps", args.steps, 1, 10**7),
        "pass_tol_r": flags.number("--pass-tol", args.pass_tol, low=0.0, closed=False, unit="cm"),
        "pass_tol_theta": math.radians(pass_deg),
    }

    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.report.waypoints import write_soccer
    from wmr_jax._src.waypoints import soccer_study

    study = soccer_study(**settings)
    write_soccer(out, study)
    table = markdown_table(study.rows)
    print(f"soccer-like sequence -> {out}/soccer.png, soccer.md, soccer.json\n{table}", end="")
    return 0


SUBCOMMANDS = {
    "waypoints": {
        "help": "consecutive motions through a chain of waypoints",
        "add_arguments": add_arguments,
        "run": run,
    },
}
