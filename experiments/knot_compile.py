"""How the compilation of a gain table's gradient grows with its knots.

Three tables of K knots, each evaluated by ``schedule.table_at`` (the
first knot plus each increment times its ramp, knot by knot) at 136 radii
in every step of a 182-step scan, and the gradient of the scan's result
with respect to every knot; beside it the same sum written as one vector
operation over the knots. Prints the CPU seconds XLA takes to compile each.

Usage: ``python experiments/knot_compile.py [K ...]`` (default 10 31 60).
"""

import sys
import time

import jax
import jax.numpy as jnp

from wmr_jax._src.model.controllers.schedule import knot_radii, table_at

TABLES, STEPS, RADII = 3, 182, 136


def vector_table(values: jax.Array, r: jax.Array, radii) -> jax.Array:
    """``table_at``'s sum as one operation over the knots (rounded otherwise)."""
    ramp = jnp.clip((r[..., None] - radii[:-1]) / (radii[1:] - radii[:-1]), 0.0, 1.0)
    return values[0] + jnp.sum((values[1:] - values[:-1]) * ramp, axis=-1)


def compile_seconds(knots: int, table) -> float:
    radii = knot_radii(knots)

    def loss(tables, r0):
        def body(r, _):
            gain = sum(table(values, r, radii) for values in tables)
            return 0.99 * r + 0.01 * gain, None

        return jnp.sum(jax.lax.scan(body, r0, None, length=STEPS)[0])

    values = jnp.linspace(1.0, 2.0, knots)
    tables = [values * (t + 1) for t in range(TABLES)]
    if table is table_at:  # its knots are separate scalars, as a schedule's are
        tables = [tuple(values) for values in tables]
    lowered = jax.jit(jax.grad(loss)).lower(tables, jnp.linspace(0.0, 100.0, RADII))
    start = time.process_time()
    lowered.compile()
    return time.process_time() - start


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    for knots in [int(k) for k in sys.argv[1:]] or [10, 31, 60]:
        print(
            f"{knots} knots: knot by knot {compile_seconds(knots, table_at):.2f} CPU s, "
            f"one vector operation {compile_seconds(knots, vector_table):.2f} CPU s",
            flush=True,
        )
