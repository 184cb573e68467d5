"""Commands that excite every parameter of the identified model, and synthetic logs of them.

A plan alternates random held commands (speeds and turn rates spread over
the robot's limits, held 0.3–1.5 s, so that the wheel lag and the latency
show at every change) with UMBmark's square paths (Borenstein & Feng 1996:
four straight sides and four on-the-spot quarter turns, driven clockwise and
counter-clockwise), which also feed that method's correction.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.identify import model
from wmr_jax._src.model.params import Robot

# The fastest turn a plan asks for, rad/s: a small robot spinning at the
# rate its wheels allow traces loops a few cm wide, where its speed scale
# hardly shows.
TURN_RATE = 2.0


def _limits(robot: Robot) -> tuple[float, float]:
    """Speed and turn rate within half the rim budget each (turns at most ``TURN_RATE``)."""
    v_max = float(robot.v_max)
    return 0.5 * v_max, min(0.5 * v_max / float(robot.half_track), TURN_RATE)


def square_commands(robot: Robot, dt: float, side: float, clockwise: bool) -> np.ndarray:
    """One UMBmark square of ``side`` cm: go, stop, quarter turn on the spot, four times."""
    v, w = _limits(robot)
    v, w = 0.6 * v, 0.6 * w
    go = max(1, round(side / (v * dt)))
    v_go = side / (go * dt)
    turn = max(1, round((np.pi / 2) / (w * dt)))
    w_turn = (np.pi / 2) / (turn * dt) * (-1 if clockwise else 1)
    rest = max(1, round(0.5 / dt))
    leg = [[v_go, 0.0]] * go + [[0.0, 0.0]] * rest + [[0.0, w_turn]] * turn + [[0.0, 0.0]] * rest
    return np.asarray(leg * 4, dtype=float)


def plan_commands(
    robot: Robot, dt: float, minutes: float, seed: int = 0, *, squares: bool = True
) -> np.ndarray:
    """An exciting command sequence ``(N, 2)`` of ``minutes`` at period ``dt`` (cm/s, rad/s).

    The two squares first (a plan shorter than they are ends inside them),
    then random held commands.
    """
    rng = np.random.default_rng(seed)
    total = round(minutes * 60 / dt)
    v_lim, w_lim = _limits(robot)
    parts = []
    if squares:
        side = min(200.0, 4 * v_lim)
        for clockwise in (False, True):
            parts.append(square_commands(robot, dt, side, clockwise))
    count = sum(len(p) for p in parts)
    while count < total:
        hold = max(1, round(rng.uniform(0.3, 1.5) / dt))
        v = rng.uniform(-0.3, 1.0) * v_lim
        w = rng.uniform(-1.0, 1.0) * w_lim
        # Within the rims' budget: |v| + L |ω| ≤ V_max / 2.
        excess = abs(v) / v_lim + abs(w) / w_lim
        if excess > 1:
            v, w = v / excess, w / excess
        parts.append(np.tile([v, w], (hold, 1)))
        count += hold
    commands = np.concatenate(parts)[:total]
    return commands


def synthetic_log(
    commands: Any,
    base: Robot,
    scale: Any,
    half_track: float,
    speed_gain: float,
    latency: int,
    dt: float,
    sigma_xy: float,
    sigma_theta: float,
    key: Any,
    init: Any = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The log the true robot would write: ``(commands, measured poses (N, 3), true poses)``.

    Row ``k`` holds the command sent at sample ``k`` and the pose measured
    there; the robot starts at rest at ``init``.
    """
    with jax.enable_x64(True):
        commands = jnp.asarray(commands, jnp.float64)
        init = jnp.asarray(init, jnp.float64)
        base64 = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), base)
        robot = model.fitted_robot(base64, half_track, speed_gain)
        poses = model.replay(
            commands,
            init,
            robot,
            jnp.asarray(scale),
            base64.half_track,
            latency,
            dt,
            max_delay=max(1, latency),
        )
        true = jnp.concatenate([init[None], poses[:-1]])
        noise = jax.random.normal(key, true.shape, jnp.float64) * jnp.asarray(
            [sigma_xy, sigma_xy, sigma_theta]
        )
        return np.asarray(commands), np.asarray(true + noise), np.asarray(true)
