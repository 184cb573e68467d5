"""Closed-loop rollouts: the entry points ``rollout``, ``batch_rollout``, ``final_poses``.

Each checks its inputs in plain Python, then calls a jitted core of ``loops.py``.
"""

from __future__ import annotations

import functools
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    FINITE_ALLOWED,
    MAX_STEPS,
    as_float_tree,
    as_poses,
    batch_sizes,
    check_dt,
    check_int,
    check_substeps,
    check_temperature,
    common_batch_size,
    drop_shared_axes,
    float_dtype,
    is_traced,
    require_finite_runs,
    require_one_batch_size,
    require_unbatched,
)
from wmr_jax._src.model import velocity_loop
from wmr_jax._src.model.controllers.base import Controller, check_command_output, get_controller
from wmr_jax._src.model.controllers.polar import AT_GOAL, GOAL_EPS
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Robot, validate_robot
from wmr_jax._src.sim.loops import (
    DEFAULT_STEPS,
    DEFAULT_SUBSTEPS,
    VELOCITY_LOOPS,
    WHEEL_LIMITS,
    EntryJit,
    Options,
    batched,
    for_robot,
    scan_closed_loop,
)

DEFAULT_DT = 0.033


class Trajectory(NamedTuple):
    """A closed-loop run, sampled once per control period.

    Leading batch axes, if any, come first in every field.

    Attributes:
        poses: ``(steps + 1, 3)`` poses ``[x cm, y cm, θ rad]``, the initial one first.
        v: ``(steps,)`` linear-velocity command of the law over each period,
            cm/s (before a speed limiter, docs/model.md §4.2.2).
        omega: ``(steps,)`` angular-velocity command, rad/s.
        region: ``(steps,)`` int32 region label 0–3 of the command (docs/model.md §3).
        wheel_speeds: ``(steps, 2)`` rim speeds ``[v_L, v_R]`` of the robot
            at the end of each period, cm/s (after the speed limiter, if any).
        distance: ``(steps,)`` distance the centre travelled over each period, cm.
    """

    poses: jax.Array
    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


# choice: where the compute dtype spaces positions near the reference more than
# this apart, cm, a run that starts nearer its reference than the origin is
# computed in the reference's frame: the law does not depend on the origin but
# the rounding does (docs/model.md §3.8). Elsewhere the shift is 0, bit for bit.
GOAL_FRAME_SPACING = AT_GOAL / GOAL_EPS


