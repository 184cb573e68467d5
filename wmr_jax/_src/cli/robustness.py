"""``wmr-jax robustness``: Monte Carlo of noise, model mismatch and latency (docs/model.md §7).

With ``--robot DIR/identified.json`` the gain sets run on the identified
robot while the controller believes its base, instead of the Monte Carlo,
whose drawn mismatch, latency and noise the identification replaces.
"""

from __future__ import annotations

import math
from typing import Any

from wmr_jax._src.cli import flags

# What the command writes into --out (the noise curve only with --noise-curve).
_OUTPUTS = tuple(
    f"{stem}.{ext}"
    for stem in ("robustness", "standard_conditions", "noise_curve", "identified_conditions")
    for ext in ("png", "md", "json")
)
# Each gain-file flag: the label of its rows, the tuning its file must come from, its help.
_GAIN_FILES = {
    "--nominal-gains": ("nominal-tuned", "nominal", "shown beside the paper's gains"),
    "--robust-gains": (
        "robust-tuned",
        "robust",
        "shown beside them, run whole (with the estimator it was tuned with)",
    ),
}

# The columns printed after the run (robustness.md has them all).
_PRINTED = ["condition", "controller", "noise xy cm", "success", "median arrival s"]


def add_study_flags(parser: Any) -> None:
    """Add ``--out``, ``--controller`` and ``--velocity``, the flags every study command has."""
    from wmr_jax._src.model.controllers import registered_names

    known = ", ".join(registered_names())
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        metavar="NAME",
        help=f"controllers to run (repeatable; if omitted, every registered one: {known})",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax robustness``."""
    add_study_flags(parser)
    parser.add_argument("--seed", default=0, metavar="N", help="PRNG seed, an integer >= 0")
    parser.add_argument("--runs", default=256, metavar="N", help="runs per noise level")
    from wmr_jax._src.cli.sweep import _flags as sweep_flags

    parser.add_argument("--horizon", **sweep_flags()["--horizon"])
    parser.add_argument("--float32", **flags.FLOAT32)
    from wmr_jax._src.tuning.saved import TUNINGS

    for flag, (_, tuning, shown) in _GAIN_FILES.items():
        text = f"tuned_gains.json of `{TUNINGS[tuning]}`, {shown}"
        parser.add_argument(flag, metavar="PATH", help=text)
    parser.add_argument(
        "--estimator",
        default="none",
        metavar="NAME",
        help="estimator of the Monte Carlo's controllers: none (raw feedback), observer, ekf "
        "or a registered estimator's name (docs/model.md §9)",
    )
    parser.add_argument(
        "--noise-curve",
        action="store_true",
        help="also write noise_curve.{png,md,json}: success and arrival against sigma_xy "
        "0-2 cm with ±3 %% wheel mismatch, raw and estimated feedback, for the paper's gains "
        "and the --robust-gains file",
    )
    flags.add_robot_flag(parser, default="the gain files' robot, else paper")


def run(args: Any) -> int:
    """Run ``wmr-jax robustness``; return the exit status."""
    out = flags.output_dir("--out", args.out)
    seed = flags.positive_int("--seed", args.seed, 0, 2**32 - 1)
    # Each run keeps its noise for the whole horizon: 10^6 runs are ~4 GB a level.
    n_runs = flags.positive_int("--runs", args.runs, 1, 10**6)
    names = flags.controller_names(args.controller)
    velocity = flags.velocity_loop(args.velocity)
    estimator = flags.estimator(args.estimator)
    x64 = not args.float32
    from wmr_jax._src.identify.closed_loop import loaded_identified

    identified = loaded_identified(args.robot)
    if identified is not None and args.noise_curve:
        raise ValueError(
            f"--noise-curve is not allowed with --robot {args.robot}; allowed: the identified "
            "robot's own tracker noise"
        )
    sets, robot = _gain_sets(args, identified)
    horizon = None if args.horizon is None else flags.horizon("--horizon", args.horizon, robot)
    meta = _meta(seed, robot, sets, args)
    # The folder holds this run's results only: an earlier run's go first.
    for name in _OUTPUTS:
        (out / name).unlink(missing_ok=True)
    if identified is not None:
        _on_identified(out, sets, seed, identified, meta, x64=x64, horizon=horizon)
        return 0

    from wmr_jax._src.model.robots import describe_robot, robot_name
    from wmr_jax._src.report.robustness import robustness_table, write_robustness
    from wmr_jax._src.studies.robustness import robustness_study, study_horizon

    note = ""
    if robot_name(robot) != "paper":
        note = (
            "; the Monte Carlo runs shim-sung and shim-sung-schedule on the paper's gains "
            "scaled into this robot's wheel budget, the baselines on their defaults (the "
            "ideal loop does not limit their wheel commands: robustness.json has each row's "
            "peak wheel speed; --velocity nonideal holds the wheels within V_max)"
        )
    origin = f", from {args.robot}" if flags.is_robot_file(args.robot) else ""
    shown = study_horizon(robot) if horizon is None else horizon
    print(f"robot {describe_robot(robot)}{origin}, horizon {shown:g} s{note}")
    study = {"seed": seed, "velocity": velocity, "n_runs": n_runs, "robot": robot, "x64": x64}
    rows = robustness_study(controller_names=names, estimator=estimator, horizon=horizon, **study)
    write_robustness(out, rows, **study)
    print(f"robustness -> {out}/robustness.png, robustness.md, robustness.json")
    printed = _PRINTED if estimator is None else [*_PRINTED[:2], "feedback", *_PRINTED[2:]]
    print(robustness_table(rows, printed), end="")
    # What the judged runs share: the robot, the dtype and the horizon.
    runs = {"robot": robot, "x64": x64, "horizon": horizon}
    _standard(out, sets, seed, meta, runs)
    if args.noise_curve:
        _noise_curve(out, sets, seed, meta, runs)
    return 0


def _meta(seed: int, robot: Any, sets: dict[str, Any], args: Any) -> dict[str, Any]:
    """What the standard conditions and the noise curve record beside their rows."""
    from wmr_jax._src.model.robots import robot_json
    from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED

    files = {flag: _gain_file(args, flag) for flag in _GAIN_FILES}
    return {
        "seed": seed,
        "held_out_poses": EVAL_POSES,
        "eval_seed": EVAL_SEED,
        "dtype": "float32" if args.float32 else "float64",
        "gain_files": {flag: str(path) for flag, path in files.items() if path is not None},
        "gains": _gains_of(sets),
        "robot": robot_json(robot),
    }


def _gains_of(sets: dict[str, Any]) -> dict[str, Any]:
    """Each set's parameters and estimator, as ``tuned_gains.json`` holds them."""
    from wmr_jax._src.studies.conditions import as_closed_loop
    from wmr_jax._src.tuning.saved import tuned_json

    loops = {label: as_closed_loop(loop, "shim-sung", None, label) for label, loop in sets.items()}
    return {label: tuned_json(loop.params, loop.estimator) for label, loop in loops.items()}


