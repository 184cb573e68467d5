"""Robustness Monte Carlo: noisy pose measurements, a robot unlike its model, latency.

The protocol is ``docs/model.md §7``. One closed loop per run, with four
departures from the nominal one, all drawn from a PRNG key (same key, same
numbers):

* **Pose-measurement noise.** The controller sees ``pose + n_k`` with
  ``n_k ~ N(0, diag(σ_xy², σ_xy², σ_θ²))``, independent at every sample.
  Arrival is judged on the true pose.
* **Wheel-radius mismatch.** The controller converts rim speeds to wheel
  turns with the nominal radius, so a wheel of radius ``r (1 + δ)`` moves its
  rim ``1 + δ`` times as fast as commanded; each wheel has its own ``δ``.
  choice: in the non-ideal loop the scaled rim set points go to the wheel-speed
  controller, as if it regulated the speeds it believes it measures; the
  ``±V_max`` limit is then applied to the scaled set points.
* **Mass mismatch** (non-ideal loop only; the ideal loop has no dynamics): the
  robot's body mass is ``M (1 + μ)`` while the wheel-speed controller's model
  keeps ``M`` (``velocity_loop.advance(model=...)``).
* **One-sample latency.** The command computed at sample ``k`` is applied over
  period ``k + 1`` (zero over the first period).

With no noise, no mismatch and no latency the run is the nominal rollout, and
its metrics those of ``docs/model.md §6`` (tested). The metrics stream through
the scan (``metrics.stream_update``), so batches are bounded in memory. The
engine returns values; ``wmr_jax.report`` draws and writes them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks, controllers, dynamics, loops, metrics
from wmr_jax._src import rollout as simulation
from wmr_jax._src.controllers import shim_sung as law
from wmr_jax._src.loops import Options, StepOutput
from wmr_jax._src.maps import PoseMetrics
from wmr_jax._src.params import Robot
from wmr_jax._src.poses import horizon_steps, sample_poses
from wmr_jax._src.rollout import DEFAULT_DT

__all__ = [
    "STANDARD_CONDITIONS",
    "DEFAULT_NOISE_DEG",
    "DEFAULT_NOISE_XY",
    "ROBUSTNESS_CONDITIONS",
    "Disturbance",
    "draw_disturbances",
    "monte_carlo",
    "perturbed_metrics",
    "robustness_study",
    "sample_disturbance",
    "standard_conditions",
    "disturbed_rollout",
    "disturbed_run",
]

DEFAULT_NOISE_XY = (0.0, 0.25, 0.5, 1.0, 2.0)  # σ of x and y, cm
DEFAULT_NOISE_DEG = (0.0, 0.5, 1.0, 2.0, 4.0)  # σ of θ, degrees, paired with the above

# The study's conditions (docs/model.md §7):
# (label, wheel-radius mismatch bound, body-mass mismatch bound, one-sample latency).
ROBUSTNESS_CONDITIONS = (
    ("noise", 0.0, 0.0, False),
    ("noise + mismatch", 0.03, 0.2, False),
    ("noise + mismatch + latency", 0.03, 0.2, True),
)


# The standard conditions of docs/model.md §7, with the nominal model first:
# (label, σ_xy cm, σ_θ degrees, one-sample latency). Ideal loop.
STANDARD_CONDITIONS = (
    ("nominal", 0.0, 0.0, False),
    ("latency", 0.0, 0.0, True),
    ("noise", 0.5, 1.0, False),
    ("both", 0.5, 1.0, True),
)


class Disturbance(NamedTuple):
    """What makes one run differ from the nominal one (leading batch axes first).

    Attributes:
        ref: ``(3,)`` reference pose ``[cm, cm, rad]``.
        noise: ``(steps, 3)`` measurement error added to the pose at each
            sample, ``[cm, cm, rad]``.
        mismatch: ``(3,)`` ``[left rim factor, right rim factor, mass factor]``:
            realised over commanded rim speed per wheel, and true over model
            body mass (1: no mismatch).
        delay: ``()`` 1.0 for a one-sample latency, 0.0 for none (per run,
            or one value shared by a batch).
    """

    ref: jax.Array
    noise: jax.Array
    mismatch: jax.Array
    delay: jax.Array


# ---------------------------------------------------------------- one disturbed run


def _realised(command: jax.Array, mismatch: jax.Array, robot: Robot) -> tuple[jax.Array, ...]:
    """Return the body velocity ``(v, ω)`` whose rims are the commanded ``v + i ω``, scaled."""
    v, omega = command.real, command.imag
    rims = law.wheel_speeds(v, omega, robot)  # [v_L, v_R]
    # Written as a correction of the command, so that factors of exactly 1
    # return it bit for bit (no rounding from the round trip through the rims).
    extra_left, extra_right = rims[0] * (mismatch[0] - 1), rims[1] * (mismatch[1] - 1)
    return (
        v + 0.5 * (extra_left + extra_right),
        omega + 0.5 * (extra_right - extra_left) / robot.half_track,
    )


def _measured(pose: loops.SplitPose, noise: jax.Array) -> loops.SplitPose:
    """The pose the controller sees: ``pose + noise`` (exactly ``pose`` for zero noise)."""
    cos_n, sin_n = dynamics.sin_cos(noise[2])
    return loops.SplitPose(
        pose.position + jax.lax.complex(noise[0], noise[1]),
        pose.heading * jax.lax.complex(cos_n, sin_n),
        pose.theta + noise[2],
    )


def disturbed_run(
    spec: Disturbance,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    fold: loops.Fold | None = None,
    acc: Any = None,
    record: bool = False,
) -> tuple[jax.Array, Any, Any]:
    """Run one pose under its ``Disturbance`` (``docs/model.md §7``); the one disturbed loop.

    The robustness Monte Carlo and the robust tuner both run this. Over
    period ``k`` the robot moves under the command computed from the
    measurement at sample ``k`` (``delay`` 0) or ``k − 1`` (``delay`` 1; zero
    over the first period), its rims scaled by the wheel-radius factors; in
    the non-ideal loop the true robot's mass is ``M`` times the mass factor
    while the wheel controller keeps the nominal model. Arrival is judged
    on the true pose.

    Args:
        spec: the disturbance of this run (no batch axes; ``noise (steps, 3)``).
        params: the controller's parameters.
        init: ``(3,)`` initial pose.
        robot: the nominal robot (the controller's model).
        dt: control period, s.
        options: static options; ``options.temperature`` selects the relaxed law.
        fold: ``fold(acc, true pose (a loops.SplitPose), StepOutput) -> acc``
            after every period.
        acc: the fold's initial accumulator.
        record: also return every true pose ``(steps, 3)`` and ``StepOutput``.

    Returns:
        ``(final true pose (3,), acc, (poses, outputs) or None)``.
    """
    ref = spec.ref
    true_robot = robot.replace(body_mass=robot.body_mass * spec.mismatch[2])

    def body(carry, noise_next):
        pose, wheel, fresh, held, acc = carry
        applied = jnp.where(spec.delay > 0, held, fresh)
        target = _realised(applied, spec.mismatch, robot)
        pose, wheel, rims, distance = loops.advance_period(
            pose, wheel, target, true_robot, dt, options, model=robot
        )
        out = StepOutput(applied.real, applied.imag, jnp.int32(-1), rims, distance)
        if fold is not None:
            acc = fold(acc, pose, out)
        command = loops.split_command(_measured(pose, noise_next), ref, params, options)
        return (pose, wheel, command, fresh, acc), ((pose.stacked(), out) if record else None)

    pose = loops.SplitPose.of(init)
    first = loops.split_command(_measured(pose, spec.noise[0]), ref, params, options)
    # The measurement at sample k + 1 is taken at the end of period k; the
    # last period's is never used.
    later = jnp.concatenate([spec.noise[1:], jnp.zeros_like(spec.noise[:1])])
    carry = (pose, loops.initial_wheel(init, options), first, jnp.zeros_like(first), acc)
    step = loops.remat(body) if options.remat else body
    (pose, _, _, _, acc), ys = jax.lax.scan(step, carry, later)
    return pose.stacked(), acc, ys


def _perturbed_single(spec: Disturbance, params, init, robot, dt, options: Options):
    """Run one pose under its ``Disturbance``, streaming the ``docs/model.md §6`` metrics."""
    ref = spec.ref
    thresholds = metrics.Thresholds()

    def fold(acc, pose, out):
        return metrics.stream_update(acc, pose.stacked(), ref, out, thresholds, frame=pose.frame())

    final, acc, _ = disturbed_run(
        spec, params, init, robot, dt, options, fold=fold, acc=metrics.stream_start(ref.dtype)
    )
    result = metrics.stream_result(acc, dt)
    d = final[:2] - ref[:2]
    return {
        "arrival": result["arrival_time"],
        "path": result["path_length"],
        "peak_wheel": result["peak_wheel_speed"],
        "zigzag": result["zigzags"],
        "final_distance": jnp.sqrt(jnp.sum(d * d)),
        "first_arrival": result["first_arrival"],
    }


def batched_disturbed(single):
    """Lift ``single(spec, params, init, robot, dt, options)`` over a batch of disturbances.

    Every field of ``spec`` carries the batch axis, except a scalar ``delay``
    (shared); ``params`` and ``robot`` leaves may carry it too.
    """

    def run(spec, params, init, robot, dt, options):
        spec_axes = Disturbance(0, 0, 0, 0 if jnp.ndim(spec.delay) == 1 else None)
        in_axes = (spec_axes, loops.batch_axes(params, 0), None, loops.batch_axes(robot, 0), None)
        return jax.vmap(lambda *a: single(*a, options), in_axes=in_axes)(
            spec, params, init, robot, dt
        )

    return run


_perturbed_jit = loops.EntryJit(batched_disturbed(_perturbed_single), static_argnames=("options",))


def perturbed_metrics(
    disturbance: Disturbance,
    params: Any = None,
    *,
    controller: Any = controllers.SHIM_SUNG,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    x64: bool = True,
) -> PoseMetrics:
    """Return the ``docs/model.md §6`` metrics of a batch of disturbed runs.

    Args:
        disturbance: a ``Disturbance`` with a leading batch axis ``N`` on
            every field but ``delay`` (a scalar); ``noise`` is
            ``(N, steps, 3)`` and sets the number of periods.
        params: the controller's parameters (its defaults if ``None``).
        controller: a ``Controller`` or its registered name.
        init: ``(3,)`` initial pose (true and measured alike), ``[cm, cm, rad]``.
        dt: control period, s.
        robot: the nominal robot (the controller's model); default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        x64: compute in float64 (default): the polar baselines' bearing is
            rounding noise near the goal in float32.

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays, ``first_arrival`` included.

    Raises:
        ValueError: for misshapen or non-finite inputs and bad options.
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        return _perturbed_metrics(disturbance, params, controller, init, dt, robot, velocity)


def _checked_disturbance(disturbance: Disturbance) -> tuple[np.ndarray, ...]:
    """Return the fields of ``disturbance`` as float arrays after checking them."""
    if not isinstance(disturbance, Disturbance):
        raise ValueError(
            f"disturbance = {type(disturbance).__name__} is not allowed; "
            "allowed: a Disturbance (sample_disturbance returns one)"
        )
    refs, noise, mismatch, delay = (
        checks.real_array(f"disturbance.{field}", value, "real numbers (no bools or strings)")
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
    if delay.shape not in ((), (n,)) or not np.all((delay == 0.0) | (delay == 1.0)):
        raise ValueError(
            f"disturbance.delay = {delay!r} is not allowed; allowed: 0.0 or 1.0, or ({n},) of them"
        )
    return refs, noise, mismatch, delay


def _prepared(disturbance, params, controller, init, dt, robot, velocity) -> tuple:
    """Check a batch of disturbances and the run's settings; return the jitted core's arguments."""
    refs, noise, mismatch, delay = _checked_disturbance(disturbance)
    options = simulation.make_options(
        steps=noise.shape[1], velocity=velocity, controller=controller
    )
    refs_j, params, init, robot, dt = simulation.prepare(
        refs, params, init, robot, dt, options, batch=None
    )
    if np.ndim(init) != 1:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,)")
    dtype = dt.dtype
    spec = Disturbance(
        refs_j,
        jnp.asarray(noise, dtype),
        jnp.asarray(mismatch, dtype),
        jnp.asarray(delay, dtype),
    )
    return (spec, params, init, robot, dt), options


def _perturbed_metrics(disturbance, params, controller, init, dt, robot, velocity) -> PoseMetrics:
    args, options = _prepared(disturbance, params, controller, init, dt, robot, velocity)
    out = _perturbed_jit(*args, options=options)
    metrics = PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})
    checks.require_finite_runs(
        np.isfinite(metrics.final_distance),
        args[-1].dtype,
        allowed="disturbances, gains and dt that keep the sampled law stable "
        "(docs/model.md §4, §7)",
    )
    return metrics


