"""Where the gradient, CMA-ES and random search win as the robust problem grows, at equal compute.

The comparison of ``wmr-jax tune --robust --compare`` (``robust_run.compare_seed``:
each search scores as many candidates as the gradient's iterations cost,
``robust.iteration_price``, on one core like the CLI's, ``search.one_core``;
all judged with the hard law under the standard conditions on the same
held-out poses and draws) on joint problems of growing size:

- 38 parameters: the gain schedule of 10 knots per table (35) and the EKF (3);
- 101: the schedule of 31 knots (98) and the EKF;
- 285: the schedule of 60 knots (185, the largest tuned, ``MAX_TUNED_KNOTS``)
  and the observer's two gain tables of 50 knots (100) instead of the
  filter, whose 3 covariances have no table to grow.

Each (size, seed) is appended to ``--out`` as soon as it is done, and a
rerun with the same settings skips what is there: an interrupted study
loses nothing finished. Seeds run in the outer loop, so that every size has
seed 0 before any has seed 1. ``--table`` prints the Markdown table of a
finished file instead.
``--rerun-cma-es`` runs CMA-ES again for the (size, seed) rows of ``--out``,
at the budget in candidates each was given, and replaces its rows: the
gradient's and random search's rows do not depend on CMA-ES's code.

Usage: ``python experiments/tuner_scaling.py [--sizes 38 101 285] [--seeds 0 1 2]
[--iters 600] [--poses 32] [--out docs/data/tuner_scaling.json] [--table]
[--rerun-cma-es]``: the defaults are `tune --robust --compare`'s, so that the 38 parameters
are its problem.
"""

import argparse
import dataclasses
import json
import math
import os
from pathlib import Path

import jax
import numpy as np

from wmr_jax._src import io
from wmr_jax._src.model.params import Robot
from wmr_jax._src.studies import conditions
from wmr_jax._src.tuning import robust, robust_run, search
from wmr_jax._src.tuning.evaluation import EVAL_SEED, held_out_poses, poses_digest
from wmr_jax._src.tuning.robust import RobustConfig, condition_score

# Parameters -> (schedule knots, estimator, observer knots per table or None: the default).
SIZES = {38: (10, "ekf", None), 101: (31, "ekf", None), 285: (60, "observer", 50)}
DEFAULT = RobustConfig()


