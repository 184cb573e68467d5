"""What the robust gradient descends against what the table judges, for its loop and CMA-ES's.

For one seed of ``wmr-jax tune --robust --compare`` it tunes the default
joint problem with the gradient (``tune_robust``, no searches) and runs
CMA-ES as the comparison does (``robust.black_box``, the same search poses
and key) for ``--candidates``; then, on ``--poses`` fresh poses under each
standard condition at the judged noise level (hard law, float32), it gives
each loop's mean surrogate term (``loss.recorded_arrival``: the soft arrival
plus the log-error shaping), its share of runs that arrive and their mean
arrival (``wmr_jax.arrival_time``, docs/model.md §6). docs/robustness.md
("Which tuner to use") quotes it.

Usage: ``python experiments/surrogate_ranking.py [--seed 2] [--candidates 3203]
[--poses 200]``
"""

import argparse
import json
import math
import types


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--candidates", type=int, default=3203)
    parser.add_argument("--poses", type=int, default=200)
    args = parser.parse_args()

    import jax
    import jax.numpy as jnp
    import numpy as np

    import wmr_jax as w
    from wmr_jax._src.sim import loops
    from wmr_jax._src.sim.poses import horizon_steps, sample_poses
    from wmr_jax._src.sim.sensing import disturbances, loop
    from wmr_jax._src.studies.robustness import study_horizon
    from wmr_jax._src.tuning import loss, robust, search

    search.one_core()
    robot, dt = w.Robot(), robust.DEFAULT_DT
    config = robust.RobustConfig(seed=args.seed, compare=False).validate()
    joint = robust.joint_problem(config)
    stream = jax.random.fold_in(jax.random.key(config.seed), 11)
    search_refs = sample_poses(jax.random.fold_in(stream, -1 % 2**31), config.search_poses)
    cma_key = jax.random.fold_in(jax.random.key(config.seed), 13)  # as tune_robust's CMA-ES
    loops_by_name = {
        "gradient": robust.tune_robust(config, robot=robot).loop,
        "cma-es": robust.black_box(
            "cma-es", cma_key, search_refs, math.inf, robot, dt, joint, config.noise,
            candidates=args.candidates,
        )[0],
    }  # fmt: skip

    steps = horizon_steps(dt, study_horizon(robot))
    refs = sample_poses(jax.random.key(123), args.poses)
    init = jnp.zeros((3,), jnp.float32)
    options = loops.Options(
        steps=steps, controller=joint.problem.controller, estimator=joint.options_estimator
    )
    rows = []
    for name, closed in loops_by_name.items():

        def terms(spec, closed=closed):
            _, _, (poses, _, _) = loop.disturbed_run(
                spec, closed.params, init, robot, jnp.float32(dt), options,
                estimate=closed.estimator, record=True,
            )  # fmt: skip
            return loss.recorded_arrival(poses, spec.ref, dt), poses

        batch = jax.jit(jax.vmap(terms, in_axes=(disturbances.Disturbance(0, 0, 0, 0),)))
        for label, sxy, sdeg, latency in disturbances.STANDARD_CONDITIONS:
            if sxy:
                sxy, sdeg = config.noise
            spec = disturbances.sample_disturbance(
                jax.random.key(5), refs, steps, noise_xy=sxy, noise_theta=math.radians(sdeg),
                latency=float(latency), radius_mismatch=disturbances.STANDARD_MISMATCH,
            )  # fmt: skip
            surrogate, poses = batch(spec)
            starts = jnp.broadcast_to(init, (poses.shape[0], 1, 3))
            trajectory = types.SimpleNamespace(poses=jnp.concatenate([starts, poses], axis=1))
            arrival = np.asarray(w.arrival_time(trajectory, refs, dt=dt))
            arrived = np.isfinite(arrival)
            row = {
                "loop": name, "condition": label, "surrogate s": float(jnp.mean(surrogate)),
                "success": float(arrived.mean()), "mean arrival s": float(arrival[arrived].mean()),
            }  # fmt: skip
            rows.append(row)
    print(json.dumps({"seed": args.seed, "candidates": args.candidates, "rows": rows}, indent=1))
    print("| loop | condition | surrogate term (s) | success | mean arrival (s) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['loop']} | {r['condition']} | {r['surrogate s']:.3f} | "
            f"{100 * r['success']:.1f} % | {r['mean arrival s']:.3f} |"
        )


if __name__ == "__main__":
    main()
