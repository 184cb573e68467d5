"""Gradient-based gain tuning under ``k_r + L k_θ ≤ V_max``, with optax (``docs/model.md §6``).

The public names are those of ``wmr_jax.tuning``; the modules are listed in
``docs/custom_controller.md``.
"""
