"""The hybrid robust tuner's second half: CMA-ES from the gradient's result on the hard law.

The gradient descends a relaxed surrogate (the smooth law, a soft arrival
time); ``polish`` searches from its result with the hard law under the
standard conditions, the score the loop is judged by
(``robust.tune_robust`` with ``RobustConfig.tuner = "hybrid"``).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import jax
import jax.numpy as jnp

from wmr_jax._src.checks import float_dtype
from wmr_jax._src.tuning.estimation import concrete_loop
from wmr_jax._src.tuning.search import (
    clock,
    cma_es_proposals,
    robust_population_scores,
    search_loop,
)

__all__ = ["polish"]


def polish(key, z, refs, budget_s, robot, dt, joint, noise=None, std=0.1):
    """CMA-ES from the logits ``z`` for ``budget_s`` s of CPU time: ``(ClosedLoop, candidates)``.

    8 candidates per generation with step ``std`` in logits, each scored
    with ``robust_score`` on ``refs``, a generation in one batch as the
    searches score theirs (``search.robust_population_scores``); ``z`` is
    scored first, so the result is never worse than it on ``refs``. The
    budget is counted with ``search.clock``, ``z``'s own score included.
    """
    began = clock()
    score_key = jax.random.fold_in(key, 7)
    z = jnp.asarray(z, float_dtype())

    def closed(z):
        return concrete_loop(joint.from_logits(z, robot))

    def scores(zs: Any) -> Any:
        with warnings.catch_warnings():
            # Candidates far outside the useful set warn; their score says it.
            warnings.simplefilter("ignore")
            loops = [closed(z) for z in zs]
            return robust_population_scores(loops, refs, score_key, dt=dt, robot=robot, noise=noise)

    cma_propose, tell = cma_es_proposals(key, z, 8, std, split=False)

    def propose(generation: int) -> Any:
        return cma_propose(generation) if clock() - began < budget_s else None

    # The budget is spent when ``propose`` says so: no wall-time limit besides.
    best_z, _, count = search_loop(
        propose, scores, math.inf, began=0.0, best=(z, float(scores(z[None])[0])), count=1,
        tell=tell, at_least_once=False,
    )  # fmt: skip
    return closed(best_z), count
