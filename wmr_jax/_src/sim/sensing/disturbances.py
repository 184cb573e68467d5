"""The disturbances of docs/model.md §7, drawn from a PRNG key, and how they act on a run.

``sample_disturbance`` is the one place they are drawn.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model import dynamics
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import motion
from wmr_jax._src.sim.poses import MAX_SAMPLES, sample_poses

# The standard conditions of docs/model.md §7, with the nominal model first:
# (label, σ_xy cm, σ_θ degrees, one-sample latency). Ideal loop.
STANDARD_CONDITIONS = (
    ("nominal", 0.0, 0.0, False),
    ("latency", 0.0, 0.0, True),
    ("noise", 0.5, 1.0, False),
    ("both", 0.5, 1.0, True),
)

# The wheel-radius mismatch bound of the standard conditions for a loop with an
# estimator (docs/model.md §9): without it, dead reckoning would be exact.
STANDARD_MISMATCH = 0.03


class Disturbance(NamedTuple):
    """What makes one run differ from the nominal one (leading batch axes first).

    Attributes:
        ref: ``(3,)`` reference pose ``[cm, cm, rad]``.
        noise: ``(steps, 3)`` measurement error added to the pose at each
            sample, ``[cm, cm, rad]``.
        mismatch: ``(3,)`` ``[left rim factor, right rim factor, mass factor]``
            (1: no mismatch).
        delay: ``()`` the latency in samples, an integer ``m >= 0`` stored as
            a float: the command of sample ``k`` acts from sample ``k + m``.
    """

    ref: jax.Array
    noise: jax.Array
    mismatch: jax.Array
    delay: jax.Array

    def realised(self, command: jax.Array, robot: Robot) -> tuple[jax.Array, ...]:
        """The body velocity ``(v, ω)`` of the rims of ``command`` (``v + i ω``), scaled."""
        return realised(command, self.mismatch, robot)

    def true_robot(self, robot: Robot) -> Robot:
        """The robot that moves: ``robot`` with its body mass off by the mass factor."""
        return robot.replace(body_mass=robot.body_mass * self.mismatch[2])

    def measurement(self, pose: motion.SplitPose, noise: jax.Array) -> Measurement:
        """What the sensor reports at ``pose`` with ``noise`` ``(3,)``."""
        return measurement(pose, noise)


def realised(command: jax.Array, mismatch: jax.Array, robot: Robot) -> tuple[jax.Array, ...]:
    """Return the body velocity ``(v, ω)`` whose rims are the commanded ``v + i ω``, scaled."""
    v, omega = command.real, command.imag
    rims = law.wheel_speeds(v, omega, robot)  # [v_L, v_R]
    # A correction of the command, so that factors of 1 return it bit for bit.
    extra_left, extra_right = rims[0] * (mismatch[0] - 1), rims[1] * (mismatch[1] - 1)
    return (
        v + 0.5 * (extra_left + extra_right),
        omega + 0.5 * (extra_right - extra_left) / robot.half_track,
    )


class Measurement(NamedTuple):
    """A measured pose ``pose + noise``: the true heading ``base`` turned by ``offset`` rad."""

    position: jax.Array
    base: jax.Array
    offset: jax.Array
    theta: jax.Array

    def turned(self, angle: jax.Array) -> jax.Array:
        """The measured heading turned further by ``angle``: ``base · e^{i (offset + angle)}``."""
        cos_n, sin_n = dynamics.sin_cos(self.offset + angle)
        return self.base * jax.lax.complex(cos_n, sin_n)

    def pose(self) -> motion.SplitPose:
        """The measured pose (exactly the pose for zero noise)."""
        cos_n, sin_n = dynamics.sin_cos(self.offset)
        return motion.SplitPose(
            self.position, self.base * jax.lax.complex(cos_n, sin_n), self.theta
        )

    def residual(self, estimate: motion.SplitPose) -> jax.Array:
        """Return ``θ_measured − θ_estimate`` wrapped to ``[−π, π)``, rad."""
        # From the unwrapped angles both carry: cheaper than an arctangent.
        return law.wrap_angle(self.theta - estimate.theta)


def measurement(pose: motion.SplitPose, noise: jax.Array) -> Measurement:
    """What the sensor reports at ``pose`` with ``noise`` ``(3,)`` ``[cm, cm, rad]``."""
    return Measurement(
        pose.position + jax.lax.complex(noise[0], noise[1]),
        pose.heading,
        noise[2],
        pose.theta + noise[2],
    )


def checked_disturbance(disturbance: Disturbance) -> tuple[np.ndarray, ...]:
    """Return the fields of ``disturbance`` as float arrays after checking them."""
    if not isinstance(disturbance, Disturbance):
        raise ValueError(
            f"disturbance = {type(disturbance).__name__} is not allowed; "
            "allowed: a Disturbance (sample_disturbance returns one)"
        )
    refs, noise, mismatch, delay = (
        checks.real_array(
            f"disturbance.{field}",
            value,
            "an integer number of samples m >= 0 (no bools or strings)"
            if field == "delay"
            else "real numbers (no bools or strings)",
        )
        for field, value in zip(Disturbance._fields, disturbance, strict=True)
    )
    if refs.ndim != 2 or refs.shape[1] != 3:
        raise ValueError(f"disturbance.ref has shape {refs.shape}; allowed: (N, 3)")
    n = refs.shape[0]
    if noise.ndim != 3 or noise.shape[0] != n or noise.shape[2] != 3 or noise.shape[1] < 1:
        raise ValueError(f"disturbance.noise has shape {noise.shape}; allowed: ({n}, steps, 3)")
    if mismatch.shape != (n, 3):
        raise ValueError(f"disturbance.mismatch has shape {mismatch.shape}; allowed: ({n}, 3)")
    checks.require("disturbance.noise", noise, np.isfinite(noise), "finite numbers")
    limit = checks.position_limit()
    checks.require(
        "disturbance.noise",
        noise,
        np.abs(noise) <= np.array([limit, limit, checks.MAX_HEADING]),
        f"|x|, |y| noise <= {limit:.0e} cm and heading noise <= {checks.MAX_HEADING:.0e} rad",
    )
    checks.require(
        "disturbance.mismatch", mismatch, np.isfinite(mismatch) & (mismatch > 0), "finite, > 0"
    )
    checks.require_representable("disturbance.mismatch", mismatch)
    checks.require_representable("disturbance.noise", noise, tiny_ok=True)
    steps = noise.shape[1]
    whole = np.isfinite(delay) & (delay >= 0) & (delay <= steps)
    allowed = f"an integer number of samples 0 <= m <= {steps} (the steps), or ({n},) of them"
    if delay.shape not in ((), (n,)):
        raise ValueError(f"disturbance.delay has shape {delay.shape}; allowed: {allowed}")
    checks.require("disturbance.delay", delay, whole & (np.floor(delay) == delay), allowed)
    return refs, noise, mismatch, delay


# Beyond these a level no longer describes a sensor (σ_θ of 2π is uniform).
_LEVEL_LIMITS = {"noise_xy": 1e6, "noise_theta": 2 * math.pi, "latency": 1.0}


def _check_draw(key: Any, steps: Any, n: int | None, **levels: Any) -> None:
    """Check a draw's key, length and levels (scalars or ``(n,)``) where concrete."""
    checks.check_key("key", key)
    checks.check_int("steps", steps, 1, checks.MAX_STEPS)
    for name, value in levels.items():
        if checks.is_traced(value):
            continue
        high = _LEVEL_LIMITS.get(name, 1.0)
        closed_high = name in _LEVEL_LIMITS
        upper = f"<= {high:g}" if closed_high else f"< {high:g}"
        allowed = f"a number >= 0 and {upper}"
        arr = checks.real_array(name, value, allowed)
        if arr.ndim > 1 or (arr.ndim == 1 and n is not None and arr.shape not in ((1,), (n,))):
            per_run = f"({n},)" if n is not None else "(N,)"
            raise ValueError(
                f"{name} has shape {arr.shape}; allowed: a scalar (or (1,)) shared by every "
                f"run, or {per_run}, one per run"
            )
        ok = np.isfinite(arr) & (arr >= 0) & ((arr <= high) if closed_high else (arr < high))
        checks.require(name, arr, ok, allowed)


