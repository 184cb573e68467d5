"""What one gradient of the tuning loss costs, with and without ``jax.checkpoint``.

Times the tuner's loss (the fixed gains at the paper's feasible values, the
smooth law at temperature 0.05) and its robust batch gradient on
``--poses`` × ``--steps``, fastest of ``--repeats`` wall-clock calls after a
warm-up, and reads XLA's peak memory of each compiled program, once with
the scan body checkpointed (``remat=True``, the tuner's default) and once
storing every step's intermediates. docs/tuning.md ("What the gradient
costs") quotes it; ``wmr-jax bench --cases grad_tuning_loss`` times the same
gradient against its forward pass at other sizes.

Usage: ``python experiments/gradient_cost.py [--poses 4096] [--steps 150]
[--repeats 5] [--json FILE]``
"""

import argparse
import json
import time


def peak_bytes(compiled) -> int:
    """Arguments, outputs and temporaries of a compiled program (XLA's own
    ``peak_memory_in_bytes`` leaves the temporaries out on the CPU)."""
    stats = compiled.memory_analysis()
    return int(
        stats.argument_size_in_bytes
        + stats.output_size_in_bytes
        + stats.temp_size_in_bytes
        - stats.alias_size_in_bytes
    )


def programs(poses: int, steps: int, remat: bool, seed: int = 0) -> dict:
    """The loss and its gradient compiled for ``poses`` × ``steps``, with their arguments."""
    import jax
    import jax.numpy as jnp

    from wmr_jax import Robot, sample_poses
    from wmr_jax._src.checks import as_float_tree, float_dtype
    from wmr_jax._src.sim.rollout import DEFAULT_DT as dt
    from wmr_jax._src.tuning.loss import batch_loss, make_spec, robust_value_and_grad
    from wmr_jax._src.tuning.parametrisation import (
        PAPER_FEASIBLE_GAINS,
        gains_from_logits,
        logits_from_gains,
    )

    spec = make_spec(horizon=steps * dt, dt=dt, remat=remat)
    dtype = float_dtype()
    robot = as_float_tree(Robot())
    z = jnp.asarray(logits_from_gains(PAPER_FEASIBLE_GAINS), dtype)
    refs = sample_poses(jax.random.key(seed), poses)
    args = (
        z,
        refs,
        jnp.zeros((3,), dtype),
        robot,
        jnp.asarray(dt, dtype),
        jnp.asarray(0.05, dtype),
    )

    def forward(z, refs, init, robot, dt, temperature):
        gains = gains_from_logits(z, robot)
        return batch_loss(refs, gains, init, robot, dt, spec, temperature)

    def gradient(z, refs, init, robot, dt, temperature):
        return robust_value_and_grad(z, refs, init, robot, dt, spec, temperature, 1.0)[:2]

    return {
        name: jax.jit(function).lower(*args).compile()
        for name, function in (("forward", forward), ("gradient", gradient))
    }, args


def fastest(compiled, args, repeats: int) -> float:
    """The fastest of ``repeats`` calls after one warm-up, s (the slower ones measure the
    neighbours too on a shared machine)."""
    import jax

    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - began)
    return min(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=4096, help="batch size (default 4096)")
    parser.add_argument("--steps", type=int, default=150, help="control periods (default 150)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls, fastest kept")
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args(argv)
    rows = []
    for remat in (True, False):
        compiled, call_args = programs(args.poses, args.steps, remat)
        row = {"poses": args.poses, "steps": args.steps, "remat": remat}
        for name, program in compiled.items():
            row[f"{name}_s"] = fastest(program, call_args, args.repeats)
            row[f"{name}_peak_bytes"] = peak_bytes(program)
        rows.append(row)
        print(
            f"{args.poses} poses x {args.steps} steps, remat={remat}: forward "
            f"{row['forward_s'] * 1e3:.3g} ms, gradient {row['gradient_s'] * 1e3:.3g} ms "
            f"({row['gradient_s'] / row['forward_s']:.1f}x); peak memory forward "
            f"{row['forward_peak_bytes'] / 2**20:.3g} MiB, gradient "
            f"{row['gradient_peak_bytes'] / 2**20:.3g} MiB"
        )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
