"""Controllers as values: a pure command law plus the type of its parameter pytree.

A ``Controller`` bundles ``command(pose, ref, params, *, temperature)`` →
``(v cm/s, ω rad/s)`` with the things a rollout needs around it: a region label
for diagnostics, a boundary check of its parameters and their defaults.
Rollouts, batching, metrics and tuning take any ``Controller``; the
Shim–Sung controller of the paper is the default.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from wmr_jax import law
from wmr_jax.params import Gains, validate_gains

__all__ = ["SHIM_SUNG", "Controller", "get_controller", "register_controller"]


@dataclasses.dataclass(frozen=True)
class Controller:
    """A pose controller as a value (hashable, so it can be a static ``jit`` argument).

    Attributes:
        name: short name used by the CLI and in tables.
        command: ``(pose (…,3), ref (…,3), params, *, temperature) -> (v, ω)``.
        params_type: the class of its parameter pytree (built with defaults
            when a rollout gets ``None``).
        validate: checks a parameter pytree before tracing; returns it.
        region: ``(pose, ref, params) -> int32`` diagnostic label, or ``None``
            for a controller without regions (labels are then −1).
        smooth: whether ``command`` accepts a positive ``temperature``.
    """

    name: str
    command: Callable[..., tuple[jax.Array, jax.Array]]
    params_type: type
    validate: Callable[[Any], Any]
    region: Callable[..., jax.Array] | None = None
    smooth: bool = False

    def default_params(self) -> Any:
        """Return the controller's default parameters."""
        return self.params_type()

    def region_of(self, pose: jax.Array, ref: jax.Array, params: Any) -> jax.Array:
        """Return the region label of the command at ``pose`` (−1 if it has none)."""
        if self.region is None:
            return jnp.full(jnp.shape(pose)[:-1], -1, jnp.int32)
        return self.region(pose, ref, params)


def _shim_sung_region(pose: jax.Array, ref: jax.Array, gains: Gains) -> jax.Array:
    return law.region_label(law.polar_error(pose, ref), gains)


SHIM_SUNG = Controller(
    name="shim-sung",
    command=law.control,
    params_type=Gains,
    validate=validate_gains,
    region=_shim_sung_region,
    smooth=True,
)

_REGISTRY: dict[str, Controller] = {SHIM_SUNG.name: SHIM_SUNG}


def register_controller(controller: Controller) -> Controller:
    """Make ``controller`` known by name to the CLI and ``get_controller``."""
    _REGISTRY[controller.name] = controller
    return controller


def get_controller(name: str | Controller) -> Controller:
    """Return the controller called ``name`` (a ``Controller`` is returned as is)."""
    if isinstance(name, Controller):
        return name
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(
            f"controller = {name!r} is not known; allowed: {sorted(_REGISTRY)}"
        ) from None
