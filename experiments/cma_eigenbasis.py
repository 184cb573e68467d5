"""Why CMA-ES's runs differ between machines: the eigenbasis its sampler draws in.

evosax's CMA-ES draws each generation as ``mean + σ · B · D · z`` from the
eigendecomposition ``C = B D² Bᵀ`` of its covariance (``jnp.linalg.eigh``:
LAPACK's ``dsyevd``, from the OpenBLAS that SciPy ships). ``C`` starts as
the identity and each generation adds a low-rank update, so for many
generations several eigenvalues are equal; within such an eigenspace every
orthonormal basis is a right answer, and OpenBLAS's kernels (chosen for
the CPU at run time, or by ``OPENBLAS_CORETYPE``) return different ones.
The candidates ``B · D · z`` then differ entirely, as if the run had another
seed. Drawing with the symmetric root instead, ``B · D · Bᵀ · z`` (the same
distribution, since ``Bᵀ z`` is again standard normal), gives the same
candidates for any basis, up to rounding. wmr_jax's own CMA-ES (``xla``:
``wmr_jax._src.tuning.cma``) takes ``B`` and ``D`` from a Jacobi method in
XLA's operations instead of LAPACK, and so the same bits on every kernel.

For each kernel named on the command line (default: Haswell, and SkylakeX
where the CPU has AVX-512; Sandybridge) and each sampler, this runs 400
generations of 8 on a 38-dimensional test function in a fresh process and
prints how many distinct eigenvalues ``C`` has after the first generation, the
objective at the final mean, and how far that mean lies from the first
kernel's with the same sampler (largest coordinate difference).

With ``--comparison SEED`` it runs one seed of ``wmr-jax tune --robust
--compare --price 5`` instead (``compare_seed``, one core; two minutes
each on a fast 2-core machine) and prints each method's judged score, and how far CMA-ES's
candidates lie from the first kernel's run generation by generation:
whether the symmetric root makes CMA-ES's row the same for every kernel in
the comparison itself, and if not, where the runs part.

Usage: ``python experiments/cma_eigenbasis.py [--comparison SEED] [KERNEL ...]``
"""

import json
import os
import subprocess
import sys
import tempfile

DIM, POPULATION, GENERATIONS = 38, 8, 400
SAMPLERS = ("evosax", "symmetric", "xla")


def run(sampler: str) -> str:
    import jax
    import jax.numpy as jnp
    import numpy as np

    jax.config.update("jax_enable_x64", True)

    def objective(x):
        ripples = jnp.sum(x**2 - 3.0 * jnp.cos(2.0 * jnp.pi * x), axis=-1)
        return ripples + jnp.sum((x[..., :-1] - x[..., 1:]) ** 2, axis=-1)

    strategy = sampler_class(sampler)(population_size=POPULATION, solution=jnp.zeros(DIM))
    params = strategy.default_params
    state = strategy.init(jax.random.key(0), jnp.zeros(DIM), params)
    ask, tell = jax.jit(strategy.ask), jax.jit(strategy.tell)
    distinct = None
    for generation in range(GENERATIONS):
        ask_key, tell_key = jax.random.split(jax.random.fold_in(jax.random.key(1), generation))
        x, state = ask(ask_key, state, params)
        state, _ = tell(tell_key, x, objective(x), state, params)
        if generation == 0:
            distinct = len(np.unique(np.round(np.linalg.eigvalsh(np.asarray(state.C)), 12)))
    mean = np.asarray(state.mean)
    return json.dumps(
        {"distinct": distinct, "objective": float(objective(mean)), "mean": mean.tolist()}
    )


def comparison(sampler: str, seed: int, record: str) -> str:
    import numpy as np

    import wmr_jax._src.tuning.search as search
    from wmr_jax import Robot
    from wmr_jax._src.tuning.robust import RobustConfig, condition_score
    from wmr_jax._src.tuning.robust_run import compare_seed

    search.one_core()  # as `tune --compare` runs, before JAX starts
    populations = []
    strategy = recorded(sampler_class(sampler), populations)
    search._evosax_cma_es = lambda: strategy
    rows = compare_seed(RobustConfig(price=5.0), seed, Robot())
    np.save(record, np.stack(populations))
    scores = {}
    for row in rows:
        scores.setdefault(row["method"], []).append(condition_score(row))
    return json.dumps({m: float(np.mean(v)) for m, v in scores.items()})