def sample_disturbance(
    key: jax.Array,
    refs: jax.Array,
    steps: int,
    *,
    noise_xy: Any = 0.0,
    noise_theta: Any = 0.0,
    latency: Any = 0.0,
    radius_mismatch: Any = 0.0,
    mass_mismatch: Any = 0.0,
) -> Disturbance:
    """Draw one ``Disturbance`` per reference from ``key`` (``docs/model.md §7``); traceable.

    Args:
        key: a ``jax.random`` key.
        refs: ``(N, 3)`` reference poses.
        steps: control periods per run (static).
        noise_xy, ...: each level a scalar or one value per run ``(N,)``.
        noise_xy: σ of the x and y measurement noise, cm.
        noise_theta: σ of the heading measurement noise, rad.
        latency: probability that a run has a one-sample latency (the standard
            conditions'); for ``m`` samples in every run, replace the draw's
            delay: ``spec._replace(delay=jnp.full_like(spec.delay, m))``.
        radius_mismatch: each wheel's radius error ``δ ~ U(−m, m)``.
        mass_mismatch: the body-mass error ``μ ~ U(−m, m)``.

    Returns:
        A ``Disturbance``: ``noise (N, steps, 3)`` Gaussian, independent per
        sample; ``mismatch (N, 3)``; ``delay (N,)`` in {0, 1}.
    """
    checked = None if checks.is_traced(refs) else checks.as_poses("refs", refs, batch=True)
    _check_draw(
        key,
        steps,
        np.shape(refs)[0],
        noise_xy=noise_xy,
        noise_theta=noise_theta,
        latency=latency,
        radius_mismatch=radius_mismatch,
        mass_mismatch=mass_mismatch,
    )
    if checked is not None:
        # Draw in the poses' own float dtype, else JAX's default one.
        own = getattr(refs, "dtype", None)
        floating = own is not None and jnp.issubdtype(own, jnp.floating)
        refs = jnp.asarray(refs) if floating else checked
    refs = jnp.asarray(refs)
    n, dtype = refs.shape[0], refs.dtype
    k_noise, k_mis, k_delay = jax.random.split(key, 3)

    def per_run(level):
        return jnp.broadcast_to(jnp.asarray(level, dtype), (n,))

    sxy, sth = per_run(noise_xy), per_run(noise_theta)
    scale = jnp.stack([sxy, sxy, sth], axis=-1)[:, None, :]
    noise = jax.random.normal(k_noise, (n, steps, 3), dtype) * scale
    bounds = jnp.stack([per_run(radius_mismatch)] * 2 + [per_run(mass_mismatch)], axis=-1)
    mismatch = 1.0 + jax.random.uniform(k_mis, (n, 3), dtype, -1.0, 1.0) * bounds
    delay = jax.random.bernoulli(k_delay, per_run(latency)).astype(dtype)
    return Disturbance(refs, noise, mismatch, delay)


def draw_disturbances(
    key: jax.Array,
    n: int,
    steps: int,
    *,
    radius_mismatch: float = 0.0,
    mass_mismatch: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw ``n`` references (``sample_poses``), unit noise and mismatch factors from ``key``.

    Returns:
        ``(refs (n, 3), unit noise (n, steps, 3) ~ N(0, 1), mismatch (n, 3))``.
    """
    n = checks.check_int("n", n, 1, MAX_SAMPLES)
    _check_draw(key, steps, n, radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch)
    k_ref, k_rest = jax.random.split(key)
    refs = sample_poses(k_ref, n, dtype=jnp.float32)
    d = sample_disturbance(
        k_rest,
        refs,
        steps,
        noise_xy=1.0,
        noise_theta=1.0,
        radius_mismatch=radius_mismatch,
        mass_mismatch=mass_mismatch,
    )
    return tuple(np.asarray(a, dtype=float) for a in (refs, d.noise, d.mismatch))
