"""What one gradient of the tuning loss costs: wall time and XLA's peak memory."""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src.checks import as_float_tree, check_int, float_dtype
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.poses import sample_poses
from wmr_jax._src.tuning.loss import batch_loss, make_spec, robust_value_and_grad
from wmr_jax._src.tuning.parametrisation import (
    PAPER_FEASIBLE_GAINS,
    gains_from_logits,
    logits_from_gains,
)


class GradientCost(NamedTuple):
    """Measured cost of one loss gradient against the forward pass.

    Attributes:
        poses: batch size.
        steps: control periods per run.
        remat: whether the scan body was checkpointed.
        forward_s: wall time of the jitted loss (fastest of the repeats), s.
        gradient_s: wall time of the jitted robust gradient (fastest), s.
        forward_peak_bytes: XLA's peak memory estimate of the loss.
        gradient_peak_bytes: XLA's peak memory estimate of the gradient.
    """

    poses: int
    steps: int
    remat: bool
    forward_s: float
    gradient_s: float
    forward_peak_bytes: int
    gradient_peak_bytes: int


def _fastest(function: Any, args: tuple, repeats: int) -> tuple[float, int]:
    """Compile ``function``; return (fastest of ``repeats`` timed calls s, peak bytes)."""
    compiled = jax.jit(function).lower(*args).compile()
    # Arguments, outputs and temporaries: XLA's own ``peak_memory_in_bytes``
    # leaves the temporaries out on the CPU.
    stats = compiled.memory_analysis()
    peak = int(
        stats.argument_size_in_bytes
        + stats.output_size_in_bytes
        + stats.temp_size_in_bytes
        - stats.alias_size_in_bytes
    )
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - began)
    # On a shared machine the slower repeats measure the neighbours too.
    return min(times), peak


def gradient_cost(
    *,
    poses: int = 4096,
    steps: int = loops.DEFAULT_STEPS,
    remat: bool = True,
    velocity: str = "ideal",
    temperature: float = 0.05,
    repeats: int = 5,
    seed: int = 0,
) -> GradientCost:
    """Time the loss and its gradient on ``poses`` × ``steps``; read XLA's peak memory of each.

    Args:
        poses: batch size.
        steps: control periods per run.
        remat: ``jax.checkpoint`` on the scan body.
        velocity: ``"ideal"`` or ``"nonideal"``.
        temperature: smooth-law temperature.
        repeats: timed calls after a warm-up; the fastest is reported.
        seed: seed of the reference poses.

    Raises:
        ValueError: for a bad count or option, naming it.
    """
    poses = check_int("poses", poses, 1)
    steps = check_int("steps", steps, 1)
    repeats = check_int("repeats", repeats, 1)
    dt = simulation.DEFAULT_DT
    spec = make_spec(horizon=steps * dt, dt=dt, velocity=velocity, remat=remat)
    dtype = float_dtype()
    robot = as_float_tree(Robot())
    refs = sample_poses(jax.random.key(seed), poses)
    init = jnp.zeros((3,), dtype)
    z = jnp.asarray(logits_from_gains(PAPER_FEASIBLE_GAINS), dtype)
    args = (z, refs, init, robot, jnp.asarray(dt, dtype), jnp.asarray(temperature, dtype))

    def forward(z, refs, init, robot, dt, temperature):
        gains = gains_from_logits(z, robot)
        return batch_loss(refs, gains, init, robot, dt, spec, temperature)

    def gradient(z, refs, init, robot, dt, temperature):
        return robust_value_and_grad(z, refs, init, robot, dt, spec, temperature, 1.0)[:2]

    forward_s, forward_peak = _fastest(forward, args, repeats)
    gradient_s, gradient_peak = _fastest(gradient, args, repeats)
    return GradientCost(
        poses, steps, bool(remat), forward_s, gradient_s, forward_peak, gradient_peak
    )


def write_gradient_costs(out: Any) -> list[GradientCost]:
    """Measure ``gradient_cost`` with and without remat; write ``out/gradient_cost.json``."""
    from wmr_jax._src import io

    costs = [gradient_cost(remat=remat) for remat in (True, False)]
    io.atomic_write_json(out / "gradient_cost.json", [c._asdict() for c in costs])
    return costs
