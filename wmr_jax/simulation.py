"""Closed-loop rollouts: one pose in a ``lax.scan``, batches by one ``vmap``.

The public functions check their inputs in plain Python (SPEC §3 ranges,
shapes, finiteness, options) and then call a jitted core whose static
arguments are the shape-deciding options. Calling them again with the same
shapes and options reuses the compiled code.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import dynamics, law, velocity_loop
from wmr_jax.controllers import SHIM_SUNG, Controller, get_controller
from wmr_jax.params import Robot, check_feasible, validate_robot

__all__ = [
    "VELOCITY_LOOPS",
    "Options",
    "StepOutput",
    "Trajectory",
    "batch_rollout",
    "batched",
    "closed_loop_step",
    "initial_state",
    "final_poses",
    "jit_top_level",
    "rollout",
    "scan_closed_loop",
]

VELOCITY_LOOPS = ("ideal", "nonideal")
WHEEL_LIMITS = ("clip", "scale")
DEFAULT_SUBSTEPS = velocity_loop.DEFAULT_SUBSTEPS

DEFAULT_DT = 0.033
DEFAULT_STEPS = 150


class Trajectory(NamedTuple):
    """A closed-loop run, sampled once per control period.

    Leading batch axes, if any, come first in every field.

    Attributes:
        poses: ``(steps + 1, 3)`` poses ``[x cm, y cm, θ rad]``, the initial one first.
        v: ``(steps,)`` linear-velocity command applied over each period, cm/s.
        omega: ``(steps,)`` angular-velocity command, rad/s.
        region: ``(steps,)`` int32 region label 0–3 of the command (SPEC §3).
        wheel_speeds: ``(steps, 2)`` rim speeds ``[v_L, v_R]`` of the robot
            at the end of each period, cm/s.
        distance: ``(steps,)`` distance the centre travelled over each period, cm.
    """

    poses: jax.Array
    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


# ---------------------------------------------------------------- single pose


@dataclasses.dataclass(frozen=True)
class Options:
    """Shape- and code-deciding options of a rollout: static under ``jit``.

    Attributes:
        steps: number of control periods.
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (SPEC §4).
        controller: the pose controller (``wmr_jax.controllers.SHIM_SUNG``).
        temperature: ``None`` for the hard law, else its smooth relaxation.
        substeps: inner integration steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` each wheel command at ``±v_max`` or ``"scale"``
            both by one factor, keeping the curvature (non-ideal loop).
    """

    steps: int = DEFAULT_STEPS
    velocity: str = "ideal"
    controller: Controller = SHIM_SUNG
    temperature: float | None = None
    substeps: int = DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"


def initial_state(init: jax.Array) -> dynamics.RobotState:
    """Return the robot at rest at ``init`` ``(3,)``."""
    zeros = jnp.zeros((2,), init.dtype)
    return dynamics.RobotState(pose=init, velocity=zeros, integral=zeros)


class StepOutput(NamedTuple):
    """What one control period reports (one sample of a ``Trajectory``)."""

    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


def closed_loop_step(
    state: dynamics.RobotState,
    ref: jax.Array,
    params: Any,
    robot: Robot,
    dt: jax.Array,
    options: Options,
) -> tuple[dynamics.RobotState, StepOutput]:
    """Sample the controller at ``state`` and move the robot over one ``dt`` (SPEC §4).

    The single-pose building block of every rollout; scans of other kinds
    (streaming metrics, waypoints) are built from it.
    """
    control = options.controller
    v, omega = control.command(state.pose, ref, params, temperature=options.temperature)
    region = control.region_of(state.pose, ref, params)
    if options.velocity == "ideal":
        pose = dynamics.arc_step(state.pose, v, omega, dt)
        new_state = dynamics.RobotState(pose, jnp.stack([v, omega]), state.integral)
        distance = jnp.abs(v) * dt
    else:
        new_state, distance = velocity_loop.advance(
            state,
            jnp.stack([v, omega]),
            robot,
            dt,
            substeps=options.substeps,
            wheel_limit=options.wheel_limit,
        )
    rims = law.wheel_speeds(new_state.velocity[0], new_state.velocity[1], robot)
    return new_state, StepOutput(v, omega, region, rims, distance)


Fold = Callable[[Any, jax.Array, StepOutput], Any]


def scan_closed_loop(
    ref: jax.Array,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    fold: Fold | None = None,
    acc: Any = None,
    record: bool = False,
) -> tuple[jax.Array, Any, Any]:
    """Run ``options.steps`` control periods for one pose, streaming or recording.

    The same closed loop as scanning ``closed_loop_step``; the ideal velocity
    loop takes a faster route to it (see ``_ideal_loop``).

    Args:
        ref: ``(3,)`` reference pose.
        params: the controller's parameters.
        init: ``(3,)`` initial pose.
        robot: robot parameters.
        dt: control period, s.
        options: static rollout options.
        fold: ``fold(acc, pose, out) -> acc``, called after every period with
            the pose ``(3,)`` at its end and its ``StepOutput``: metrics that
            stream through the scan instead of storing the trajectory.
        acc: the initial value of the fold's accumulator (a pytree).
        record: also return every pose and ``StepOutput`` (stacked over steps).

    Returns:
        ``(final pose (3,), acc, (poses (steps, 3), StepOutput) or None)``.
    """
    if options.velocity == "ideal":
        return _ideal_loop(ref, params, init, robot, dt, options, fold, acc, record)
    return _generic_loop(ref, params, init, robot, dt, options, fold, acc, record)


def _remat(body: Callable) -> Callable:
    """Differentiate ``body`` by recomputing it, not by storing its intermediates.

    Reverse-mode through a scan otherwise keeps every intermediate of every
    step (some fifty arrays of ``N × steps`` for the ideal loop, gigabytes at
    ``N = 10⁵``); with this only the carry is kept per step and the backward
    pass recomputes the step, which is cheaper than writing it all to memory.
    No effect on evaluation without differentiation.
    """
    return jax.checkpoint(body, prevent_cse=False)


def _generic_loop(ref, params, init, robot, dt, options, fold, acc, record):
    def body(carry, _):
        (x, y, theta), velocity, integral, acc = carry
        state = dynamics.RobotState(jnp.stack([x, y, theta]), velocity, integral)
        new_state, out = closed_loop_step(state, ref, params, robot, dt, options)
        pose = new_state.pose
        if fold is not None:
            acc = fold(acc, pose, out)
        # The pose rides in the carry as three scalars: a batched (N, 3) carry
        # is rebuilt column by column every step, the law evaluated once per column.
        carry = ((pose[0], pose[1], pose[2]), new_state.velocity, new_state.integral, acc)
        return carry, ((pose, out) if record else None)

    start = initial_state(init)
    carry = ((init[0], init[1], init[2]), start.velocity, start.integral, acc)
    (final, _, _, acc), ys = jax.lax.scan(_remat(body), carry, None, length=options.steps)
    return jnp.stack(final), acc, ys


def _takes_frame(controller: Controller) -> bool:
    """Whether ``controller.command`` accepts ``frame=(x, y, cos θ, sin θ)``."""
    try:
        return "frame" in inspect.signature(controller.command).parameters
    except (TypeError, ValueError):
        return False


def _ideal_loop(ref, params, init, robot, dt, options, fold, acc, record):
    """The ideal velocity loop, arranged for speed; equal to scanning ``closed_loop_step``.

    Three things make it several times faster than the plain scan:

    * The position and heading ride as complex numbers ``x + i y`` and
      ``cos θ + i sin θ`` (``dynamics.arc_advance``), so no step recomputes
      the heading's cosine and sine for the law (``frame=`` of
      ``law.control``) or the arc. θ itself is carried too, for the pose.
    * The command of the next period is computed at the end of each period
      and carried as ``v + i ω``. XLA on the CPU compiles a step into one
      loop per output of the step and repeats in each whatever they share;
      carried this way, the law is evaluated in one loop only, and the
      step's outputs are four arrays, not nine.
    * The heading is renormalised every step by one Newton step towards
      ``|heading| = 1``, so rounding does not make it drift over long runs.
    """
    control = options.controller
    frame_kw = _takes_frame(control)

    def frame(position, heading):
        return position.real, position.imag, heading.real, heading.imag

    def command(position, heading, theta):
        pose = jnp.stack([position.real, position.imag, theta])
        extra = {"frame": frame(position, heading)} if frame_kw else {}
        v, omega = control.command(pose, ref, params, temperature=options.temperature, **extra)
        return jax.lax.complex(v, omega)

    def region(position, heading, theta):
        if control is SHIM_SUNG:
            err = law.polar_error(None, ref, frame=frame(position, heading))
            return law.region_label(err, params)
        return control.region_of(jnp.stack([position.real, position.imag, theta]), ref, params)

    def body(carry, _):
        position, heading, theta, cmd, acc = carry
        v, omega = cmd.real, cmd.imag
        if fold is not None or record:
            out = StepOutput(
                v,
                omega,
                region(position, heading, theta),
                law.wheel_speeds(v, omega, robot),
                jnp.abs(v) * dt,
            )
        position, heading = dynamics.arc_advance(position, heading, v, omega, dt)
        heading = heading * (1.5 - 0.5 * (heading.real**2 + heading.imag**2))
        theta = theta + omega * dt
        pose = jnp.stack([position.real, position.imag, theta])
        if fold is not None:
            acc = fold(acc, pose, out)
        carry = (position, heading, theta, command(position, heading, theta), acc)
        return carry, ((pose, out) if record else None)

    cos_0, sin_0 = dynamics.sin_cos(init[2])
    position = jax.lax.complex(init[0], init[1])
    heading = jax.lax.complex(cos_0, sin_0)
    carry = (position, heading, init[2], command(position, heading, init[2]), acc)
    (position, _, theta, _, acc), ys = jax.lax.scan(_remat(body), carry, None, length=options.steps)
    return jnp.stack([position.real, position.imag, theta]), acc, ys


def _trajectory(ref, params, init, robot, dt, options: Options) -> Trajectory:
    _, _, (poses, out) = scan_closed_loop(ref, params, init, robot, dt, options, record=True)
    poses = jnp.concatenate([init[None], poses], axis=0)
    return Trajectory(poses, out.v, out.omega, out.region, out.wheel_speeds, out.distance)


def _final_pose(ref, params, init, robot, dt, options: Options) -> jax.Array:
    final, _, _ = scan_closed_loop(ref, params, init, robot, dt, options)
    return final


# ---------------------------------------------------------------- batching


def _batch_axes(tree: Any, single_ndim: int) -> Any:
    """Map each leaf to 0 if it carries a leading batch axis, else ``None``."""
    return jax.tree.map(lambda leaf: 0 if jnp.ndim(leaf) > single_ndim else None, tree)


def batched(single: Callable) -> Callable:
    """Lift ``single(ref, params, init, robot, dt, options)`` to batched inputs.

    A leading axis on ``ref``/``init`` (beyond ``(3,)``) or on any leaf of
    ``params``/``robot`` (beyond a scalar) is mapped over; the others are
    shared. This is the one place where ``vmap`` is applied.
    """

    def run(ref, params, init, robot, dt, options):
        in_axes = (
            _batch_axes(ref, 1),
            _batch_axes(params, 0),
            _batch_axes(init, 1),
            _batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: single(*a, options), in_axes=in_axes)(
            ref, params, init, robot, dt
        )

    return run


# XLA:CPU targets 256-bit vectors unless told otherwise; on a CPU with AVX-512
# the rollouts run about 20 % faster with 512-bit ones (measured on AMD Zen 4).
# Other backends ignore the option, and a CPU without AVX-512 uses what it has.
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": "512"}


def jit_top_level(fn: Callable, **kwargs: Any) -> Callable:
    """Return ``jax.jit(fn, **kwargs)`` compiled with ``COMPILER_OPTIONS``.

    For a function of the caller's that runs rollouts inside (a loss, its
    gradient): only the outermost ``jit`` can carry compiler options.
    """
    try:
        return jax.jit(fn, compiler_options=COMPILER_OPTIONS, **kwargs)
    except TypeError:  # a JAX without per-function compiler options
        return jax.jit(fn, **kwargs)


class EntryJit:
    """A jitted entry point, compiled with ``COMPILER_OPTIONS`` when called at top level.

    JAX accepts compiler options only on a top-level ``jit``; inside a
    caller's own ``jit``/``grad``/``vmap`` (traced arguments) the same
    function runs as a plain nested ``jit``.
    """

    def __init__(self, fn: Callable, **kwargs: Any):
        self.nested = jax.jit(fn, **kwargs)
        self.top = jit_top_level(fn, **kwargs)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        traced = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(args))
        return (self.nested if traced else self.top)(*args, **kwargs)

    def lower(self, *args: Any, **kwargs: Any) -> Any:
        """Lower the top-level version (for inspecting the compiled program)."""
        return self.top.lower(*args, **kwargs)

    def _cache_size(self) -> int:
        return self.top._cache_size() + self.nested._cache_size()


_rollout_jit = EntryJit(_trajectory, static_argnames=("options",))
_batch_rollout_jit = EntryJit(batched(_trajectory), static_argnames=("options",))
_final_poses_jit = EntryJit(batched(_final_pose), static_argnames=("options",))


# ---------------------------------------------------------------- boundary checks


def float_dtype() -> Any:
    """Return JAX's default float dtype (float64 when ``jax_enable_x64`` is on)."""
    return jnp.result_type(float)


def as_poses(name: str, value: Any, *, batch: bool | None) -> jax.Array:
    """Return ``value`` as a float pose array after checking shape and finiteness.

    Args:
        name: the argument's name, for error messages.
        value: a pose ``(3,)`` or, where ``batch`` allows, a batch ``(N, 3)``.
        batch: ``False`` for a single pose, ``True`` for ``(N, 3)``, ``None`` for either.

    Raises:
        ValueError: naming the argument, its shape or bad value, and what is allowed.
    """
    if isinstance(value, jax.core.Tracer):
        return value
    if isinstance(value, jax.Array):
        arr = value.astype(float_dtype()) if value.dtype != float_dtype() else value
        host = None
    else:
        try:
            host = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be numbers [x cm, y cm, theta rad]: {err}") from err
        arr = None
    shape = tuple((arr if arr is not None else host).shape)
    allowed = {False: "(3,)", True: "(N, 3) with N >= 1", None: "(3,) or (N, 3)"}[batch]
    ok_ndim = {False: (1,), True: (2,), None: (1, 2)}[batch]
    if len(shape) not in ok_ndim or shape[-1] != 3 or (len(shape) == 2 and shape[0] == 0):
        raise ValueError(f"{name} has shape {shape}; allowed: {allowed} [x cm, y cm, theta rad]")
    if arr is not None:
        # Concrete, but maybe closed over by a caller's jit: check it eagerly.
        with jax.ensure_compile_time_eval():
            finite = bool(jnp.all(jnp.isfinite(arr)))
    else:
        finite = bool(np.isfinite(host).all())
    if not finite:
        flat = np.asarray(arr if arr is not None else host).reshape(-1, 3)
        row = int(np.flatnonzero(~np.isfinite(flat).all(axis=1))[0])
        where = f"{name}[{row}]" if len(shape) == 2 else name
        raise ValueError(f"{where} = {flat[row].tolist()} is not finite; allowed: finite numbers")
    return arr if arr is not None else jnp.asarray(host, dtype=float_dtype())


def _check_int(name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= {minimum}")
    return int(value)


def make_options(
    *,
    steps: Any = DEFAULT_STEPS,
    velocity: Any = "ideal",
    controller: Any = SHIM_SUNG,
    temperature: Any = None,
    substeps: Any = DEFAULT_SUBSTEPS,
    wheel_limit: Any = "clip",
) -> Options:
    """Check the static options of a rollout and return them as ``Options``.

    Raises:
        ValueError: naming the option, its value and what is allowed.
    """
    steps = _check_int("steps", steps)
    substeps = _check_int("substeps", substeps)
    if velocity not in VELOCITY_LOOPS:
        raise ValueError(f"velocity = {velocity!r} is not allowed; allowed: {VELOCITY_LOOPS}")
    if wheel_limit not in WHEEL_LIMITS:
        raise ValueError(f"wheel_limit = {wheel_limit!r} is not allowed; allowed: {WHEEL_LIMITS}")
    controller = get_controller(controller)
    if temperature is not None:
        try:
            value = float(temperature)
        except (TypeError, ValueError):
            value = float("nan")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(
                f"temperature = {temperature!r} is not allowed; allowed: None or a number > 0"
            )
        if not controller.smooth:
            raise ValueError(
                f"temperature = {temperature!r} is not allowed for controller "
                f"{controller.name!r}; allowed: None (it has no smooth relaxation)"
            )
        temperature = value
    return Options(steps, velocity, controller, temperature, substeps, wheel_limit)


def check_dt(dt: Any) -> float:
    """Return ``dt`` as a float after checking it is finite and positive."""
    if isinstance(dt, jax.core.Tracer):
        return dt
    try:
        value = float(dt)
    except (TypeError, ValueError) as err:
        raise ValueError(f"dt = {dt!r} is not allowed; allowed: a number > 0 s") from err
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"dt = {dt!r} is not allowed; allowed: a finite number > 0 s")
    return value


def _batch_size(refs: jax.Array, params: Any, init: jax.Array, robot: Robot) -> int:
    sizes = {}
    if refs.ndim == 2:
        sizes["refs"] = refs.shape[0]
    if init.ndim == 2:
        sizes["init"] = init.shape[0]
    for prefix, tree in (("gains", params), ("robot", robot)):
        for key, leaf in jax.tree_util.tree_leaves_with_path(tree):
            if jnp.ndim(leaf) == 1:
                sizes[f"{prefix}{jax.tree_util.keystr(key)}"] = jnp.shape(leaf)[0]
    if not sizes:
        raise ValueError(
            "refs has shape (3,) and nothing else is batched; allowed: refs (N, 3), "
            "init (N, 3) or gains/robot fields of shape (N,)"
        )
    if len(set(sizes.values())) > 1:
        listed = ", ".join(f"{k}: {v}" for k, v in sizes.items())
        raise ValueError(f"batch sizes differ ({listed}); allowed: one common N")
    return next(iter(sizes.values()))


def as_float_tree(tree: Any) -> Any:
    """Convert every concrete leaf to an array of the default float dtype.

    Python floats, NumPy scalars and arrays then all reach ``jit`` with one
    signature, so changing a gain's type does not recompile.
    """
    dtype = float_dtype()

    def convert(leaf):
        if isinstance(leaf, jax.core.Tracer):
            return leaf
        if isinstance(leaf, jax.Array):
            return leaf if leaf.dtype == dtype else leaf.astype(dtype)
        # Host values stay NumPy: jit transfers them with the call, which is
        # much cheaper than one device transfer per leaf here.
        return np.asarray(leaf, dtype)

    return jax.tree.map(convert, tree)


def prepare(refs, params, init, robot, dt, options: Options, *, batch: bool | None):
    """Check and convert every argument of a rollout entry point (before tracing).

    Args:
        batch: ``False`` for one run (``refs`` and ``init`` ``(3,)``), ``None``
            for a batch over any of refs/init/params/robot.

    Returns:
        ``(refs, params, init, robot, dt)`` ready for the jitted cores.
    """
    control = options.controller
    params = control.default_params() if params is None else params
    if not isinstance(params, control.params_type):
        raise ValueError(
            f"gains is a {type(params).__name__}; allowed: a {control.params_type.__name__} "
            f"for controller {control.name!r}"
        )
    params = as_float_tree(control.validate(params))
    robot = as_float_tree(validate_robot(Robot() if robot is None else robot))
    dt = check_dt(dt)
    if options.velocity == "nonideal":
        velocity_loop.check_stability(robot, dt, options.substeps)
    refs = as_poses("refs" if batch is not False else "ref", refs, batch=batch)
    init = as_poses("init", init, batch=None if batch is not False else False)
    if batch is not False:
        _batch_size(refs, params, init, robot)
    leaves = jax.tree.leaves((params, robot))
    concrete = not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)
    if concrete and control is SHIM_SUNG:
        check_feasible(params, robot, warn=True, stacklevel=4)  # legal, but warned (SPEC §3)
    return refs, params, init, robot, jnp.asarray(dt, dtype=float_dtype())


# ---------------------------------------------------------------- entry points

_OPTIONS_DOC = """
        init: ``(3,)`` initial pose, or ``(N, 3)`` for a batch.
        dt: control period in s; commands are held over it (SPEC §4).
        steps: number of control periods (static).
        robot: robot parameters; default ``Robot()``.
        velocity: velocity loop between command and robot (static):
            ``"ideal"`` or ``"nonideal"`` (SPEC §4).
        controller: a ``Controller`` or its name (static); default Shim–Sung.
        temperature: ``None`` for the paper's law, or a smooth relaxation
            (see ``wmr_jax.law``).
        substeps: inner integration steps per period, non-ideal loop (static).
        wheel_limit: ``"clip"`` (per wheel) or ``"scale"`` (keep the curvature),
            non-ideal loop (static)."""


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
    options = make_options(
        steps=steps,
        velocity=velocity,
        controller=controller,
        temperature=temperature,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    args = prepare(ref, gains, init, robot, dt, options, batch=False)
    return _rollout_jit(*args, options=options)


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
    options = make_options(
        steps=steps,
        velocity=velocity,
        controller=controller,
        temperature=temperature,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    args = prepare(refs, gains, init, robot, dt, options, batch=None)
    return _batch_rollout_jit(*args, options=options)


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
    options = make_options(
        steps=steps,
        velocity=velocity,
        controller=controller,
        temperature=temperature,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    args = prepare(refs, gains, init, robot, dt, options, batch=None)
    return _final_poses_jit(*args, options=options)


for _entry in (rollout, batch_rollout, final_poses):
    _entry.__doc__ = _entry.__doc__.replace("    {options}", _OPTIONS_DOC)
