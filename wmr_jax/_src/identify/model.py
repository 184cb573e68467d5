"""The robot a log is fitted with, replayed through the one closed-loop step (docs/model.md §10).

The firmware turns the logged command ``(v, ω)`` into rim set points with the
half-track it believes (``BASE``'s, ``L₀``); each true wheel moves its rim
``1 + δ_L`` and ``1 + δ_R`` times its set point; the body moves with the true
half-track ``L``; the wheel-speed loop of §4.3 (an exact model, torques not
saturated) makes each velocity a first-order lag of time constant
``1 / speed_gain``; a command sent at sample ``k`` acts from sample ``k + m``.

A replay is ``loops.scan_closed_loop`` with two plug-ins: ``LOGGED``, a
controller whose command is the logged one (the reference that ``aim`` hands
it), and ``TrueRobot``, a disturbance that turns the firmware's set points
into the true robot's motion. So the same step that runs every closed loop
replays a log, and a log written by a closed loop replays bit for bit.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src.model.controllers.base import Controller
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim import loops
from wmr_jax._src.sim.sensing import disturbances

# The largest latency the fit profiles over, in samples.
MAX_LATENCY = 10
SUBSTEPS = loops.DEFAULT_SUBSTEPS
# The replayed robot's torques and rims are not limited (the model assumes
# neither saturates; a log that drives a robot into its limits breaks it).
_UNLIMITED = 1e9


def _logged_command(pose, ref, params, *, temperature=None, frame=None):
    """The command of a log: the reference's first two entries, ``(v, ω)``."""
    del pose, params, temperature, frame
    return ref[..., 0], ref[..., 1]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class _NoParams:
    """The logged controller has no parameters."""


LOGGED = Controller(
    name="logged", command=_logged_command, params_type=_NoParams, validate=lambda p: p
)


class TrueRobot(NamedTuple):
    """How the true robot follows the firmware's set points: a disturbance of the one step.

    Attributes:
        noise: ``(steps, 3)`` measurement noise (zeros in a replay).
        scale: ``(2,)`` ``[1 + δ_L, 1 + δ_R]``, rim over set point.
        base_half_track: ``L₀``, the half-track the firmware converts with, cm.
        delay: the latency ``m`` in samples (a float holding an integer).
        half_track: the true half-track ``L``, cm.
        speed_gain: the true wheel loop's gain, 1/s.
    """

    noise: jax.Array
    scale: jax.Array
    base_half_track: jax.Array
    delay: jax.Array
    half_track: jax.Array
    speed_gain: jax.Array

    def realised(self, command: jax.Array, robot: Robot) -> tuple[jax.Array, jax.Array]:
        """The body velocity of the true rims of ``command`` (``v + i ω``)."""
        del robot  # the firmware's half-track is the base's, the body's the true one
        v, omega = command.real, command.imag
        left = (v - self.base_half_track * omega) * self.scale[0]
        right = (v + self.base_half_track * omega) * self.scale[1]
        return 0.5 * (left + right), 0.5 * (right - left) / self.half_track

    def true_robot(self, robot: Robot) -> Robot:
        """The robot that moves: ``robot`` with the true half-track and wheel-loop gain."""
        return robot.replace(half_track=self.half_track, speed_gain=self.speed_gain)

    def measurement(self, pose: loops.SplitPose, noise: jax.Array) -> Any:
        return disturbances.measurement(pose, noise)


def fitted_robot(base: Robot, half_track: Any, speed_gain: Any) -> Robot:
    """The robot a replay moves: ``base`` with the true half-track and wheel-loop gain.

    Its torques and rim speeds are not limited and it has no integral action,
    so the wheel loop is the exact first-order lag of docs/model.md §4.3.
    """
    return base.replace(
        half_track=half_track,
        speed_gain=speed_gain,
        integral_gain=0.0,
        com_offset=0.0,
        torque_max=_UNLIMITED,
        v_max=_UNLIMITED,
    )


def replay_options(steps: int, max_delay: int = MAX_LATENCY) -> loops.Options:
    """The options of a replay: the non-ideal loop, ``max_delay`` commands in flight."""
    return loops.Options(
        steps=steps,
        velocity="nonideal",
        controller=LOGGED,
        substeps=SUBSTEPS,
        wheel_integral=False,
        wheel_coriolis=False,
        remat=False,
        max_delay=max(1, max_delay),
    )


def replay(
    commands: jax.Array,
    init: jax.Array,
    robot: Robot,
    scale: jax.Array,
    base_half_track: Any,
    delay: Any,
    dt: Any,
    *,
    max_delay: int = MAX_LATENCY,
) -> jax.Array:
    """Replay ``commands`` ``(steps, 2)`` from rest at ``init`` ``(3,)``: the poses ``(steps, 3)``.

    Pose ``k`` is the true pose at the end of period ``k`` (sample ``k + 1``).
    ``robot`` is the true robot (``fitted_robot``).
    """
    steps = commands.shape[0]
    dtype = init.dtype
    refs = jnp.concatenate([commands, jnp.zeros((steps, 1), dtype)], axis=1)
    refs = jnp.concatenate([refs, refs[-1:]], axis=0)  # the one after the last is never used
    spec = TrueRobot(
        jnp.zeros((steps, 3), dtype),
        jnp.asarray(scale, dtype),
        jnp.asarray(base_half_track, dtype),
        jnp.asarray(delay, dtype),
        robot.half_track,
        robot.speed_gain,
    )
    _, _, records = loops.scan_closed_loop(
        refs[0],
        _NoParams(),
        init,
        robot,
        jnp.asarray(dt, dtype),
        replay_options(steps, max_delay),
        disturbance=spec,
        aim=lambda k: refs[k],
        fold=lambda k, pose, out: k + 1,
        acc=jnp.int32(0),
        record=True,
    )
    return records[0]
