"""Run the closed loop on an identified robot while the controller believes the base robot.

``identified.json`` says how the true robot differs from the one the
controller was written for: its wheels' scales, its half-track, its wheel
loop's gain, its latency and its tracker's noise. A run on it is the one
closed-loop step with ``model.TrueRobot`` as its disturbance: the law and
the firmware keep ``BASE``, the body moves as the identified robot does.
In the ideal velocity loop the wheel loop's gain plays no part; in the
non-ideal loop the wheel controller keeps the base's model.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import loops
from wmr_jax._src.identify import model
from wmr_jax._src.params import Robot
from wmr_jax._src.rollout import Trajectory

__all__ = ["is_identified", "read_identified", "identified_rollout"]

_KEYS = ("robot", "base_robot", "wheel_scale", "latency_samples", "noise")


def is_identified(source: Any) -> bool:
    """Whether ``source`` names an ``identified.json`` written by ``identify``."""
    if source is None or not str(source).endswith(".json") or not Path(source).is_file():
        return False
    try:
        content = json.loads(Path(source).read_text())
    except ValueError:
        return False
    return isinstance(content, dict) and "wheel_scale" in content


def read_identified(source: Any) -> tuple[Robot, dict[str, Any]]:
    """Return ``(base robot, identified content)`` of an ``identified.json``, checked."""
    content = json.loads(Path(source).read_text())
    missing = [k for k in _KEYS if k not in content]
    if missing:
        raise ValueError(f"--robot {source} lacks {', '.join(missing)}; allowed: identify's output")
    base = Robot(**{k: float(v) for k, v in content["base_robot"].items()})
    latency = content["latency_samples"]
    if not isinstance(latency, int) or not 0 <= latency <= model.MAX_LATENCY:
        raise ValueError(
            f"--robot {source}: latency_samples = {latency!r} is not allowed; allowed: an "
            f"integer 0-{model.MAX_LATENCY}"
        )
    return base, content


def identified_rollout(
    ref: Any,
    params: Any,
    *,
    controller: Any,
    init: Any,
    dt: float,
    steps: int,
    velocity: str,
    base: Robot,
    identified: dict[str, Any],
    seed: int = 0,
    noise: bool = True,
) -> Trajectory:
    """One run of ``controller`` (believing ``base``) on the identified robot.

    The law sees the pose with the identified tracker noise (``noise``) and
    acts ``latency_samples`` late; the region is ``-1`` (the law sees a
    measurement, not the true pose).
    """
    with jax.enable_x64(True):
        true = identified["robot"]
        sigma = identified["noise"]
        scale = np.array([identified["wheel_scale"]["left"], identified["wheel_scale"]["right"]])
        delay = int(identified["latency_samples"])
        key = jax.random.PRNGKey(seed)
        draws = jax.random.normal(key, (steps, 3), jnp.float64)
        spread = jnp.asarray([sigma["sigma_xy"], sigma["sigma_xy"], sigma["sigma_theta"]])
        spec = model.TrueRobot(
            draws * spread * (1.0 if noise else 0.0),
            jnp.asarray(scale),
            jnp.float64(base.half_track),
            jnp.float64(delay),
            jnp.float64(true["half_track"]),
            jnp.float64(true["speed_gain"]),
        )
        options = loops.for_robot(
            loops.Options(
                steps=steps,
                velocity=velocity,
                controller=controller,
                max_delay=max(1, delay),
                remat=False,
            ),
            base,
            dt,
        )
        init = jnp.asarray(init, jnp.float64)
        base64 = jax.tree.map(jnp.float64, base)
        params = jax.tree.map(jnp.float64, params)
        _, _, (poses, out, _) = jax.jit(
            lambda s: loops.scan_closed_loop(
                jnp.asarray(ref, jnp.float64),
                params,
                init,
                base64,
                jnp.float64(dt),
                options,
                disturbance=s,
                record=True,
            )
        )(spec)
        return Trajectory(
            np.asarray(jnp.concatenate([init[None], poses])),
            np.asarray(out.v),
            np.asarray(out.omega),
            np.asarray(out.region),
            np.asarray(out.wheel_speeds),
            np.asarray(out.distance),
        )
