"""Candidates per CPU-second of the robust searches' scoring, one at a time and batched.

The robust tuner's searches score each candidate with ``robust_score`` (the
hard law under the standard conditions on ``search_poses`` poses). This
scores one generation of 8 candidates of the joint problem both ways (a
Python loop of ``robust_score`` calls, and ``robust_population_scores``, one
batch per condition), checks that both give the same scores, and prints
candidates per CPU-second (``search.clock``) and per wall-second of each,
after one warm-up generation (compilation not counted).

Usage: ``python experiments/robust_scoring_rate.py [--poses 32] [--repeats 5] [--knots K]``
"""

import argparse
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim.poses import sample_poses
from wmr_jax._src.tuning import robust
from wmr_jax._src.tuning.estimation import concrete_loop
from wmr_jax._src.tuning.search import clock, robust_population_scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--knots", type=int, default=robust.RobustConfig.knots)
    args = parser.parse_args()
    config = robust.RobustConfig(knots=args.knots)
    joint, robot = robust.joint_problem(config), Robot()
    refs = sample_poses(jax.random.key(1), args.poses)
    key = jax.random.key(2)
    start = jnp.asarray(joint.start_logits(robot))
    zs = start + 0.5 * jax.random.normal(jax.random.key(3), (8, joint.dim), start.dtype)
    loops = [concrete_loop(joint.from_logits(z, robot)) for z in zs]

    def one_at_a_time() -> np.ndarray:
        return np.array(
            [robust.robust_score(lp, refs, key, robot=robot, noise=config.noise) for lp in loops]
        )

    def batched() -> np.ndarray:
        return robust_population_scores(
            loops, refs, key, dt=robust.DEFAULT_DT, robot=robot, noise=config.noise
        )

    results = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, fn in (("one at a time", one_at_a_time), ("batched", batched)):
            scores = fn()  # warm-up: compilation
            cpu, wall = clock(), time.perf_counter()
            for _ in range(args.repeats):
                fn()
            cpu, wall = clock() - cpu, time.perf_counter() - wall
            n = args.repeats * len(loops)
            results[name] = scores
            print(
                f"{name}: {n / cpu:.1f} candidates per CPU-s, {n / wall:.1f} per wall-s "
                f"({joint.dim} parameters, {args.poses} poses x 5 conditions)"
            )
    gap = np.max(np.abs(results["batched"] - results["one at a time"]))
    print(f"largest score difference between the two: {gap:.2e} s")


if __name__ == "__main__":
    main()