def config_of(size: int, args: argparse.Namespace) -> RobustConfig:
    """``tune --robust --compare``'s settings (reduced where ``args`` say) at ``size`` params."""
    knots, estimator, observer_knots = SIZES[size]
    return RobustConfig(
        iters=args.iters,
        poses=args.poses,
        nonideal_poses=args.nonideal_poses,
        search_poses=args.poses,
        validation_poses=args.poses,
        validate_every=max(1, min(DEFAULT.validate_every, args.iters // 4)),
        eval_poses=args.eval_poses,
        knots=knots,
        estimator=estimator,
        observer_knots=observer_knots or DEFAULT.observer_knots,
    ).validate()


def summary(rows: list[dict], size: int) -> list[dict]:
    """One line per method of one seed's rows: the judged score beside the spending."""
    out = []
    for method in ("gradient", "cma-es", "random search"):
        mine = [r for r in rows if r["method"] == method]
        if not mine:
            continue
        first = mine[0]
        out.append(
            {
                "parameters": size,
                "seed": first["seed"],
                "method": method,
                "score_s": float(np.mean([condition_score(r) for r in mine])),
                "worst_success": min(r["success"] for r in mine),
                **{
                    k: first[k]
                    for k in (
                        "budget_s",
                        "cpu_s",
                        "wall_s",
                        "candidates",
                        "per_cpu_s",
                        "loadavg",
                        "minimises",
                        "held_out",
                    )
                },  # fmt: skip
            }
        )
    return out


def table(record: dict) -> str:
    """Markdown: per size and method, the score per seed, its mean, the CPU spent and candidates."""
    lines = [
        "| parameters | method | score (s), seeds 0/1/2 | mean | worst success | "
        "CPU s per seed | candidates (gradient: iterations) |",
        "|---:|---|---|---:|---:|---|---|",
    ]
    groups: dict = {}
    for row in record["rows"]:
        groups.setdefault((row["parameters"], row["method"]), []).append(row)
    for (size, method), rows in sorted(groups.items()):
        rows = sorted(rows, key=lambda r: r["seed"])

        def joined(key: str, fmt: str, rows: list = rows) -> str:
            return " / ".join(fmt.format(r[key]) for r in rows)

        mean = np.mean([r["score_s"] for r in rows])
        worst = min(r["worst_success"] for r in rows)
        lines.append(
            f"| {size} | {method} | {joined('score_s', '{:.3f}')} | {mean:.3f} | "
            f"{100 * worst:.2f} % | {joined('cpu_s', '{:.0f}')} | {joined('candidates', '{:,}')} |"
        )
    return "\n".join(lines) + "\n"


def rerun_cma_es(record: dict, args: argparse.Namespace, out: Path) -> None:
    """Run CMA-ES again for each of ``record``'s (size, seed) in ``args``, at its budget."""
    robot = Robot()
    for i, row in enumerate(record["rows"]):
        size, seed = row["parameters"], row["seed"]
        if row["method"] != "cma-es" or size not in args.sizes or seed not in args.seeds:
            continue
        config = dataclasses.replace(config_of(size, args), seed=seed, compare=True)
        print(f"{size} parameters, seed {seed}: CMA-ES at {row['candidates']:,} candidates")
        loop, count, cpu, wall = robust.compared_search("cma-es", config, robot, row["candidates"])
        held_out = held_out_poses(config.eval_poses, EVAL_SEED)
        judged = conditions.standard_conditions(
            {"cma-es": loop}, held_out, jax.random.key(robust.EVAL_NOISE_SEED), robot=robot,
            noise=config.noise,
        )  # fmt: skip
        spent = {
            "method": "cma-es", "seed": seed, "budget_s": row["budget_s"], "cpu_s": cpu,
            "wall_s": wall, "candidates": count, "per_cpu_s": count / cpu,
            "loadavg": os.getloadavg()[0], "minimises": row["minimises"],
            "held_out": poses_digest(held_out),
        }  # fmt: skip
        (new,) = summary([{**r, **spent} for r in judged], size)
        print(f"  score {row['score_s']:.3f} -> {new['score_s']:.3f} s", flush=True)
        record["rows"][i] = new
        io.atomic_write_json(out, record)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=sorted(SIZES), choices=SIZES)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--iters", type=int, default=DEFAULT.iters)
    parser.add_argument("--poses", type=int, default=DEFAULT.poses)
    parser.add_argument("--nonideal-poses", type=int, default=DEFAULT.nonideal_poses)
    parser.add_argument("--eval-poses", type=int, default=DEFAULT.eval_poses)
    parser.add_argument("--out", type=Path, default=Path("docs/data/tuner_scaling.json"))
    parser.add_argument("--table", action="store_true", help="print the table of --out")
    parser.add_argument("--rerun-cma-es", action="store_true", help="CMA-ES again, same budgets")
    args = parser.parse_args()
    if args.table:
        print(table(json.loads(args.out.read_text(encoding="utf-8"))), end="")
        return
    search.one_core()
    settings = {
        "iters": args.iters,
        "poses": args.poses,
        "nonideal_poses": args.nonideal_poses,
        "eval_poses": args.eval_poses,
        "configs": {str(size): dataclasses.asdict(config_of(size, args)) for size in args.sizes},
    }
    settings = json.loads(json.dumps(settings))
    record = {"settings": settings, "rows": []}
    if args.out.exists():
        saved = json.loads(args.out.read_text(encoding="utf-8"))
        defaults = json.loads(json.dumps(dataclasses.asdict(DEFAULT)))
        for size in args.sizes:  # a size run before must have been run so
            theirs = saved["settings"]["configs"].get(str(size))
            mine = settings["configs"][str(size)]
            # A field added since the file was written counts at its default.
            if theirs is not None and {**defaults, **theirs} != {**defaults, **mine}:
                raise SystemExit(f"{args.out} holds {size} parameters of other settings")
        saved["settings"]["configs"].update(settings["configs"])
        record = saved
    if args.rerun_cma_es:
        rerun_cma_es(record, args, args.out)
        return
    done = {(r["parameters"], r["seed"]) for r in record["rows"]}
    robot = Robot()
    for seed in args.seeds:
        for size in args.sizes:
            if (size, seed) in done:
                continue
            config = config_of(size, args)
            print(f"{size} parameters, seed {seed}", flush=True)
            rows = summary(robust_run.compare_seed(config, seed, robot), size)
            for row in rows:
                rate = row["per_cpu_s"]
                print(
                    f"  {row['method']}: score {row['score_s']:.3f} s, {row['cpu_s']:.0f} CPU s "
                    f"of {row['budget_s']:.0f}, {row['wall_s']:.0f} wall s, "
                    f"{rate if rate is None or math.isnan(rate) else round(rate, 2)} per CPU-s, "
                    f"load {row['loadavg']:.1f}",
                    flush=True,
                )
            record["rows"] += rows
            io.atomic_write_json(args.out, record)


if __name__ == "__main__":
    main()
