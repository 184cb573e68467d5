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
    parser.add_argument(
        "--nominal-gains",
        default=None,
        metavar="PATH",
        help="tuned_gains.json of `wmr-jax tune`, shown beside the paper's gains",
    )
    parser.add_argument(
        "--robust-gains",
        default=None,
        metavar="PATH",
        help="tuned_gains.json of `wmr-jax tune --robust`, shown beside them, run whole "
        "(with the estimator it was tuned with)",
    )
    parser.add_argument(
        "--estimator",
        default="none",
        metavar="NAME",
        help="estimator of the Monte Carlo's controllers: none (raw feedback), observer or ekf "
        "(docs/model.md §9)",
    )
    parser.add_argument(
        "--noise-curve",
        action="store_true",
        help="also write noise_curve.{png,md,json}: success and arrival against sigma_xy "
        "0-2 cm with ±3 %% wheel mismatch, raw and estimated feedback, for the paper's gains "
        "and the --robust-gains file",
    )


def run(args: Any) -> int:
    """Run ``wmr-jax robustness``; return the exit status."""
    out = flags.output_dir("--out", args.out)
    seed = flags.positive_int("--seed", args.seed, 0, 2**32 - 1)
    # Each run keeps its noise for the whole horizon: 10^6 runs are ~4 GB a level.
    n_runs = flags.positive_int("--runs", args.runs, 1, 10**6)
    names = flags.controller_names(args.controller)
    velocity = flags.velocity_loop(args.velocity)
    estimator = _estimator(args.estimator)
    sets = _gain_sets(args)

    from wmr_jax._src.report.robustness import write_robustness
    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.robustness import robustness_study

    rows = robustness_study(
        seed=seed,
        controller_names=names,
        n_runs=n_runs,
        velocity=velocity,
        x64=not args.float32,
        estimator=estimator,
    )
    write_robustness(out, rows, seed=seed, velocity=velocity, n_runs=n_runs)
    print(f"robustness -> {out}/robustness.png, robustness.md, robustness.json")
    print(markdown_table(rows, _PRINTED), end="")
    _standard(out, sets, seed, x64=not args.float32)
    if args.noise_curve:
        _noise_curve(out, sets, seed, x64=not args.float32)
    return 0


def _estimator(name: str) -> Any:
    """The ``--estimator`` value: ``None`` for raw feedback, else a registered estimator's name."""
    from wmr_jax._src.sensing.estimators import ESTIMATORS

    if name in ("none", "raw"):
        return None
    if name not in ESTIMATORS:
        raise ValueError(
            f"--estimator {name!r} is not allowed; allowed: none, {', '.join(ESTIMATORS)}"
        )
    return name


def _noise_curve(out: Any, sets: dict[str, Any], seed: int, *, x64: bool) -> None:
    """Success and arrival against noise: each set raw and with its (or the default) estimator."""
    import jax

    from wmr_jax._src.report.robustness import write_noise_curve
    from wmr_jax._src.robustness import noise_curve
    from wmr_jax._src.sensing.loop import ClosedLoop
    from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED, held_out_poses

    loops = {}
    for name, value in sets.items():
        if name.endswith(", raw feedback"):
            continue  # drawn as the raw line of its own set
        loop = value if isinstance(value, ClosedLoop) else ClosedLoop("shim-sung", value, None)
        loops[name] = loop._replace(estimator=None)
        # The tuned estimator where the file has one, else the EKF's defaults.
        loops[name + " + estimator"] = loop._replace(estimator=loop.estimator or "ekf")
    refs = held_out_poses(EVAL_POSES, EVAL_SEED)
    rows = noise_curve(loops, refs, jax.random.key(seed), x64=x64)
    meta = {"seed": seed, "held_out_poses": EVAL_POSES, "eval_seed": EVAL_SEED}
    write_noise_curve(out, rows, meta=meta)
    print(f"noise curve -> {out}/noise_curve.png, .md, .json")


def _gain_sets(args: Any) -> dict[str, Any]:
    """The paper's gains and those of the files given (checked before any computation)."""
    from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS
    from wmr_jax._src.tuning.saved import load_tuned

    sets = {"paper (k_r = 60)": PAPER_FEASIBLE_GAINS}
    for flag, label in (("--nominal-gains", "nominal-tuned"), ("--robust-gains", "robust-tuned")):
        path = getattr(args, flag[2:].replace("-", "_"), None)
        if path is None:
            continue
        try:
            loop = load_tuned(path)  # run whole: its controller and estimator
        except ValueError as err:
            raise ValueError(f"{flag} {path!r} is not allowed: {err}") from None
        # The studies take no robot yet: they run every set on the paper robot.
        flags.paper_robot_only(loop.robot, flag, path, "robustness")
        sets[label] = loop
        if loop.estimator is not None:  # beside it, the same law on raw measurements
            sets[f"{label}, raw feedback"] = loop._replace(estimator=None)
    return sets


def _standard(out: Any, sets: dict[str, Any], seed: int, *, x64: bool) -> None:
    """Judge the gain sets under the standard conditions; write and print the table."""
    import jax

    from wmr_jax._src.report.robustness import STANDARD_COLUMNS, write_standard_conditions
    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.robustness import standard_conditions
    from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED, held_out_poses

    refs = held_out_poses(EVAL_POSES, EVAL_SEED)
    rows = standard_conditions(sets, refs, jax.random.key(seed), x64=x64)
    meta = {"seed": seed, "held_out_poses": EVAL_POSES, "eval_seed": EVAL_SEED}
    write_standard_conditions(out, rows, meta=meta)
    print(f"standard conditions -> {out}/standard_conditions.png, .md, .json")
    print(markdown_table(rows, STANDARD_COLUMNS[:6]), end="")


SUBCOMMANDS = {
    "robustness": {
        "help": "Monte Carlo of noise, model mismatch and latency",
        "add_arguments": add_arguments,
        "run": run,
    },
}
