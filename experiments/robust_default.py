"""The robust tuner against CMA-ES alone at equal CPU time, judged on held-out poses.

Usage: ``python experiments/robust_default.py --out FILE.json [--seeds 0 1 2]
[--tuner hybrid|gradient] [--iters N] [--poses N] [--nonideal-poses N]
[--validation-poses N] [--search-poses N] [--eval-poses N] [--polish-share S]
[--polish-std S]`` (defaults: ``RobustConfig``'s). For each seed it runs
``tune_robust`` with the chosen tuner (no searches), then CMA-ES alone
from the tuner's start with step 1 (as ``tune_robust``'s CMA-ES: 8
candidates a generation, hard-law scores on the same search poses) for the
tuner's CPU time (``search.clock``), and judges the loops as
``tune_robust`` does: the standard conditions on the held-out poses, under
the noise of ``wmr-jax robustness``. For the hybrid it also judges the
gradient's result before the polish. A row per loop is written to ``--out``
as soon as its seed ends (a rerun of the same file keeps finished seeds).
docs/robustness.md quotes it.
"""

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--tuner", default=None)
    for name in (
        "iters", "poses", "nonideal_poses", "validation_poses", "search_poses", "eval_poses",
    ):  # fmt: skip
        parser.add_argument("--" + name.replace("_", "-"), type=int, default=None)
    for name in ("polish_share", "polish_std"):
        parser.add_argument("--" + name.replace("_", "-"), type=float, default=None)
    args = parser.parse_args(argv)

    import jax
    import numpy as np

    import wmr_jax as w
    from wmr_jax._src.sim.poses import sample_poses
    from wmr_jax._src.sim.rollout import DEFAULT_DT
    from wmr_jax._src.studies import conditions
    from wmr_jax._src.tuning import robust, search
    from wmr_jax._src.tuning.evaluation import EVAL_SEED, held_out_poses

    search.one_core()  # CPU time counts the work alone, as in ``tune --compare``

    fields = {f.name for f in dataclasses.fields(robust.RobustConfig)}
    changes = {k: v for k, v in vars(args).items() if k in fields and v is not None}
    base = robust.RobustConfig(**changes, compare=False).validate()
    robot = w.Robot()
    path = Path(args.out)
    rows = json.loads(path.read_text()) if path.exists() else []
    starts = []
    black_box = robust.black_box

    def recording(method, *rest, start=None, **kwargs):
        starts.append(start)  # the hybrid's polish: the gradient part's end
        return black_box(method, *rest, start=start, **kwargs)

    robust.black_box = recording
    for seed in args.seeds:
        if any(r["seed"] == seed for r in rows):
            print(f"seed {seed}: kept", flush=True)
            continue
        config = dataclasses.replace(base, seed=seed)
        joint = robust.joint_problem(config)
        began, starts[:] = search.clock(), []
        result = robust.tune_robust(config, robot=robot)
        tuner_cpu, budget = search.clock() - began, result.tune_cpu_s
        stream = jax.random.fold_in(jax.random.key(seed), 11)
        refs = sample_poses(jax.random.fold_in(stream, -1 % 2**31), config.search_poses)
        began = search.clock()
        cma, count, *_ = black_box(
            "cma-es", jax.random.fold_in(jax.random.key(seed), 13), refs, budget, robot,
            DEFAULT_DT, joint, config.noise, start=joint.start_logits(robot), std=1.0,
        )  # fmt: skip
        cma_cpu = search.clock() - began
        sets = {config.tuner: result.loop, "cma-es": cma}
        if starts:
            sets["gradient part"] = robust.concrete_loop(joint.from_logits(starts[0], robot))
        held_out = held_out_poses(config.eval_poses, EVAL_SEED)
        judged = conditions.standard_conditions(
            sets, held_out, jax.random.key(robust.EVAL_NOISE_SEED), robot=robot,
            noise=config.noise,
        )  # fmt: skip
        for name in sets:
            mine = [r for r in judged if r["gains"] == name]
            rows.append(
                {
                    "seed": seed,
                    "method": name,
                    "score_s": float(np.mean([robust.condition_score(r) for r in mine])),
                    "worst_success": float(min(r["success"] for r in mine)),
                    "conditions": {
                        r["condition"]: [r["success"], r["mean arrival s"]] for r in mine
                    },
                    "budget_cpu_s": budget,
                    "cpu_s": {config.tuner: tuner_cpu, "cma-es": cma_cpu}.get(name),
                    "candidates": count if name == "cma-es" else None,
                    "config": {k: v for k, v in config.as_dict().items() if k != "around"},
                    "load": os.getloadavg()[0],
                }
            )
            print(json.dumps(rows[-1]), flush=True)
        path.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
