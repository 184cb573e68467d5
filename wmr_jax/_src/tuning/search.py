"""The black-box searches, the baselines the gradient must beat: random search and CMA-ES.

``search_loop`` drives every search (``robust.black_box``'s too); every budget
is process CPU time (``clock``), the gradient tuner's included.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import os
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    as_poses,
    check_callable,
    check_int,
    check_key,
    check_number,
    float_dtype,
)
from wmr_jax._src.model.params import Gains, Robot, validate_one_robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.poses import MAX_SAMPLES
from wmr_jax._src.tuning import cma
from wmr_jax._src.tuning.evaluation import check_run, hard_runs, quiet_scoring, run_options
from wmr_jax._src.tuning.parametrisation import PAPER_FEASIBLE_GAINS, unit_from_gains
from wmr_jax._src.tuning.problems import FIXED, Problem, get_problem

# Random search scores a run that never arrives as twice the horizon: worse
# than any arrival, but finite, so that candidates' means stay comparable.
FAILURE_FACTOR = 2.0


class SearchResult(NamedTuple):
    """Outcome of ``random_search``.

    Attributes:
        gains: the best candidate found.
        score: its mean arrival time on the search poses, failures counted as
            twice the horizon, s.
        candidates: how many candidates were scored.
        wall_s: wall time spent, s.
        cpu_s: process CPU time spent (``clock``), s: what the budget counts.
    """

    gains: Gains
    score: float
    candidates: int
    wall_s: float
    cpu_s: float


def random_search(
    key: jax.Array,
    refs: Any,
    *,
    budget_s: float,
    robot: Robot | None = None,
    start: Gains = PAPER_FEASIBLE_GAINS,
    chunk: int = 16,
    dt: float = simulation.DEFAULT_DT,
    horizon: float | None = None,
    velocity: str = "ideal",
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    problem: Any = "fixed",
    progress: Any = None,
) -> SearchResult:
    """Search the feasible set of ``problem`` at random for ``budget_s`` CPU seconds.

    Candidates ``u ~ U[0, 1]^dim`` are scored ``chunk`` at a time with the
    hard law on ``refs`` (mean arrival time, failures at twice the horizon);
    ``start`` is the first, so the result is never worse than it on ``refs``.
    At least one chunk is scored whatever the budget.

    Args:
        key: PRNG key of the candidates.
        refs: ``(N, 3)`` reference poses the candidates are scored on.
        budget_s: budget in process CPU time (``clock``), s.
        robot: robot parameters; default ``Robot()``.
        start: gains scored first (fixed problem); the schedule starts from
            its own starting point.
        chunk: candidates per batched rollout.
        dt, horizon, velocity, substeps, wheel_limit: as for ``evaluate``.
        problem: ``"fixed"`` or ``"schedule"`` (``wmr_jax.tuning`` problems).
        progress: called with the number of candidates after each chunk.

    Raises:
        ValueError: for out-of-range options or poses, naming the value.
    """
    check_key("key", key)
    robot = validate_one_robot(robot, "tuning")
    budget_s = check_number("budget_s", budget_s, closed=True, high=1e9, unit="s")
    chunk = check_int("chunk", chunk, 1, MAX_SAMPLES)
    check_callable("progress", progress)
    refs = as_poses("refs", refs, batch=True)
    run = check_run(run_options(locals()))
    problem = get_problem(problem)
    if problem is not FIXED and start is not PAPER_FEASIBLE_GAINS:
        raise ValueError(
            f"start is for the fixed problem; problem = {problem.name!r} starts from its own "
            "starting point (allowed: leave start out)"
        )
    first = problem.start(robot) if problem is not FIXED else unit_from_gains(start, robot)
    first = jnp.asarray(first, float_dtype())

    def propose(generation: int) -> jax.Array:
        k = jax.random.fold_in(key, generation * chunk)
        u = jax.random.uniform(k, (chunk, problem.dim), float_dtype())
        return u.at[0].set(first) if generation == 0 else u

    return _hard_law_search(
        problem, refs, chunk, robot, run, budget_s, first, lambda: (propose, None), progress
    )


def _hard_law_search(
    problem, refs, size, robot, run, budget_s, first, proposals, progress, *, logits=False
):
    """``search_loop`` over ``population_scores`` of ``problem``'s cube (or logits) on ``refs``.

    ``proposals()`` makes ``(propose, tell)`` once the budget's clocks run.
    """
    n, tiled = refs.shape[0], jnp.tile(refs, (size, 1))
    wall, began = time.perf_counter(), clock()
    propose, tell = proposals()

    def score(x: jax.Array) -> Any:
        return population_scores(problem, jax.nn.sigmoid(x) if logits else x, tiled, n, robot, run)

    best_x, best_score, count = search_loop(
        propose, score, budget_s, began=began, best=(first, math.inf), tell=tell,
        progress=progress,
    )  # fmt: skip
    params = problem.from_logits(best_x, robot) if logits else problem.from_unit(best_x, robot)
    best = jax.tree.map(float, params)
    return SearchResult(best, best_score, count, time.perf_counter() - wall, clock() - began)


def clock() -> float:
    """Process CPU time, s: every budget's clock, the same work however busy the machine is."""
    return time.process_time()


