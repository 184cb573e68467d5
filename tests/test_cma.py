"""CMA-ES's eigenbasis from XLA alone (``tuning/cma.py``), against NumPy's LAPACK."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wmr_jax._src.tuning import cma


def _spd(rng, n, spread):
    """A symmetric positive-definite ``(n, n)`` with eigenvalues spread over ``spread`` decades."""
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    values = np.logspace(0.0, spread, n)
    return (q * values) @ q.T


@pytest.mark.parametrize("n", [1, 2, 3, 8, 13])
@pytest.mark.parametrize(("dtype", "tol"), [(np.float64, 1e-12), (np.float32, 2e-5)])
def test_jacobi_eigh_is_the_eigendecomposition(n, dtype, tol):
    rng = np.random.default_rng(n)
    a = _spd(rng, n, 4.0).astype(dtype)
    with jax.enable_x64(dtype == np.float64):
        values, vectors, _ = cma.jacobi_eigh(jnp.asarray(a), jnp.eye(n, dtype=dtype))
    values, vectors = np.asarray(values, np.float64), np.asarray(vectors, np.float64)
    assert values.dtype == vectors.dtype and vectors.shape == (n, n)
    top = np.linalg.eigvalsh(a.astype(np.float64)).max()
    np.testing.assert_allclose(
        np.sort(values), np.linalg.eigvalsh(a.astype(np.float64)), atol=tol * top
    )
    np.testing.assert_allclose(vectors.T @ vectors, np.eye(n), atol=tol * 10)
    np.testing.assert_allclose(vectors @ np.diag(values) @ vectors.T, a, atol=tol * top)
    # Each column is an eigenvector: A v = λ v.
    np.testing.assert_allclose(a @ vectors, vectors * values, atol=tol * top * 10)


def test_a_start_that_diagonalises_is_kept_bit_for_bit():
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((5, 5)))
    diagonal = np.array([3.0, 1.0, 4.0, 1.5, 9.0])
    with jax.enable_x64(True):
        values, vectors, sweeps = cma.jacobi_eigh(jnp.diag(jnp.asarray(diagonal)), jnp.eye(5))
        np.testing.assert_array_equal(values, diagonal)  # already diagonal: nothing rotates
        np.testing.assert_array_equal(vectors, np.eye(5))
        assert int(sweeps) == 1
        # From a nearby matrix's basis the method ends where it began, up to rounding.
        a = (q * diagonal) @ q.T
        values, vectors, _ = cma.jacobi_eigh(jnp.asarray(a), jnp.asarray(q))
    np.testing.assert_allclose(values, diagonal, rtol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(vectors * q, axis=0)), np.ones(5), atol=1e-12)


def test_a_nearby_matrix_s_basis_converges_in_a_few_sweeps():
    # The reason CMA-ES starts each generation from the last one's basis.
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((13, 13)))
    a = (q * np.logspace(0.0, 4.0, 13)) @ q.T
    x = rng.standard_normal(13)
    with jax.enable_x64(True):
        _, basis, cold = cma.jacobi_eigh(jnp.asarray(a), jnp.eye(13))
        values, _, warm = cma.jacobi_eigh(jnp.asarray(a + 1e-3 * np.outer(x, x)), basis)
    assert 4 <= int(cold) <= 12 and int(warm) <= 5, (int(cold), int(warm))
    np.testing.assert_allclose(
        np.sort(np.asarray(values)), np.linalg.eigvalsh(a + 1e-3 * np.outer(x, x)), rtol=1e-12
    )


def test_repeated_and_zero_eigenvalues():
    with jax.enable_x64(True):
        values, vectors, _ = cma.jacobi_eigh(jnp.ones((4, 4)), jnp.eye(4))
    np.testing.assert_allclose(np.sort(np.asarray(values)), [0.0, 0.0, 0.0, 4.0], atol=1e-14)
    np.testing.assert_allclose(np.asarray(vectors).T @ np.asarray(vectors), np.eye(4), atol=1e-14)


def test_round_robin_pairs_every_index_once_with_disjoint_rounds():
    for m in (2, 4, 8, 14):
        p, q = cma._round_robin(m)
        assert p.shape == q.shape == (m - 1, m // 2)
        for row_p, row_q in zip(p, q, strict=True):
            assert sorted([*row_p, *row_q]) == list(range(m))  # disjoint: each index once
        pairs = {frozenset(pair) for pair in zip(p.ravel(), q.ravel(), strict=True)}
        assert len(pairs) == m * (m - 1) // 2  # every pair, none twice


def _primitives(jaxpr):
    for eqn in jaxpr.eqns:
        yield eqn.primitive.name
        for value in eqn.params.values():
            for sub in value if isinstance(value, (list, tuple)) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    yield from _primitives(inner)


def test_cma_es_asks_without_lapack_and_samples_its_covariance():
    evosax = pytest.importorskip("evosax.algorithms")
    cls = cma.cma_es_class()
    assert issubclass(cls, evosax.CMA_ES) and cma.cma_es_class() is cls
    with jax.enable_x64(True):
        strategy = cls(population_size=20_000, solution=jnp.zeros(3))
        params = strategy.default_params
        state = strategy.init(jax.random.key(0), jnp.array([1.0, -2.0, 0.5]), params)
        covariance = jnp.asarray(_spd(np.random.default_rng(1), 3, 1.0))
        state = state.replace(C=covariance, std=jnp.asarray(0.5))
        ask = jax.make_jaxpr(lambda key, state: strategy._ask(key, state, params))
        names = set(_primitives(ask(jax.random.key(1), state).jaxpr))
        assert "eigh" not in names and "while" in names  # the Jacobi loop, not LAPACK's
        # evosax's own ask calls LAPACK: the check above can fail.
        base = evosax.CMA_ES(population_size=4, solution=jnp.zeros(3))
        base_ask = jax.make_jaxpr(lambda key, state: base._ask(key, state, params))
        assert "eigh" in set(_primitives(base_ask(jax.random.key(1), state).jaxpr))
        population, asked = strategy.ask(jax.random.key(2), state, params)
    population = np.asarray(population)
    np.testing.assert_allclose(population.mean(axis=0), [1.0, -2.0, 0.5], atol=0.05)
    np.testing.assert_allclose(
        np.cov(population.T), 0.25 * np.asarray(covariance), rtol=0.05, atol=0.01
    )
    # The basis it keeps diagonalises the covariance it sampled.
    b, d = np.asarray(asked.B), np.asarray(asked.D)
    np.testing.assert_allclose(b @ np.diag(d**2) @ b.T, np.asarray(asked.C), atol=1e-12)
    # A covariance gone astray is conditioned as evosax's own eigendecomposition
    # conditions it (symmetric, diagonal at least 0, entries at most 1e8), with its D.
    from evosax.algorithms.distribution_based.cma_es import eigen_decomposition

    with jax.enable_x64(True):
        state = state.replace(C=covariance.at[0, 0].set(-1.0).at[1, 2].set(6e8))
        _, asked = strategy.ask(jax.random.key(2), state, params)
        conditioned, _, d_evosax = eigen_decomposition(state.C)
    np.testing.assert_array_equal(asked.C, conditioned)
    np.testing.assert_allclose(np.sort(asked.D), np.sort(np.asarray(d_evosax)), rtol=1e-12)


def test_one_sweep_diagonalises_two_by_two(monkeypatch):
    # One rotation zeroes a 2 x 2's off-diagonal exactly (up to rounding).
    monkeypatch.setattr(cma, "MAX_SWEEPS", 1)
    with jax.enable_x64(True):
        a = jnp.array([[2.0, 0.7], [0.7, -1.0]])
        values, vectors, _ = cma.jacobi_eigh(a, jnp.eye(2))
    np.testing.assert_allclose(
        np.sort(np.asarray(values)), np.linalg.eigvalsh(np.asarray(a)), atol=1e-15
    )
    np.testing.assert_allclose(
        np.asarray(vectors) @ np.diag(values) @ np.asarray(vectors).T, a, atol=1e-15
    )