def _gain_file(args: Any, flag: str) -> Any:
    return getattr(args, flag[2:].replace("-", "_"), None)


def _noise_curve(
    out: Any, sets: dict[str, Any], seed: int, meta: dict[str, Any], runs: dict[str, Any]
) -> None:
    """Success and arrival against noise: each set raw and with its (or the default) estimator."""
    import jax

    from wmr_jax._src.report.robustness import write_noise_curve
    from wmr_jax._src.studies.conditions import as_closed_loop, noise_curve

    loops = {}
    for name, value in sets.items():
        if name.endswith(", raw feedback"):
            continue  # drawn as the raw line of its own set
        loop = as_closed_loop(value, "shim-sung", None, name)
        loops[name] = loop._replace(estimator=None)
        # The tuned estimator where the file has one, else the EKF's defaults.
        loops[name + " + estimator"] = loop._replace(estimator=loop.estimator or "ekf")
    rows = noise_curve(loops, _held_out(), jax.random.key(seed), **runs)
    write_noise_curve(out, rows, meta={**meta, "gains": _gains_of(loops)})  # the loops it ran
    print(f"noise curve -> {out}/noise_curve.png, .md, .json")


def _gain_sets(args: Any, identified: Any = None) -> tuple[dict[str, Any], Any]:
    """The gain sets, the paper's feasible gains first, and the robot they run on (checked)."""
    from wmr_jax._src.identify.closed_loop import tuned_for_identified
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.model.robots import same_robot
    from wmr_jax._src.tuning.parametrisation import paper_feasible_gains
    from wmr_jax._src.tuning.saved import TUNINGS

    given = flags.robot_from(args.robot) if identified is None else identified[0]
    if given is not None and given.note:
        print(given.note)
    loops = {}
    robot, source = (None, None) if given is None else (given.robot, f"--robot {given.label!r}")
    for flag, (label, wanted, _) in _GAIN_FILES.items():
        path = _gain_file(args, flag)
        if path is None:
            continue
        loop, tuning = flags.tuned_file(flag, path)  # run whole: its law and estimator
        if identified is not None and tuned_for_identified(loop.robot, identified[1]):
            loop = loop._replace(robot=given.robot)  # its controller believes the base
        if tuning is not None and tuning != wanted:
            # Its rows would be labelled by the flag: a nominal file called robust-tuned.
            other = "--nominal-gains" if tuning == "nominal" else "--robust-gains"
            raise ValueError(
                f"{flag} {str(path)!r} is not allowed: its gains were tuned by "
                f"`{TUNINGS[tuning]}`; allowed: a file of `{TUNINGS[wanted]}` (give this "
                f"one as {other})"
            )
        chosen = flags.robot_for_gains(given, loop.robot, flag, path)
        if chosen is not None and robot is None:
            robot, source = chosen, f"{flag} {str(path)!r}"
        elif chosen is not None and not same_robot(chosen, robot):
            raise ValueError(
                f"{flag} {str(path)!r} is not allowed with {source}: tuned for "
                f"{flags.short_robot(chosen)}, the other for {flags.short_robot(robot)}; "
                "allowed: gain files tuned for one robot"
            )
        loops[label] = loop
    robot = Robot() if robot is None else robot
    paper = paper_feasible_gains(robot)
    sets = {f"paper (k_r = {float(paper.kr):.3g})": paper}
    for label, loop in loops.items():
        sets[label] = loop._replace(robot=robot)  # a file that records none runs there too
        if loop.estimator is not None:  # beside it, the same law on raw measurements
            sets[f"{label}, raw feedback"] = sets[label]._replace(estimator=None)
    return sets, robot