def one_core() -> bool:
    """Confine this process to one of its cores; call it before JAX's first computation.

    On several cores ``clock`` also counts XLA's pool threads waiting on each
    other, as much as the machine's load makes them; on one it counts the work.
    The equal-compute comparisons run so (docs/robustness.md). Returns whether it
    confined: not once JAX's runtime has started, where that cannot be told, or
    without ``os.sched_setaffinity``.
    """
    try:  # JAX has no public spelling of this
        from jax._src.xla_bridge import backends_are_initialized as started
    except ImportError:
        return False
    if started() or not hasattr(os, "sched_setaffinity"):
        return False
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    return True


def search_loop(
    propose: Any,
    score: Any,
    budget_s: float,
    *,
    began: float,
    best: tuple[Any, float],
    count: int = 0,
    tell: Any = None,
    progress: Any = None,
    at_least_once: bool = True,
    max_count: int | None = None,
) -> tuple[Any, float, int]:
    """The loop of every black-box search: propose, score, keep the best, until the budget.

    Args:
        propose: ``propose(generation)`` → candidates ``(P, dim)``, or ``None``
            to stop (a strategy that broke down).
        score: ``score(candidates)`` → ``(P,)`` scores, lower is better.
        budget_s: budget in process CPU time, s, from ``began`` (a ``clock()``
            reading): the loop stops once ``clock()`` has advanced by it.
        best: ``(candidate, score)`` to beat; ``count``: candidates scored already.
        tell: ``tell(generation, candidates, scores)`` after each scoring.
        progress: called with the generation's size after each.
        at_least_once: run one generation whatever the budget.
        max_count: a budget in candidates instead: stop once ``count`` reaches it
            (``budget_s`` is then not read).

    Returns:
        ``(best candidate, its score, candidates scored)``.
    """
    best_x, best_score = best
    generation = 0

    def within() -> bool:  # reads ``count`` as the loop advances it
        return clock() - began < budget_s if max_count is None else count < max_count

    while (at_least_once and generation == 0) or within():
        xs = propose(generation)
        if xs is None:
            break
        scores = score(xs)
        if tell is not None:
            tell(generation, xs, scores)
        host = np.asarray(scores)
        i = int(np.argmin(host))
        if float(host[i]) < best_score:
            best_score, best_x = float(host[i]), xs[i]
        count += len(xs)
        generation += 1
        if progress is not None:
            progress(len(xs))
    return best_x, best_score, count


def population_scores(problem: Problem, u: jax.Array, tiled: jax.Array, n: int, robot, run):
    """Mean hard-law arrival of each candidate ``u (P, dim)``, failures at twice the horizon, s.

    Candidate i runs on poses i·N … (i+1)·N − 1 of ``tiled``, one flat batch.
    """
    params = problem.from_unit(u, robot)
    # Leaves the same for every candidate (the robot's V_max, L) are repeated too.
    size = u.shape[0]
    population = jax.tree.map(lambda leaf: jnp.repeat(jnp.broadcast_to(leaf, (size,)), n), params)
    with quiet_scoring():
        _, times, steps = hard_runs(tiled, population, **run, controller=problem.controller)
    times = times.reshape(u.shape[0], n)
    return jnp.mean(jnp.minimum(times, FAILURE_FACTOR * steps * run["dt"]), axis=1)


def robust_population_scores(
    loops: Any, refs: Any, key: jax.Array, *, dt: float, robot: Robot, noise: Any = None
) -> np.ndarray:
    """``robust.robust_score`` of each of ``loops`` (one controller and estimator kind), s.

    One ``disturbed_metrics`` call per standard condition over every
    candidate's runs; the arguments as for ``robust_score`` (``robot`` checked).
    """
    from wmr_jax._src.sim.sensing.disturbances import STANDARD_MISMATCH
    from wmr_jax._src.sim.sensing.loop import disturbed_metrics
    from wmr_jax._src.studies import conditions

    refs, unit, factors, horizon = conditions._runs(
        refs, key, robot, None, dt, STANDARD_MISMATCH, False
    )
    size, n = len(loops), len(refs)

    def per_run(*leaves: Any) -> np.ndarray:  # candidate i's value on runs i·N … (i+1)·N − 1
        return np.repeat(np.asarray(leaves, dtype=float), n)

    params = jax.tree.map(per_run, *[loop.params for loop in loops])
    estimate = loops[0].estimator
    if estimate is not None and not isinstance(estimate, str):
        estimate = jax.tree.map(per_run, *[loop.estimator for loop in loops])

    def tiled(a: np.ndarray) -> np.ndarray:
        return np.tile(a, (size,) + (1,) * (a.ndim - 1))

    refs, unit, factors = tiled(refs), tiled(unit), tiled(factors)
    table = conditions._standard_table(factors, noise)
    total = np.zeros(size)
    for _, sxy, sdeg, latency, wheels in table:
        m = disturbed_metrics(
            conditions._scaled(refs, unit, wheels, sxy, sdeg, latency), params,
            controller=loops[0].controller, estimator=estimate, dt=dt, robot=robot, x64=False,
        )  # fmt: skip
        arrival = np.where(m.success, m.arrival, FAILURE_FACTOR * horizon)
        total += arrival.reshape(size, n).mean(axis=1)
    return total / len(table)


