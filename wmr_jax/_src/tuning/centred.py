"""Robust training conditions centred on an identified robot (docs/model.md §10).

``tune --robust --robot DIR/identified.json`` trains through the identified
robot instead of the standard conditions of §7: each run's wheel scales,
tracker noise and latency are drawn over the identified 95 % intervals.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src.sim.sensing.disturbances import STANDARD_CONDITIONS, Disturbance

# choice: a neighbouring latency is drawn too when its cost in identify's
# profile over the latency is within this fraction of the winner's; on a log
# that shows the latency at all, one sample off costs far more.
LATENCY_TIE = 0.01
# The body-mass bound of the non-ideal group, as in the standard training.
_MASS_MISMATCH = 0.2


class Centred(NamedTuple):
    """The ranges a centred training draws from (hashable: static under ``jit``).

    Attributes:
        scale_left: ``(low, high)`` of the left wheel's scale (rim over set
            point), drawn uniformly per run.
        scale_right: the same for the right wheel, drawn independently.
        latency: the latencies in samples, each drawn with equal probability.
        noise_xy: ``(low, high)`` of the tracker's σ_xy, cm, drawn uniformly per run.
        noise_theta: ``(low, high)`` of its σ_θ, rad, drawn uniformly per run.
    """

    scale_left: tuple[float, float]
    scale_right: tuple[float, float]
    latency: tuple[int, ...]
    noise_xy: tuple[float, float]
    noise_theta: tuple[float, float]


def _interval(content: Mapping[str, Any], name: str, value: float) -> tuple[float, float]:
    """The 95 % interval of ``name``, checked to hold ``value``."""
    try:
        low, high = (float(v) for v in content["ci95"][name])
    except (KeyError, TypeError, ValueError):
        raise ValueError(
            f"ci95.{name} = {content.get('ci95', {}).get(name)!r:.60} is not allowed; allowed: "
            "[low, high] as identify writes it"
        ) from None
    if not (math.isfinite(low) and math.isfinite(high) and low <= value <= high):
        raise ValueError(
            f"ci95.{name} = [{low}, {high}] is not allowed: it does not hold the identified "
            f"{value}; allowed: an interval around it"
        )
    return low, high


def around(content: Mapping[str, Any]) -> Centred:
    """The ranges of a training centred on the content of an ``identified.json``.

    Wheel scales and noise levels: their 95 % intervals (``ci95``). Latency:
    the identified ``m``, and ``m ± 1`` where their cost in ``latency_profile``
    is within ``LATENCY_TIE`` of its own.

    Raises:
        ValueError: one line naming a missing or malformed field.
    """
    for key in ("wheel_scale", "latency_samples", "noise", "ci95"):
        if key not in content:
            raise ValueError(f"{key} is missing; allowed: an identified.json of identify")
    scale, noise = content["wheel_scale"], content["noise"]
    m = content["latency_samples"]
    if isinstance(m, bool) or not isinstance(m, int) or m < 0:
        raise ValueError(f"latency_samples = {m!r} is not allowed; allowed: an integer >= 0")
    profile = [float(c) for c in content.get("latency_profile", [])]
    latency = [m]
    if m < len(profile):
        tie = profile[m] * (1.0 + LATENCY_TIE)
        latency += [k for k in (m - 1, m + 1) if 0 <= k < len(profile) and profile[k] <= tie]
    return Centred(
        _interval(content, "wheel_scale_left", float(scale["left"])),
        _interval(content, "wheel_scale_right", float(scale["right"])),
        tuple(sorted(latency)),
        _interval(content, "sigma_xy", float(noise["sigma_xy"])),
        _interval(content, "sigma_theta", float(noise["sigma_theta"])),
    )


def draw(key: jax.Array, refs: jax.Array, steps: int, ranges: Centred, mass: float = 0.0):
    """One ``Disturbance`` per reference of ``refs (N, 3)`` drawn from ``ranges`` (traceable).

    ``mismatch (N, 3)``: the two wheel scales and the mass factor ``1 + U(−mass, mass)``
    (non-ideal loop); ``noise (N, steps, 3)``: Gaussian with each run's own σ_xy and
    σ_θ; ``delay (N,)``: one of ``ranges.latency``. ``steps`` is static.
    """
    n, dtype = refs.shape[0], refs.dtype
    k_scale, k_level, k_noise, k_delay = jax.random.split(key, 4)
    low = jnp.asarray([ranges.scale_left[0], ranges.scale_right[0], 1.0 - mass], dtype)
    high = jnp.asarray([ranges.scale_left[1], ranges.scale_right[1], 1.0 + mass], dtype)
    mismatch = low + jax.random.uniform(k_scale, (n, 3), dtype) * (high - low)
    low = jnp.asarray([ranges.noise_xy[0], ranges.noise_theta[0]], dtype)
    high = jnp.asarray([ranges.noise_xy[1], ranges.noise_theta[1]], dtype)
    sigma = low + jax.random.uniform(k_level, (n, 2), dtype) * (high - low)
    spread = jnp.stack([sigma[:, 0], sigma[:, 0], sigma[:, 1]], axis=-1)[:, None, :]
    noise = jax.random.normal(k_noise, (n, steps, 3), dtype) * spread
    choices = jnp.asarray(ranges.latency, dtype)
    delay = choices[jax.random.randint(k_delay, (n,), 0, len(ranges.latency))]
    return Disturbance(refs, noise, mismatch, delay)


def batches(key, refs, nonideal_refs, steps, ideal, ranges: Centred) -> list:
    """The robust loss's ``[(spec, options)]`` drawn from ``ranges`` instead of the standard ones.

    ``refs`` run in the ideal loop (options ``ideal``) once per standard
    condition, each with its own draw; ``nonideal_refs`` (may be empty) in
    the non-ideal loop, the body mass off by up to ±20 % besides.
    """
    ideal = dataclasses.replace(ideal, max_delay=max(1, *ranges.latency))
    k_ideal, k_nonideal = jax.random.split(key)
    refs = jnp.tile(refs, (len(STANDARD_CONDITIONS), 1))
    out = [(draw(k_ideal, refs, steps, ranges), ideal)]
    if nonideal_refs.shape[0]:
        nonideal = dataclasses.replace(ideal, velocity="nonideal", accel_limit=False)
        spec = draw(k_nonideal, nonideal_refs, steps, ranges, _MASS_MISMATCH)
        out.append((spec, nonideal))
    return out


def for_config(config: Any, content: Mapping[str, Any]) -> Any:
    """``config`` (a ``RobustConfig``) tuned around ``content``, an ``identified.json``'s.

    The training draws from ``around(content)``; the validation and the
    table judge the standard conditions at the identified tracker noise.
    """
    ranges = around(content)
    noise = content["noise"]
    return dataclasses.replace(
        config,
        around=ranges,
        noise_xy=float(noise["sigma_xy"]),
        noise_theta=math.degrees(float(noise["sigma_theta"])),
    )
