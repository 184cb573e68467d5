"""What the robust loss's gradient costs with the law's Jacobian against JAX's own derivative.

Times, in one process confined to one core (``search.one_core``), the robust
loss of ``tune --robust`` (``RobustLoss``: per-run gradients, capped mean) at
its start, and its forward pass (``robust_loss_value``), with the law's
derivative ``"traced"`` (JAX differentiates the law's operations, the
default) and ``"jacobian"`` (``loops.Options.law_derivative``: the law's
Jacobian in the pose formed once per step), for each estimator asked for.
Calls are interleaved round by round so that load falls on all alike;
process CPU time, medians. It also checks that both give the same loss and
the same gradient. docs/robustness.md ("Which tuner to use") quotes it.

Usage: ``python experiments/law_derivative.py [--poses 256] [--steps 182]
[--rounds 7] [--estimators ekf observer none] [--json FILE]``
"""

import argparse
import json
import statistics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=256, help="poses per condition")
    parser.add_argument("--steps", type=int, default=182)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--estimators", nargs="+", default=["ekf", "observer", "none"])
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()

    from wmr_jax._src.tuning import search

    confined = search.one_core()

    import jax
    import jax.numpy as jnp
    import numpy as np

    import wmr_jax as w
    from wmr_jax._src.sim import loops
    from wmr_jax._src.studies.bench import TUNING_TEMPERATURE
    from wmr_jax._src.tuning import robust

    robot, dt = w.Robot(), jnp.asarray(w.DEFAULT_DT, jnp.float32)
    refs = jnp.asarray(w.sample_poses(0, args.poses, dtype=np.float32))
    accel = loops.for_robot(loops.Options(), robot, dt).accel_limit
    batch = (jax.random.key(0), refs, refs[: max(args.poses // 4, 1)])
    temperature = jnp.asarray(TUNING_TEMPERATURE, jnp.float32)
    calls, values = {}, {}
    for name in args.estimators:
        config = robust.RobustConfig(estimator=None if name == "none" else name)
        joint = robust.joint_problem(config)
        z = jnp.asarray(joint.start_logits(robot), jnp.float32)

        def forward(z, joint=joint):
            return robust.robust_loss_value(
                z, *batch, temperature, robot, dt, args.steps, joint, accel, None
            )

        calls[name, "forward"] = jax.jit(forward), z
        for derivative in ("traced", "jacobian"):
            loss = robust.RobustLoss(args.steps, joint, accel, None, derivative)
            gradient = jax.jit(lambda z, loss=loss: loss(z, batch, temperature, (robot, dt)))
            calls[name, derivative] = gradient, z
    for key, (fn, z) in calls.items():
        values[key] = jax.block_until_ready(fn(z))  # compiled before any timing
    times: dict = {key: [] for key in calls}
    for _ in range(args.rounds):
        for key, (fn, z) in calls.items():
            began = search.clock()
            jax.block_until_ready(fn(z))
            times[key].append(search.clock() - began)
    rows = []
    for name in args.estimators:
        median = {
            part: statistics.median(times[name, part]) for part in ("forward", "traced", "jacobian")
        }
        (loss_t, grad_t), (loss_j, grad_j) = values[name, "traced"], values[name, "jacobian"]
        rows.append(
            {
                "estimator": name,
                "forward_s": median["forward"],
                "traced_gradient_s": median["traced"],
                "jacobian_gradient_s": median["jacobian"],
                "traced_over_forward": median["traced"] / median["forward"],
                "jacobian_over_forward": median["jacobian"] / median["forward"],
                "speed_up": median["traced"] / median["jacobian"],
                "loss_difference": float(abs(loss_t - loss_j)),
                "gradient_difference": float(jnp.max(jnp.abs(grad_t - grad_j))),
                "largest_gradient": float(jnp.max(jnp.abs(grad_t))),
            }
        )
    print(f"{args.poses} poses per condition, {args.steps} steps, float32, one core: {confined}")
    print("| estimator | forward ms | gradient, traced | gradient, Jacobian | traced ÷ Jacobian |")
    print("|---|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['estimator']} | {1e3 * r['forward_s']:.1f} | "
            f"{1e3 * r['traced_gradient_s']:.0f} ms ({r['traced_over_forward']:.1f}×) | "
            f"{1e3 * r['jacobian_gradient_s']:.0f} ms ({r['jacobian_over_forward']:.1f}×) | "
            f"{r['speed_up']:.2f}× |"
        )
    for r in rows:
        print(
            f"{r['estimator']}: the two gradients differ by at most {r['gradient_difference']:.2g} "
            f"(largest entry {r['largest_gradient']:.3g}), the losses by {r['loss_difference']:.2g}"
        )
    if args.json:
        meta = {"poses": args.poses, "steps": args.steps, "rounds": args.rounds}
        with open(args.json, "w") as f:
            json.dump({"settings": {**meta, "one_core": confined}, "rows": rows}, f, indent=2)
            f.write("\n")


if __name__ == "__main__":
    main()