# The run options of ``cma_es_search`` not given: ``random_search``'s defaults.
_RUN_DEFAULTS = run_options(
    {name: p.default for name, p in inspect.signature(random_search).parameters.items()}
)


def evosax_available() -> bool:
    """Whether the CMA-ES baseline's library (evosax) can be imported."""
    try:
        import evosax.algorithms  # noqa: F401
    except ImportError:
        return False
    return True


def _evosax_cma_es() -> Any:
    """evosax's CMA-ES with an eigenbasis from XLA alone (``cma``); one clear error without it."""
    try:
        return cma.cma_es_class()
    except ImportError:
        raise ValueError(
            "CMA-ES needs evosax; allowed: pip install 'wmr-jax[search]' (evosax 0.3)"
        ) from None


@functools.cache
def _strategy(cls: Any, population: int, shape: tuple[int, ...], dtype: str) -> Any:
    """One evosax strategy per class, population and shape, for every search of the process.

    evosax compiles ``init``, ``ask`` and ``tell`` per strategy object: a new
    object per search would compile them again inside each search's budget.
    """
    return cls(population_size=population, solution=jnp.zeros(shape, dtype))


@jax.jit
def _generation_keys(key: jax.Array, generation: Any) -> jax.Array:
    """The ask and tell keys of a generation, in one compiled call (the loop's time is budgeted)."""
    return jax.random.split(jax.random.fold_in(key, generation + 1))


def cma_es_proposals(
    key: jax.Array, start: jax.Array, population: int, std_init: float = 1.0, *, split: bool = True
) -> tuple[Any, Any]:
    """``(propose, tell)`` of CMA-ES from ``start`` (logits), for ``search_loop``.

    Generation ``g`` asks and tells with ``split(fold_in(key, g + 1))``, or
    with ``fold_in(key, g + 1)`` for both without ``split`` (the robust tuner's).
    """
    strategy = _strategy(_evosax_cma_es(), population, start.shape, str(start.dtype))
    params = dataclasses.replace(strategy.default_params, std_init=std_init)
    state = strategy.init(jax.random.fold_in(key, 0), start, params)
    tell_keys = {}

    def propose(generation: int) -> Any:
        nonlocal state
        if split:
            ask_key, tell_keys[generation] = _generation_keys(key, generation)
        else:
            ask_key = tell_keys[generation] = jax.random.fold_in(key, generation + 1)
        z, state = strategy.ask(ask_key, state, params)
        # The strategy broke down: on a flat landscape (every candidate scored
        # alike) its step size can overflow. Keep the best so far.
        return z if np.all(np.isfinite(np.asarray(z))) else None

    def tell(generation: int, z: Any, scores: Any) -> None:
        nonlocal state
        state, _ = strategy.tell(tell_keys.pop(generation), z, scores, state, params)

    return propose, tell


def cma_es_search(
    key: jax.Array,
    refs: Any,
    *,
    budget_s: float,
    problem: Any = "fixed",
    robot: Robot | None = None,
    population: int = 16,
    std_init: float = 1.0,
    progress: Any = None,
    **run: Any,
) -> SearchResult:
    """CMA-ES on the logits of ``problem``'s feasible set for ``budget_s`` CPU seconds.

    Scored as by ``random_search``, from the problem's start with step
    ``std_init`` in logit space; at least one generation whatever the budget.
    ``population``: candidates per generation; ``**run``: ``random_search``'s
    ``dt``, ``horizon``, ``velocity``, ``substeps``, ``wheel_limit``.

    Raises:
        ValueError: if evosax is missing (one line) or for bad options.
    """
    check_key("key", key)
    budget_s = check_number("budget_s", budget_s, closed=True, high=1e9, unit="s")
    population = check_int("population", population, 2, MAX_SAMPLES)
    std_init = check_number("std_init", std_init)
    check_callable("progress", progress)
    problem = get_problem(problem)
    robot = validate_one_robot(robot, "tuning")
    refs = as_poses("refs", refs, batch=True)
    run = {**_RUN_DEFAULTS, **run, "robot": robot}
    run = check_run(run)
    _evosax_cma_es()
    start = jnp.asarray(problem.start_logits(robot), float_dtype())
    return _hard_law_search(
        problem, refs, population, robot, run, budget_s, start,
        lambda: cma_es_proposals(key, start, population, std_init), progress, logits=True,
    )  # fmt: skip