def _disturbed_trajectory(spec, params, init, robot, dt, options):
    _, _, (poses, out) = disturbed_run(spec, params, init, robot, dt, options, record=True)
    return {"poses": jnp.concatenate([init[None], poses]), "v": out.v, "omega": out.omega}


_trajectory_jit = loops.EntryJit(
    batched_disturbed(_disturbed_trajectory), static_argnames=("options",)
)


def disturbed_rollout(
    disturbance: Disturbance,
    params: Any = None,
    *,
    controller: Any = controllers.SHIM_SUNG,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    x64: bool = True,
) -> dict[str, np.ndarray]:
    """Return the true poses and applied commands of disturbed runs (``docs/model.md §7``).

    Args: as for ``perturbed_metrics``.

    Returns:
        ``{"poses": (N, steps + 1, 3) true poses, the initial one first,
        "v": (N, steps) cm/s, "omega": (N, steps) rad/s}``: the command
        applied over each period (zero over the first one under latency).
    """
    with jax.enable_x64(checks.check_bool("x64", x64)):
        args, options = _prepared(disturbance, params, controller, init, dt, robot, velocity)
        out = _trajectory_jit(*args, options=options)
        return {name: np.asarray(value) for name, value in out.items()}


# ---------------------------------------------------------------- Monte Carlo


