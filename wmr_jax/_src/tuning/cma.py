"""CMA-ES whose samples do not depend on the machine's LAPACK: its eigenbasis by XLA alone.

evosax draws ``mean + σ · B · D · z`` with ``B``, ``D²`` from ``jnp.linalg.eigh``
of the covariance: LAPACK on the CPU, whose last bits follow the machine's BLAS
kernels, and CMA-ES's ranking amplifies them until two machines' searches part
(docs/robustness.md, "On a second machine"). Here a cyclic Jacobi method in
JAX operations gives ``B`` and ``D``, started from the previous generation's basis.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

MAX_SWEEPS = 30  # from a near-diagonal start a sweep without rotation comes after about 3


@functools.cache
def _round_robin(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(p, q)``, each ``(m - 1, m // 2)``: all of ``m`` (even), each round disjoint."""
    others = list(range(1, m))
    p, q = [], []
    for r in range(m - 1):
        line = [0, *others[r:], *others[:r]]
        p.append(line[: m // 2])
        q.append(line[::-1][: m // 2])
    return np.asarray(p, np.int32), np.asarray(q, np.int32)


def jacobi_eigh(a: jax.Array, start: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eigenvalues ``(n,)``, unsorted, orthonormal eigenvectors (columns) of ``a``, and sweeps.

    Cyclic Jacobi on symmetric ``a`` in round-robin order from the orthogonal
    basis ``start``; a rotation is skipped where ``|a_pq| ≤ ε √|a_pp a_qq|``,
    and the method ends after a sweep that skips them all, or after ``MAX_SWEEPS``.
    """
    n = a.shape[0]
    m = n + n % 2  # an odd size gets a decoupled extra index, never rotated
    a = start.T @ a @ start
    if m > n:
        a = jnp.pad(a, ((0, 1), (0, 1))).at[n, n].set(1.0)
        start = jnp.pad(start, ((0, 1), (0, 1))).at[n, n].set(1.0)
    rounds_p, rounds_q = (jnp.asarray(index) for index in _round_robin(m))
    eps = jnp.finfo(a.dtype).eps

    def round_(r: Any, carry: tuple) -> tuple:
        a, basis, still = carry
        p, q = rounds_p[r], rounds_q[r]
        app, aqq, apq = a[p, p], a[q, q], a[p, q]
        skip = jnp.abs(apq) <= eps * jnp.sqrt(jnp.abs(app * aqq))
        # The rotation that zeroes a_pq (Golub & Van Loan, Algorithm 8.5.1).
        tau = (aqq - app) / (2.0 * jnp.where(skip, 1.0, apq))
        t = jnp.where(tau >= 0, 1.0, -1.0) / (jnp.abs(tau) + jnp.sqrt(1.0 + tau * tau))
        t = jnp.where(skip, 0.0, t)
        c = 1.0 / jnp.sqrt(1.0 + t * t)
        s = t * c
        rows_p, rows_q = a[p], a[q]
        a = a.at[p].set(c[:, None] * rows_p - s[:, None] * rows_q)
        a = a.at[q].set(s[:, None] * rows_p + c[:, None] * rows_q)
        cols_p, cols_q = a[:, p], a[:, q]
        a = a.at[:, p].set(c * cols_p - s * cols_q).at[:, q].set(s * cols_p + c * cols_q)
        vecs_p, vecs_q = basis[:, p], basis[:, q]
        basis = basis.at[:, p].set(c * vecs_p - s * vecs_q).at[:, q].set(s * vecs_p + c * vecs_q)
        return a, basis, still & jnp.all(skip)

    def sweep(carry: tuple) -> tuple:
        a, basis, sweeps, _ = carry
        a, basis, still = jax.lax.fori_loop(0, m - 1, round_, (a, basis, jnp.bool_(True)))
        return a, basis, sweeps + 1, still

    def going(carry: tuple) -> jax.Array:
        _, _, sweeps, still = carry
        return (sweeps < MAX_SWEEPS) & ~still

    a, basis, sweeps, _ = jax.lax.while_loop(going, sweep, (a, start, 0, jnp.bool_(False)))
    return jnp.diag(a)[:n], basis[:n, :n], sweeps


def cma_es_class() -> type:
    """evosax's ``CMA_ES`` with its eigenbasis from ``jacobi_eigh``; raises ``ImportError``."""
    from evosax.algorithms import CMA_ES

    return _with_xla_eigenbasis(CMA_ES)


@functools.cache
def _with_xla_eigenbasis(base: type) -> type:
    """One subclass per class: evosax compiles its methods per strategy (``search._strategy``)."""

    class XlaCMAES(base):
        """evosax's CMA-ES, its ``ask`` the same but for the eigendecomposition."""

        def _ask(self, key: jax.Array, state: Any, params: Any) -> tuple[jax.Array, Any]:
            # The covariance conditioned as evosax's eigen_decomposition does.
            c = (state.C + state.C.T) / 2
            diagonal = jnp.diag_indices_from(c)
            c = c.at[diagonal].set(jnp.maximum(c[diagonal], 0.0))
            c = jnp.minimum(c, 1e8) + 1e-8 * jnp.eye(c.shape[0], dtype=c.dtype)
            d_squared, b, _ = jacobi_eigh(c, state.B)
            d = jnp.sqrt(jnp.maximum(d_squared, 1e-8))
            z = jax.random.normal(key, (self.population_size, self.num_dims))
            population = state.mean + state.std * ((z @ jnp.diag(d).T) @ b.T)  # evosax's
            return population, state.replace(C=c, B=b, D=d)

    return XlaCMAES