def _goal_frame(ref: jax.Array, init: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Return ``(ref, init, shift)`` translated by ``-shift`` (``[x_r, y_r, 0]`` or zeros)."""
    far = jnp.max(jnp.abs(ref[:2]))
    coarse = jnp.finfo(ref.dtype).eps * far > GOAL_FRAME_SPACING
    nearer = jnp.max(jnp.abs(init[:2] - ref[:2])) < jnp.maximum(far, jnp.max(jnp.abs(init[:2])))
    shift = jnp.where(coarse & nearer, ref.at[2].set(0.0), jnp.zeros_like(ref))
    return ref - shift, init - shift, shift


def _world_frame(poses: jax.Array, shift: jax.Array) -> jax.Array:
    """Translate poses ``(..., 3)`` of the reference's frame back by ``shift``."""
    # where, not a plain sum: a shift of 0 would turn a −0.0 into 0.0.
    return jnp.where(jnp.any(shift != 0), poses + shift, poses)


def _trajectory(ref, params, init, robot, dt, options: Options) -> Trajectory:
    local_ref, local_init, shift = _goal_frame(ref, init)
    _, _, (poses, out) = scan_closed_loop(
        local_ref, params, local_init, robot, dt, options, record=True
    )
    poses = jnp.concatenate([init[None], _world_frame(poses, shift)], axis=0)
    return Trajectory(poses, out.v, out.omega, out.region, out.wheel_speeds, out.distance)


def _final_pose(ref, params, init, robot, dt, options: Options) -> jax.Array:
    local_ref, local_init, shift = _goal_frame(ref, init)
    final, _, _ = scan_closed_loop(local_ref, params, local_init, robot, dt, options)
    return _world_frame(final, shift)


_rollout_jit = EntryJit(_trajectory, static_argnames=("options",))
_batch_rollout_jit = EntryJit(batched(_trajectory), static_argnames=("options",))
_final_poses_jit = EntryJit(batched(_final_pose), static_argnames=("options",))


def make_options(
    *,
    steps: Any = DEFAULT_STEPS,
    velocity: Any = "ideal",
    controller: Any = SHIM_SUNG,
    temperature: Any = None,
    substeps: Any = DEFAULT_SUBSTEPS,
    wheel_limit: Any = "clip",
) -> Options:
    """Check the static options of a rollout and return them as ``Options``."""
    steps = check_int("steps", steps, 1, MAX_STEPS)
    if velocity not in VELOCITY_LOOPS:
        allowed = ", ".join(map(repr, VELOCITY_LOOPS))
        raise ValueError(f"velocity = {velocity!r} is not allowed; allowed: {allowed}")
    # The ideal loop has no sub-steps: any count passes (and is ignored).
    if velocity == "ideal":
        substeps = check_int("substeps", substeps, 1, MAX_STEPS)
    else:
        substeps = check_substeps(substeps)
    if wheel_limit not in WHEEL_LIMITS:
        allowed = ", ".join(map(repr, WHEEL_LIMITS))
        raise ValueError(f"wheel_limit = {wheel_limit!r} is not allowed; allowed: {allowed}")
    controller = get_controller(controller)
    if temperature is not None:
        value = check_temperature("temperature", temperature)
        if not controller.smooth:
            raise ValueError(
                f"temperature = {temperature!r} is not allowed for controller "
                f"{controller.name!r}; allowed: None (it has no smooth relaxation)"
            )
        temperature = value
    return Options(steps, velocity, controller, temperature, substeps, wheel_limit)


def _common_batch(refs, params, init, robot):
    """Check the batch sizes agree; return the arguments with size-1 (shared) axes removed."""
    n = require_one_batch_size(
        batch_sizes({"gains": params, "robot": robot}, {"refs": refs, "init": init})
    )
    if n is None:
        raise ValueError(
            "refs has shape (3,) and nothing else is batched; allowed: refs (N, 3), "
            "init (N, 3) or gains/robot fields of shape (N,)"
        )
    if n == 1:
        return refs, params, init, robot
    return drop_shared_axes((refs, params, init, robot))


def _which_controller(params: Any) -> str:
    """What to pass instead of ``params``, when it is the loop of a tuned file or its params."""
    from wmr_jax._src.model.controllers import registered_names
    from wmr_jax._src.sim.sensing.loop import ClosedLoop

    if isinstance(params, ClosedLoop):  # load_tuned's loop: its law's parameters, its controller
        name = getattr(params.controller, "name", params.controller)
        return (
            f" (a ClosedLoop runs as gains=loop.params, controller={name!r} and the robot it "
            "was tuned for, robot=loop.robot; with its estimator through "
            "wmr_jax.studies.evaluate_loop)"
        )
    owners = [n for n in registered_names() if isinstance(params, get_controller(n).params_type)]
    return f" (the parameters of {owners[0]!r}: pass controller={owners[0]!r})" if owners else ""


def prepare(
    refs,
    params,
    init,
    robot,
    dt,
    options: Options,
    *,
    batch: bool | None,
    entry: tuple[str, str] = ("rollout", "batch_rollout or final_poses"),
):
    """Check and convert every argument of a rollout entry point (before tracing).

    ``batch``: ``False`` for one run, ``None`` for a batch; ``entry``: the
    single and batched entry points the refusal of a batch in one run names.
    Returns ``(refs, params, init, robot, dt)``.
    """
    control = options.controller
    params = control.default_params() if params is None else params
    if not isinstance(params, control.params_type):
        raise ValueError(
            f"gains is a {type(params).__name__}; allowed: a {control.params_type.__name__} "
            f"for controller {control.name!r}{_which_controller(params)}"
        )
    params = as_float_tree(control.checked(params))
    check_command_output(control, params)
    robot = as_float_tree(validate_robot(Robot() if robot is None else robot))
    dt = check_dt(dt)
    if options.velocity == "nonideal":
        velocity_loop.check_stability(robot, dt, options.substeps)
    refs = as_poses("refs" if batch is not False else "ref", refs, batch=batch)
    init = as_poses("init", init, batch=None if batch is not False else False)
    if batch is False:
        for prefix, tree in (("gains", params), ("robot", robot)):
            allowed = f"a scalar in {entry[0]} (one run); use {entry[1]} for a batch"
            require_unbatched(tree, prefix, allowed)
    else:
        refs, params, init, robot = _common_batch(refs, params, init, robot)
    if not is_traced((params, robot, dt)):
        if control.check_robot is not None:
            control.check_robot(params, robot)
        if control.check_sampling is not None:
            control.check_sampling(params, dt)
    return refs, params, init, robot, jnp.asarray(dt, dtype=float_dtype())


def finite_result(
    poses: Any, result: Any, *, pose_axes: int = 1, allowed: str = FINITE_ALLOWED
) -> Any:
    """Return ``result``, or raise if a run left the floating-point range (traced poses pass)."""
    if is_traced(poses):
        return result
    axes = tuple(range(-pose_axes, 0))
    if isinstance(poses, jax.Array) and not poses.is_fully_addressable:
        # Spread over several processes: each checks the runs it holds.
        local = [np.asarray(_finite_runs(s.data, axes)) for s in poses.addressable_shards]
        finite = np.concatenate([f.reshape(-1) for f in local])
    else:
        finite = np.asarray(_finite_runs(poses, axes))
    require_finite_runs(finite, poses.dtype, allowed=allowed)
    return result


@functools.partial(jax.jit, static_argnums=1)
def _finite_runs(poses: jax.Array, axes: tuple[int, ...]) -> jax.Array:
    return jnp.isfinite(poses).all(axis=axes)


_STATIC = ("steps", "velocity", "controller", "temperature", "substeps", "wheel_limit")


def _static_options(arguments: dict[str, Any]) -> dict[str, Any]:
    return {name: arguments[name] for name in _STATIC}


def _run(jitted: EntryJit, args: tuple, options: Options, *, record: bool) -> Any:
    """Run ``jitted`` on an entry point's prepared ``args``; refuse a run that left the range."""
    if record:
        refs, params, init, robot, _ = args
        runs = common_batch_size({"gains": params, "robot": robot}, {"refs": refs, "init": init})
        require_memory(runs, options.steps, TRAJECTORY_RECORD, args)
    options = for_robot(options, args[3], args[4])
    out = jitted(*args, options=options)
    allowed = options.controller.finite_allowed(FINITE_ALLOWED)
    if record:
        return finite_result(out.poses, out, pose_axes=2, allowed=allowed)
    return finite_result(out, out, allowed=allowed)


_OPTIONS_DOC = """
        init: ``(3,)`` initial pose, or ``(N, 3)`` for a batch.
        dt: control period in s; commands are held over it (docs/model.md §4).
        steps: number of control periods (static).
        robot: robot parameters; default ``Robot()``. Its ``accel_max`` and
            ``angular_accel_max``, where above 0, limit how fast the ideal
            loop's commands change (docs/model.md §4.2.2).
        velocity: velocity loop between command and robot (static):
            ``"ideal"`` or ``"nonideal"`` (docs/model.md §4).
        controller: a ``Controller`` or its name (static); default Shim–Sung.
        temperature: ``None`` for the paper's law, or a smooth relaxation
            (``docs/model.md §3``).
        substeps: inner integration steps per period, non-ideal loop (static).
        wheel_limit: ``"clip"`` (per wheel) or ``"scale"`` (keep the curvature),
            non-ideal loop (static)."""


# What a Trajectory holds per run and period: a pose (3), v, ω, the two rim
# speeds and the distance (8 floats), and the region (an int32).
TRAJECTORY_RECORD = (8, 1)


def _memory_bytes(inputs: Any = None) -> int | None:
    """The memory a run on ``inputs`` may take: the host's, or its devices' (None: unknown)."""
    arrays = [x for x in jax.tree.leaves(inputs) if isinstance(x, jax.Array)]
    spans = [x.sharding.device_set for x in arrays if not is_traced(x)]
    devices = max(spans, key=len, default=None)
    if devices is None:
        default = jax.config.jax_default_device
        if isinstance(default, str):
            default = jax.local_devices(backend=default)[0]
        devices = {default if default is not None else jax.local_devices()[0]}
    local = [d for d in devices if d.process_index == jax.process_index()]
    if next(iter(devices)).platform == "cpu":
        try:
            memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, OSError, ValueError):  # not a POSIX system
            return None
    else:
        limits = [(d.memory_stats() or {}).get("bytes_limit") for d in local]
        if not limits or not all(limits):
            return None
        memory = sum(limits)
    return memory * len({d.process_index for d in devices})