def sampler_class(sampler: str):
    """evosax's CMA-ES (``evosax``), drawing with ``B D Bᵀ z`` (``symmetric``), or wmr_jax's."""
    from evosax.algorithms import CMA_ES

    from wmr_jax._src.tuning import cma

    return {"evosax": CMA_ES, "symmetric": symmetric_root(), "xla": cma.cma_es_class()}[sampler]


def recorded(strategy, populations: list):
    """``strategy`` appending each generation's candidates to ``populations``."""
    import jax
    import numpy as np

    class Recorded(strategy):
        def _ask(self, key, state, params):
            population, state = super()._ask(key, state, params)
            jax.debug.callback(lambda p: populations.append(np.asarray(p)), population)
            return population, state

    return Recorded


def symmetric_root():
    """evosax's CMA-ES drawing with ``B D Bᵀ z``."""
    import jax
    from evosax.algorithms import CMA_ES
    from evosax.algorithms.distribution_based.cma_es import eigen_decomposition

    class SymmetricRoot(CMA_ES):
        def _ask(self, key, state, params):
            C, B, D = eigen_decomposition(state.C)
            z = jax.random.normal(key, (self.population_size, self.num_dims))
            return state.mean + state.std * (((z @ B) * D) @ B.T), state.replace(C=C, B=B, D=D)

    return SymmetricRoot


def child(kernel: str, *args: str) -> dict:
    """The output of this script run as ``--child ARGS`` with ``kernel``, in a fresh process."""
    done = subprocess.run(
        [sys.executable, __file__, "--child", *args],
        env={**os.environ, "OPENBLAS_CORETYPE": kernel},
        capture_output=True, text=True,
    )  # fmt: skip
    if done.returncode:
        sys.exit(f"OPENBLAS_CORETYPE={kernel} {' '.join(args)} failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def parting(populations, first) -> str:
    """How far two runs' candidates lie apart, generation by generation (numbered from 1)."""
    import numpy as np

    n = min(len(populations), len(first))
    gap = np.abs(populations[:n] - first[:n]).max(axis=(1, 2))
    if gap.max() <= 1e-3:
        return f"at most {gap.max():.1e} apart in every generation"
    parted = int(np.argmax(gap > 1e-3))
    close = f"at most {gap[:parted].max():.1e} apart up to generation {parted}, " if parted else ""
    return f"{close}{gap[parted]:.2f} apart at generation {parted + 1}"


def main(kernels: list[str], seed: int | None) -> None:
    if not kernels:
        with open("/proc/cpuinfo", encoding="utf-8") as cpu:
            avx512 = " avx512f" in cpu.read()
        kernels = ["Haswell", *(["SkylakeX"] if avx512 else []), "Sandybridge"]
    if seed is not None:
        import numpy as np

        print(f"seed {seed}: judged score (s); CMA-ES's candidates against the first kernel's")
        with tempfile.TemporaryDirectory() as folder:
            for sampler in SAMPLERS:
                first = None
                for kernel in kernels:
                    record = os.path.join(folder, f"{sampler}-{kernel}.npy")
                    scores = child(kernel, sampler, str(seed), record)
                    text = ", ".join(f"{m} {v:.5f}" for m, v in scores.items())
                    populations = np.load(record)
                    first = populations if first is None else first
                    print(f"{kernel:12} {sampler:10} {text}; {parting(populations, first)}")
        return
    print(
        "kernel       sampler    distinct eigenvalues  objective at the end  from the first kernel"
    )
    first = {}
    for kernel in kernels:
        for sampler in SAMPLERS:
            out = child(kernel, sampler)
            mean = first.setdefault(sampler, out["mean"])
            apart = max(abs(a - b) for a, b in zip(out["mean"], mean, strict=True))
            print(
                f"{kernel:12} {sampler:10} {out['distinct']:2d} of {DIM}"
                f"              {out['objective']:16.10f}  {apart:.1e}"
            )


if __name__ == "__main__":
    argv = sys.argv[1:]
    if argv[:1] == ["--child"]:
        print(run(argv[1]) if len(argv) == 2 else comparison(argv[1], int(argv[2]), argv[3]))
    elif argv[:1] == ["--comparison"]:
        if len(argv) < 2 or not argv[1].isdigit():
            sys.exit("usage: python experiments/cma_eigenbasis.py --comparison SEED [KERNEL ...]")
        main(argv[2:], int(argv[1]))
    else:
        main(argv, None)
