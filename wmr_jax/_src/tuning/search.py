"""Random search over the tuner's feasible set: the baseline the tuned gains must beat."""

from __future__ import annotations

import math
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import loops
from wmr_jax._src import rollout as simulation
from wmr_jax._src.checks import as_poses, check_int, float_dtype
from wmr_jax._src.params import Gains, Robot, validate_robot
from wmr_jax._src.poses import HORIZON_S
from wmr_jax._src.tuning.evaluation import hard_runs, run_options
from wmr_jax._src.tuning.parametrisation import (
    PAPER_FEASIBLE_GAINS,
    gains_from_unit,
    unit_from_gains,
)

__all__ = ["SearchResult", "random_search"]

# Random search scores a run that never arrives as twice the horizon: worse
# than any arrival, but finite, so that candidates' means stay comparable.
_FAILURE_FACTOR = 2.0


class SearchResult(NamedTuple):
    """Outcome of ``random_search``.

    Attributes:
        gains: the best candidate found.
        score: its mean arrival time on the search poses, failures counted as
            twice the horizon, s.
        candidates: how many candidates were scored.
        wall_s: wall time spent, s.
    """

    gains: Gains
    score: float
    candidates: int
    wall_s: float


def random_search(
    key: jax.Array,
    refs: Any,
    *,
    budget_s: float,
    robot: Robot | None = None,
    start: Gains = PAPER_FEASIBLE_GAINS,
    chunk: int = 16,
    dt: float = simulation.DEFAULT_DT,
    horizon: float = HORIZON_S,
    velocity: str = "ideal",
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> SearchResult:
    """Search the feasible set of ``gains_from_unit`` at random for ``budget_s`` seconds.

    Candidates are ``u ~ U[0, 1]^7``, scored ``chunk`` at a time with the hard
    law on ``refs`` (mean arrival time, failures counted as twice the
    horizon); ``start`` is the first candidate, so the result is never worse
    than it on ``refs``. At least one chunk is scored whatever the budget.

    Args:
        key: PRNG key of the candidates.
        refs: ``(N, 3)`` reference poses the candidates are scored on.
        budget_s: wall-time budget, s.
        robot: robot parameters; default ``Robot()``.
        start: gains scored first.
        chunk: candidates per batched rollout.
        dt, horizon, velocity, substeps, wheel_limit: as for ``evaluate``.

    Raises:
        ValueError: for out-of-range options or poses, naming the value.
    """
    robot = validate_robot(Robot() if robot is None else robot)
    budget_s = float(budget_s)
    chunk = check_int("chunk", chunk, 1)
    refs = as_poses("refs", refs, batch=True)
    run = run_options(locals())
    n = refs.shape[0]
    tiled = jnp.tile(refs, (chunk, 1))
    first = jnp.asarray(unit_from_gains(start, robot), float_dtype())
    best_score, best_u, count = math.inf, first, 0
    began = time.perf_counter()
    while count == 0 or time.perf_counter() - began < budget_s:
        u = jax.random.uniform(jax.random.fold_in(key, count), (chunk, 7), float_dtype())
        if count == 0:
            u = u.at[0].set(first)
        # Candidate i runs on poses i·N … (i+1)·N − 1: one flat batch.
        population = jax.tree.map(lambda leaf: jnp.repeat(leaf, n), gains_from_unit(u, robot))
        _, times, steps = hard_runs(tiled, population, **run)
        times = times.reshape(chunk, n)
        scores = np.asarray(jnp.mean(jnp.minimum(times, _FAILURE_FACTOR * steps * dt), axis=1))
        i = int(np.argmin(scores))
        if scores[i] < best_score:
            best_score, best_u = float(scores[i]), u[i]
        count += chunk
    best = jax.tree.map(float, gains_from_unit(best_u, robot))
    return SearchResult(best, best_score, count, time.perf_counter() - began)