def record_bytes(runs: int, steps: int, record: tuple[int, int]) -> int:
    """An upper bound of the bytes of ``runs`` records of ``(floats, int32s)`` per period."""
    floats, ints = record
    return runs * (steps + 1) * (floats * np.dtype(float_dtype()).itemsize + ints * 4)


def require_memory(runs: int, steps: int, record: tuple[int, int], inputs: Any = None) -> None:
    """Refuse, before it runs, a record of ``runs`` runs larger than the memory.

    XLA would allocate it whole, and an overcommitting host may stall rather
    than fail. ``record``: ``(floats, int32s)`` per run and period; ``inputs``
    place the run on their devices.
    """
    needed = record_bytes(runs, steps, record)
    memory = _memory_bytes(inputs)
    if memory is not None and needed > memory:
        raise ValueError(
            f"steps = {steps} for {runs} run(s) is not allowed: the record of the runs needs "
            f"{needed / 1e9:.3g} GB, more than the {memory / 1e9:.3g} GB of memory here; "
            "allowed: fewer steps or runs, or final_poses or sweep, which keep no trajectory"
        )


def rollout(
    ref: Any,
    gains: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Controller | str = SHIM_SUNG,
    temperature: float | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> Trajectory:
    """Drive the robot from ``init`` towards ``ref`` and record the whole run.

    Args:
        ref: ``(3,)`` reference pose ``[x cm, y cm, θ rad]``.
        gains: the controller's parameters; default ``Gains()`` (Fig. 7).
    {options}

    Returns:
        A ``Trajectory`` with ``steps + 1`` poses.

    Raises:
        ValueError: for out-of-range gains, non-finite or misshapen poses,
            ``steps < 1``, ``dt ≤ 0`` or an unknown option.
    """
    options = make_options(**_static_options(locals()))
    args = prepare(ref, gains, init, robot, dt, options, batch=False)
    return _run(_rollout_jit, args, options, record=True)


def batch_rollout(
    refs: Any,
    gains: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Controller | str = SHIM_SUNG,
    temperature: float | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> Trajectory:
    """Run ``rollout`` for a batch, in one call.

    Any of ``refs (N, 3)``, ``init (N, 3)`` and the leaves of ``gains`` or
    ``robot`` with shape ``(N,)`` are mapped over together; the rest are
    shared by every run. Sharded ``jax.Array`` inputs give sharded outputs.

    Args:
        refs: ``(N, 3)`` reference poses (or ``(3,)`` if something else is batched).
        gains: the controller's parameters, leaves scalar or ``(N,)``.
    {options}

    Returns:
        A ``Trajectory`` whose fields have a leading axis ``N``.
    """
    options = make_options(**_static_options(locals()))
    args = prepare(refs, gains, init, robot, dt, options, batch=None)
    return _run(_batch_rollout_jit, args, options, record=True)


def final_poses(
    refs: Any,
    gains: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Controller | str = SHIM_SUNG,
    temperature: float | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> jax.Array:
    """Return only the last pose of each run, ``(N, 3)``; memory O(N), not O(N·steps).

    Args:
        refs: ``(N, 3)`` reference poses (or ``(3,)`` if something else is batched).
        gains: the controller's parameters, leaves scalar or ``(N,)``.
    {options}
    """
    options = make_options(**_static_options(locals()))
    args = prepare(refs, gains, init, robot, dt, options, batch=None)
    return _run(_final_poses_jit, args, options, record=False)


for _entry in (rollout, batch_rollout, final_poses):
    # _OPTIONS_DOC starts with its own line break: no blank line inside Args.
    _entry.__doc__ = _entry.__doc__.replace("\n    {options}", _OPTIONS_DOC)