# Beyond these a level no longer describes a sensor: σ_θ of 2π already makes
# the measured heading uniform, and σ_xy of 10 km is far beyond any workspace.
_LEVEL_LIMITS = {"noise_xy": 1e6, "noise_theta": 2 * math.pi, "latency": 1.0}


def _check_draw(key: Any, steps: Any, n: int | None, **levels: Any) -> None:
    """Check a draw's key, length and levels where they are concrete (traced ones pass).

    ``n`` is the number of runs (``None`` if unknown): a level is a scalar or ``(n,)``.
    """
    checks.check_key("key", key)
    checks.check_int("steps", steps)
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

    The one source of disturbances: the Monte Carlo and the robust tuner's
    loss (inside ``jit``) both draw here. Each level may be a scalar or one
    value per run ``(N,)``.

    Args:
        key: a ``jax.random`` key.
        refs: ``(N, 3)`` reference poses.
        steps: control periods per run (static).
        noise_xy: σ of the x and y measurement noise, cm.
        noise_theta: σ of the heading measurement noise, rad.
        latency: probability that a run has a one-sample latency (0 or 1:
            none or all).
        radius_mismatch: each wheel's radius error ``δ ~ U(−m, m)``.
        mass_mismatch: the body-mass error ``μ ~ U(−m, m)``.

    Returns:
        A ``Disturbance`` with ``noise (N, steps, 3) ~ N(0, diag(σ_xy², σ_xy², σ_θ²))``
        drawn independently at every sample, ``mismatch (N, 3)`` and
        ``delay (N,)`` in {0, 1}.
    """
    if not checks.is_traced(refs):
        checked = checks.as_poses("refs", refs, batch=True)
        # Draw in the poses' own float dtype (float32 poses give the same draws
        # in a float64 session); other numbers in JAX's default one.
        own = getattr(refs, "dtype", None)
        floating = own is not None and jnp.issubdtype(own, jnp.floating)
        refs = jnp.asarray(refs) if floating else checked
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
    """Draw references, unit noise and mismatch factors from ``key`` (via ``sample_disturbance``).

    Args:
        key: a ``jax.random`` key.
        n: number of runs.
        steps: control periods per run.
        radius_mismatch: each wheel's radius error ``δ ~ U(−m, m)``.
        mass_mismatch: the body-mass error ``μ ~ U(−m, m)``.

    Returns:
        ``(refs (n, 3), unit noise (n, steps, 3) ~ N(0, 1), mismatch (n, 3))``;
        the references follow the evaluation set of ``docs/model.md §6``
        (distance 5–80 cm, any bearing, any heading), drawn by ``sample_poses``.
    """
    n = checks.check_int("n", n)
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


def _check_levels(noise_xy: Any, noise_deg: Any) -> tuple[list[float], list[float]]:
    """Return the noise levels as lists of floats after checking them."""
    levels = []
    for name, seq in (("noise_xy", noise_xy), ("noise_deg", noise_deg)):
        if isinstance(seq, (str, bytes)) or np.ndim(seq) != 1:
            raise ValueError(
                f"{name} = {seq!r} is not allowed; allowed: a sequence of levels, one per row"
            )
        levels.append(list(seq))
    noise_xy, noise_deg = levels
    if len(noise_xy) != len(noise_deg) or not noise_xy:
        raise ValueError(
            f"noise_xy has {len(noise_xy)} levels and noise_deg {len(noise_deg)}; "
            "allowed: the same number, at least one"
        )
    limits = (("noise_xy", noise_xy, "cm", 1e6), ("noise_deg", noise_deg, "degrees", 360.0))
    for name, seq, unit, high in limits:
        for i, value in enumerate(seq):
            checks.check_number(f"{name}[{i}]", value, closed=True, high=high, unit=unit)
    return [float(x) for x in noise_xy], [float(x) for x in noise_deg]


def _summary_row(m: PoseMetrics) -> dict[str, Any]:
    """Return success, arrival, first arrival, final distance and zig-zag of a batch."""
    ok = m.success
    t = m.arrival[ok]
    return {
        "success": float(ok.mean()),
        "mean arrival s": float(t.mean()) if t.size else math.inf,
        "median arrival s": float(np.median(t)) if t.size else math.inf,
        "reached": float(np.isfinite(m.first_arrival).mean()),
        "median first arrival s": _median_finite(m.first_arrival),
        "mean final distance cm": float(m.final_distance.mean()),
        "mean zigzag": float(m.zigzag.mean()),
    }


def _median_finite(times: np.ndarray) -> float:
    finite = times[np.isfinite(times)]
    return float(np.median(finite)) if finite.size else math.inf


def monte_carlo(
    key: jax.Array,
    *,
    controller: Any = controllers.SHIM_SUNG,
    params: Any = None,
    n_runs: int = 256,
    noise_xy: Sequence[float] = DEFAULT_NOISE_XY,
    noise_deg: Sequence[float] = DEFAULT_NOISE_DEG,
    radius_mismatch: float = 0.0,
    mass_mismatch: float = 0.0,
    latency: bool = False,
    velocity: str = "ideal",
    dt: float = DEFAULT_DT,
    x64: bool = True,
) -> list[dict[str, Any]]:
    """Return success and arrival against noise level for one controller and condition.

    Every noise level reuses the same references, unit noise and mismatch
    (common random numbers), so differences between levels are the noise's.
    Each run lasts the ``docs/model.md §6`` horizon (6 s).

    Args:
        key: ``jax.random`` key; the same key gives the same numbers.
        controller: a ``Controller`` or its registered name.
        params: its parameters (defaults if ``None``).
        n_runs: Monte Carlo runs per noise level.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        radius_mismatch: bound of each wheel's relative radius error, ``[0, 1)``.
        mass_mismatch: bound of the relative body-mass error (non-ideal loop),
            ``[0, 1)``.
        latency: apply each command one sample late.
        velocity: ``"ideal"`` or ``"nonideal"``.
        dt: control period, s.
        x64: compute in float64 (see ``perturbed_metrics``).

    Returns:
        One row per noise level: success rate, mean and median arrival of the
        successful runs (s), the fraction of runs ever arrived (if only for a
        sample) and their median first arrival (s), mean final distance (cm),
        mean zig-zag count.

    Raises:
        ValueError: for a bad count, noise level, mismatch bound or option.
    """
    n_runs = checks.check_int("n_runs", n_runs)
    checks.check_key("key", key)
    noise_xy, noise_deg = _check_levels(noise_xy, noise_deg)
    if not isinstance(latency, (bool, np.bool_)):
        raise ValueError(f"latency = {latency!r} is not allowed; allowed: True or False")
    for name, value in (("radius_mismatch", radius_mismatch), ("mass_mismatch", mass_mismatch)):
        checks.check_number(name, value, high=1.0, closed=True)
    if mass_mismatch > 0 and velocity == "ideal":
        raise ValueError(
            f"mass_mismatch = {mass_mismatch!r} is not allowed with velocity = 'ideal', whose "
            "robot has no mass; allowed: 0, or velocity = 'nonideal'"
        )
    name = controllers.get_controller(controller).name
    refs, unit, mismatch = draw_disturbances(
        key, n_runs, horizon_steps(dt), radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch
    )
    delay = np.float64(1.0 if latency else 0.0)
    rows = []
    for sxy, sdeg in zip(noise_xy, noise_deg, strict=True):
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        m = perturbed_metrics(
            Disturbance(refs, unit * scale, mismatch, delay),
            params,
            controller=name,
            dt=dt,
            velocity=velocity,
            x64=x64,
        )
        condition = {
            "controller": name,
            "noise xy cm": float(sxy),
            "noise theta deg": float(sdeg),
            "radius mismatch": float(radius_mismatch),
            "mass mismatch": float(mass_mismatch),
            "latency": bool(latency),
            "runs": int(n_runs),
        }
        rows.append({**condition, **_summary_row(m)})
    return rows


def robustness_study(
    *,
    seed: int = 0,
    controller_names: Sequence[str] | None = None,
    n_runs: int = 256,
    velocity: str = "ideal",
    noise_xy: Sequence[float] = DEFAULT_NOISE_XY,
    noise_deg: Sequence[float] = DEFAULT_NOISE_DEG,
    x64: bool = True,
) -> list[dict[str, Any]]:
    """Run the Monte Carlo for each controller and condition (``docs/model.md §7``).

    Conditions (``ROBUSTNESS_CONDITIONS``): measurement noise alone; noise
    with ±3 % wheel-radius and ±20 % body-mass mismatch (the latter in the
    non-ideal loop only: the ideal one has no mass); and the same with
    one-sample latency. Each controller sees the same draws (one key per
    condition, from ``seed``). ``wmr_jax.report.write_robustness`` draws and
    writes the rows.

    Args:
        seed: PRNG seed, an integer in ``[0, 2³² − 1]``.
        controller_names: registered controllers; default every one.
        n_runs: Monte Carlo runs per noise level.
        velocity: ``"ideal"`` or ``"nonideal"``.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        x64: compute in float64 (see ``perturbed_metrics``).

    Returns:
        The rows of every condition, controller and noise level (in that
        order), each ``monte_carlo``'s row with its ``"condition"`` first.
    """
    seed = checks.check_int("seed", seed, 0, 2**32 - 1)
    names = controllers.controller_names(controller_names)
    keys = jax.random.split(jax.random.PRNGKey(seed), len(ROBUSTNESS_CONDITIONS))
    rows = []
    for (label, radius, mass, latency), key in zip(ROBUSTNESS_CONDITIONS, keys, strict=True):
        if velocity == "ideal":
            mass = 0.0  # the ideal loop has no mass: the rows say so rather than ±20 %
        for name in names:
            for row in monte_carlo(
                key,
                controller=name,
                n_runs=n_runs,
                noise_xy=noise_xy,
                noise_deg=noise_deg,
                radius_mismatch=radius,
                mass_mismatch=mass,
                latency=latency,
                velocity=velocity,
                x64=x64,
            ):
                rows.append({"condition": label, **row})
    return rows


def standard_conditions(
    params_by_name: dict[str, Any],
    refs: Any,
    key: jax.Array,
    *,
    controller: Any = controllers.SHIM_SUNG,
    dt: float = DEFAULT_DT,
    x64: bool = True,
) -> list[dict[str, Any]]:
    """Judge parameter sets under the standard conditions of ``docs/model.md §7`` (hard law).

    Every set and condition sees the same unit noise (common random numbers,
    drawn from ``key`` by ``sample_disturbance``); ideal loop, horizon 6 s.

    Args:
        params_by_name: ``{label: params}`` of ``controller``.
        refs: ``(N, 3)`` reference poses (held-out poses of ``docs/model.md §6``).
        key: ``jax.random`` key of the noise.
        controller: a ``Controller`` or its registered name.
        dt: control period, s.
        x64: compute in float64.

    Returns:
        One row per (condition, set): ``condition``, ``gains``, ``success``,
        ``mean arrival s`` and ``median arrival s`` of the successful runs
        (``inf`` if none), ``mean final distance cm``, ``runs``.
    """
    if not isinstance(params_by_name, Mapping) or not params_by_name:
        raise ValueError(
            f"params_by_name = {params_by_name!r:.80} is not allowed; allowed: a dict of "
            "label -> parameters, at least one"
        )
    with jax.enable_x64(checks.check_bool("x64", x64)):  # not rounded to float32 first
        refs = np.asarray(checks.as_poses("refs", refs, batch=True), dtype=float)
    steps = horizon_steps(dt)
    # The unit noise depends on the key and the number of runs only (drawn in
    # the session's dtype, as before): the poses themselves stay in float64.
    unit = sample_disturbance(key, np.zeros_like(refs), steps, noise_xy=1.0, noise_theta=1.0)
    noise = np.asarray(unit.noise, dtype=float)
    ones = np.ones((len(refs), 3))
    rows = []
    for label, sxy, sdeg, latency in STANDARD_CONDITIONS:
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        spec = Disturbance(refs, noise * scale, ones, np.float64(1.0 if latency else 0.0))
        for name, params in params_by_name.items():
            m = perturbed_metrics(spec, params, controller=controller, dt=dt, x64=x64)
            summary = _summary_row(m)
            rows.append(
                {
                    "condition": label,
                    "gains": name,
                    "success": summary["success"],
                    "mean arrival s": summary["mean arrival s"],
                    "median arrival s": summary["median arrival s"],
                    "mean final distance cm": summary["mean final distance cm"],
                    "runs": len(refs),
                }
            )
    return rows