def _standard(
    out: Any, sets: dict[str, Any], seed: int, meta: dict[str, Any], runs: dict[str, Any]
) -> None:
    """Judge the gain sets under the standard conditions; write and print the table."""
    import jax

    from wmr_jax._src.report.robustness import (
        STANDARD_COLUMNS,
        robustness_table,
        write_standard_conditions,
    )
    from wmr_jax._src.studies.conditions import standard_conditions

    rows = standard_conditions(sets, _held_out(), jax.random.key(seed), **runs)
    write_standard_conditions(out, rows, meta=meta)
    print(f"standard conditions -> {out}/standard_conditions.png, .md, .json")
    print(robustness_table(rows, STANDARD_COLUMNS[:6]), end="")


def _on_identified(
    out: Any,
    sets: dict[str, Any],
    seed: int,
    identified: Any,
    meta: dict[str, Any],
    *,
    x64: bool,
    horizon: float | None,
) -> None:
    """Judge the gain sets on the identified robot, without its tracker noise, and on the base."""
    import numpy as np

    from wmr_jax._src.io import atomic_write_json, atomic_write_text
    from wmr_jax._src.report.robustness import STANDARD_COLUMNS, robustness_table
    from wmr_jax._src.studies.conditions import evaluate_loop

    base, content = identified[0].robot, identified[1]
    quiet = {**content, "noise": {"sigma_xy": 0.0, "sigma_theta": 0.0}}
    conditions = {
        "identified robot": {"identified": content},
        "identified robot, no tracker noise": {"identified": quiet},
        "base robot": {"mismatch": 0.0},
    }
    refs = _held_out()
    rows = []
    for label, how in conditions.items():
        for name, value in sets.items():
            got = evaluate_loop(value, refs, seed=seed, x64=x64, robot=base, horizon=horizon, **how)
            rows.append(
                {
                    "condition": label,
                    "gains": name,
                    "feedback": got["feedback"],
                    "success": got["success"],
                    "mean arrival s": _finite(got["mean_arrival_s"]),
                    "median arrival s": _finite(got["median_arrival_s"]),
                    "mean final distance cm": float(
                        np.mean([r["final_distance_cm"] for r in got["per_reference"]])
                    ),
                    "mismatch": got["mismatch"],
                    "runs": got["n"],
                    "settled at horizon": got["settled_at_horizon"],
                    "horizon s": got["horizon_s"],
                }
            )
    table = robustness_table(rows, STANDARD_COLUMNS)
    head = (
        f"Gain sets on the robot identified in {identified[0].label} (its wheel scales, "
        "half-track, wheel lag, latency and tracker noise; the controller believes the base "
        f"robot), hard law, ideal loop, {len(refs)} held-out poses of docs/model.md §6\n\n"
    )
    atomic_write_text(out / "identified_conditions.md", head + table)
    record = {**meta, "identified_file": identified[0].label, "rows": rows}
    atomic_write_json(out / "identified_conditions.json", record)
    print(f"identified conditions -> {out}/identified_conditions.md, .json")
    print(robustness_table(rows, STANDARD_COLUMNS[:6]), end="")


def _held_out() -> Any:
    """The held-out poses of docs/model.md §6 every gain set is judged on."""
    from wmr_jax._src.tuning.evaluation import EVAL_POSES, EVAL_SEED, held_out_poses

    return held_out_poses(EVAL_POSES, EVAL_SEED)


def _finite(value: Any) -> float:
    """An arrival of ``evaluate_loop`` as the tables hold it: ``inf`` where none arrived."""
    return math.inf if value is None else float(value)
