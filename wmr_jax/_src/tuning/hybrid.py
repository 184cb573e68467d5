"""The hybrid robust tuner's second half: CMA-ES from the gradient's result on the hard law.

The gradient descends a relaxed surrogate; ``polish`` searches from its result
with the score the loop is judged by (``RobustConfig.tuner = "hybrid"``).
"""

from __future__ import annotations

from wmr_jax._src.tuning import robust


def polish(key, z, refs, budget_s, robot, dt, joint, noise=None, std=0.1):
    """CMA-ES from the logits ``z`` for ``budget_s`` s of CPU time: ``(ClosedLoop, candidates)``.

    ``z`` is scored first, within the budget, so the result is never worse
    than it on ``refs``.
    """
    loop, count, _, _ = robust.black_box(
        "cma-es", key, refs, budget_s, robot, dt, joint, noise, start=z, std=std
    )
    return loop, count
