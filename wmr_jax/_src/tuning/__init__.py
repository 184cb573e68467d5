"""Gradient-based gain tuning under ``k_r + L k_θ ≤ V_max``, with optax.

Which feasible gains bring the robot to its reference fastest, over a
distribution of reference poses (``docs/model.md §6``)? Adam descends a
differentiable surrogate of the arrival time through the law's smooth
relaxation, annealed towards the hard law, and the result is judged with the
hard law against the paper's feasible gains and black-box searches given the
same CPU time. The public names are those of ``wmr_jax.tuning``; the modules
are listed in ``docs/custom_controller.md``.
"""
