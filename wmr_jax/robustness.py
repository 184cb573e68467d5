"""Robustness Monte Carlo: noisy pose measurements, a robot unlike its model, latency.

One closed loop per run, with four departures from the nominal one, all drawn
from a PRNG key (same key, same numbers):

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
its metrics those of ``wmr_jax.metrics`` (tested). Metrics stream through the
scan, so batches are bounded in memory.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import controllers, dynamics, law, metrics, simulation, velocity_loop
from wmr_jax.io import atomic_write_json, atomic_write_text, save_figure
from wmr_jax.maps import HORIZON_S, PoseMetrics, horizon_steps
from wmr_jax.params import Robot
from wmr_jax.simulation import DEFAULT_DT, Options, StepOutput

__all__ = [
    "DEFAULT_NOISE_DEG",
    "DEFAULT_NOISE_XY",
    "Disturbance",
    "draw_disturbances",
    "monte_carlo",
    "perturbed_metrics",
    "robustness_study",
    "configure_parser",
    "run_cli",
]

DEFAULT_NOISE_XY = (0.0, 0.25, 0.5, 1.0, 2.0)  # σ of x and y, cm
DEFAULT_NOISE_DEG = (0.0, 0.5, 1.0, 2.0, 4.0)  # σ of θ, degrees, paired with the above


# ---------------------------------------------------------------- streamed metrics
# The SPEC §6 metrics, folded period by period into a few scalars (as
# ``wmr_jax.sweep`` does for the undisturbed loop), plus the first arrival.

_V_DEAD_BAND = 1.0  # cm/s, as metrics.zigzag_count
_OMEGA_DEAD_BAND = 0.1  # rad/s, as metrics.zigzag_count


class _StreamState(NamedTuple):
    """Running SPEC §6 metrics of one run (all scalars)."""

    run_start: jax.Array  # first sample of the current run of arrived samples, or −1
    path: jax.Array
    peak_wheel: jax.Array
    v_sign: jax.Array  # last sign of v outside the dead band (0: none yet)
    omega_sign: jax.Array
    zigzag: jax.Array
    first: jax.Array  # first arrived sample, or −1


def _stream_init(dtype: Any) -> _StreamState:
    """Return the metrics of a run before its first control period."""
    zero = jnp.zeros((), dtype)
    izero = jnp.zeros((), jnp.int32)
    none = jnp.full((), -1, jnp.int32)
    return _StreamState(none, zero, zero, izero, izero, izero, none)


def _flip(last: jax.Array, x: jax.Array, dead_band: float) -> tuple[jax.Array, jax.Array]:
    """Return the updated last sign and whether ``x`` flipped it (``metrics._sign_changes``)."""
    sign = jnp.where(x > dead_band, 1, jnp.where(x < -dead_band, -1, 0)).astype(jnp.int32)
    flipped = (sign != 0) & (last != 0) & (sign != last)
    return jnp.where(sign != 0, sign, last), flipped.astype(jnp.int32)


def _stream_update(
    acc: _StreamState,
    k: jax.Array,
    pose: jax.Array,
    ref: jax.Array,
    out: StepOutput,
    *,
    tol_r: Any = metrics.DEFAULT_TOL_R,
    tol_theta: Any = metrics.DEFAULT_TOL_THETA,
) -> _StreamState:
    """Fold control period ``k`` into the metrics (SPEC §6).

    Args:
        acc: the metrics so far.
        k: index of the period, 0-based (int32).
        pose: ``(3,)`` pose at the end of the period.
        ref: ``(3,)`` reference.
        out: what the period reported (``closed_loop_step``).
        tol_r: arrival distance, cm.
        tol_theta: arrival folded-heading error, rad.
    """
    ok = metrics.arrived(pose, ref, tol_r=tol_r, tol_theta=tol_theta)
    run_start = jnp.where(ok, jnp.where(acc.run_start < 0, k, acc.run_start), -1)
    v_sign, v_flip = _flip(acc.v_sign, out.v, _V_DEAD_BAND)
    omega_sign, omega_flip = _flip(acc.omega_sign, out.omega, _OMEGA_DEAD_BAND)
    return _StreamState(
        run_start=run_start,
        path=acc.path + out.distance,
        peak_wheel=jnp.maximum(acc.peak_wheel, jnp.max(jnp.abs(out.wheel_speeds))),
        v_sign=v_sign,
        omega_sign=omega_sign,
        zigzag=acc.zigzag + v_flip + omega_flip,
        first=jnp.where(ok & (acc.first < 0), k, acc.first),
    )


def _stream_finish(
    acc: _StreamState, final_pose: jax.Array, ref: jax.Array, dt: jax.Array
) -> dict[str, jax.Array]:
    """Return the finished metrics of a run as a dict of scalars (``PoseMetrics`` fields)."""

    def time_of(sample):
        return jnp.where(sample >= 0, (sample + 1).astype(acc.path.dtype) * dt, jnp.inf)

    d = final_pose[:2] - ref[:2]
    final_distance = jnp.sqrt(jnp.sum(d * d))
    return {
        "arrival": time_of(acc.run_start),
        "path": acc.path,
        "peak_wheel": acc.peak_wheel,
        "zigzag": acc.zigzag,
        "final_distance": final_distance,
        "first_arrival": time_of(acc.first),
    }


class Disturbance(NamedTuple):
    """What makes one run differ from the nominal one (leading batch axes first).

    Attributes:
        ref: ``(3,)`` reference pose.
        noise: ``(steps, 3)`` measurement error added to the pose at each
            sample, ``[cm, cm, rad]``.
        mismatch: ``(3,)`` ``[left rim factor, right rim factor, mass factor]``:
            realised over commanded rim speed per wheel, and true over model
            body mass (1: no mismatch).
        delay: ``()`` 1.0 for a one-sample latency, 0.0 for none.
    """

    ref: jax.Array
    noise: jax.Array
    mismatch: jax.Array
    delay: jax.Array


def _realised(command: jax.Array, mismatch: jax.Array, robot: Robot) -> jax.Array:
    """Return the body velocity ``[v, ω]`` whose rims are the commanded ones, scaled."""
    rims = law.wheel_speeds(command[0], command[1], robot)  # [v_L, v_R]
    # Written as a correction of the command, so that factors of exactly 1
    # return it bit for bit (no rounding from the round trip through the rims).
    extra_left, extra_right = rims[0] * (mismatch[0] - 1), rims[1] * (mismatch[1] - 1)
    v = command[0] + 0.5 * (extra_left + extra_right)
    omega = command[1] + 0.5 * (extra_right - extra_left) / robot.half_track
    return jnp.stack([v, omega])


def _perturbed_single(spec: Disturbance, params, init, robot, dt, options: Options):
    """Run one pose under its ``Disturbance``, streaming the SPEC §6 metrics."""
    control = options.controller
    ref = spec.ref
    true_robot = robot.replace(body_mass=robot.body_mass * spec.mismatch[2])

    def body(carry, xs):
        state, held, acc = carry
        k, noise = xs
        v, omega = control.command(state.pose + noise, ref, params, temperature=None)
        fresh = jnp.stack([v, omega])
        applied = jnp.where(spec.delay > 0, held, fresh)
        target = _realised(applied, spec.mismatch, robot)
        if options.velocity == "ideal":
            pose = dynamics.arc_step(state.pose, target[0], target[1], dt)
            new_state = dynamics.RobotState(pose, target, state.integral)
            distance = jnp.abs(target[0]) * dt
        else:
            new_state, distance = velocity_loop.advance(
                state,
                target,
                true_robot,
                dt,
                substeps=options.substeps,
                wheel_limit=options.wheel_limit,
                model=robot,
            )
        rims = law.wheel_speeds(new_state.velocity[0], new_state.velocity[1], robot)
        out = StepOutput(applied[0], applied[1], jnp.int32(-1), rims, distance)
        acc = _stream_update(acc, k, new_state.pose, ref, out)
        return (new_state, fresh, acc), None

    carry = (simulation.initial_state(init), jnp.zeros((2,), init.dtype), _stream_init(ref.dtype))
    xs = (jnp.arange(options.steps, dtype=jnp.int32), spec.noise)
    (state, _, acc), _ = jax.lax.scan(body, carry, xs)
    return _stream_finish(acc, state.pose, ref, dt)


_perturbed_jit = simulation.EntryJit(
    simulation.batched(_perturbed_single), static_argnames=("options",)
)


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
    """Return the SPEC §6 metrics of a batch of disturbed runs.

    Args:
        disturbance: a ``Disturbance`` with a leading batch axis ``N`` on
            every field but ``delay`` (a scalar); ``noise`` is
            ``(N, steps, 3)`` and sets the number of periods.
        params: the controller's parameters (its defaults if ``None``).
        controller: a ``Controller`` or its registered name.
        init: ``(3,)`` initial pose (true and measured alike).
        dt: control period, s.
        robot: the nominal robot (the controller's model); default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        x64: compute in float64 (default; see ``maps.evaluate_poses`` why).

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays.

    Raises:
        ValueError: for misshapen or non-finite inputs and bad options.
    """
    with jax.enable_x64(bool(x64)):
        return _perturbed_metrics(disturbance, params, controller, init, dt, robot, velocity)


def _perturbed_metrics(disturbance, params, controller, init, dt, robot, velocity) -> PoseMetrics:
    refs = np.asarray(disturbance.ref, dtype=float)
    noise = np.asarray(disturbance.noise, dtype=float)
    mismatch = np.asarray(disturbance.mismatch, dtype=float)
    delay = np.asarray(disturbance.delay, dtype=float)
    if refs.ndim != 2 or refs.shape[1] != 3:
        raise ValueError(f"disturbance.ref has shape {refs.shape}; allowed: (N, 3)")
    n = refs.shape[0]
    if noise.ndim != 3 or noise.shape[0] != n or noise.shape[2] != 3 or noise.shape[1] < 1:
        raise ValueError(f"disturbance.noise has shape {noise.shape}; allowed: ({n}, steps, 3)")
    if mismatch.shape != (n, 3):
        raise ValueError(f"disturbance.mismatch has shape {mismatch.shape}; allowed: ({n}, 3)")
    if not (np.isfinite(noise).all() and np.isfinite(mismatch).all() and (mismatch > 0).all()):
        raise ValueError("disturbance.noise/mismatch must be finite, mismatch > 0")
    if delay.shape != () or float(delay) not in (0.0, 1.0):
        raise ValueError(f"disturbance.delay = {delay!r} is not allowed; allowed: 0.0 or 1.0")
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
    out = _perturbed_jit(spec, params, init, robot, dt, options=options)
    return PoseMetrics(**{f: np.asarray(out[f]) for f in PoseMetrics._fields})


# ---------------------------------------------------------------- Monte Carlo


def draw_disturbances(
    key: jax.Array,
    n: int,
    steps: int,
    *,
    radius_mismatch: float = 0.0,
    mass_mismatch: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw references, unit noise and mismatch factors from ``key``.

    Args:
        key: a ``jax.random`` key.
        n: number of runs.
        steps: control periods per run.
        radius_mismatch: each wheel's radius error ``δ ~ U(−m, m)``.
        mass_mismatch: the body-mass error ``μ ~ U(−m, m)``.

    Returns:
        ``(refs (n, 3), unit noise (n, steps, 3) ~ N(0, 1), mismatch (n, 3))``;
        references follow SPEC §6 (distance 5–80 cm, any bearing, any heading).
    """
    k_ref, k_noise, k_mis = jax.random.split(key, 3)
    u = np.asarray(jax.random.uniform(k_ref, (n, 3), dtype=jnp.float32), dtype=float)
    dist = 5.0 + 75.0 * u[:, 0]
    bearing = math.pi * (2 * u[:, 1] - 1)
    heading = math.pi * (2 * u[:, 2] - 1)
    refs = np.stack([dist * np.cos(bearing), dist * np.sin(bearing), heading], axis=-1)
    unit = np.asarray(jax.random.normal(k_noise, (n, steps, 3), dtype=jnp.float32), dtype=float)
    m = np.asarray(jax.random.uniform(k_mis, (n, 3), dtype=jnp.float32), dtype=float) * 2 - 1
    mismatch = 1.0 + m * np.array([radius_mismatch, radius_mismatch, mass_mismatch])
    return refs, unit, mismatch


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

    Args:
        key: ``jax.random`` key; the same key gives the same numbers.
        controller: a ``Controller`` or its registered name.
        params: its parameters (defaults if ``None``).
        n_runs: Monte Carlo runs per noise level.
        noise_xy: σ of the x and y measurement noise per level, cm.
        noise_deg: σ of the heading measurement noise per level, degrees.
        radius_mismatch: bound of each wheel's relative radius error.
        mass_mismatch: bound of the relative body-mass error (non-ideal loop).
        latency: apply each command one sample late.
        velocity: ``"ideal"`` or ``"nonideal"``.
        dt: control period, s.
        x64: compute in float64 (see ``maps.evaluate_poses``).

    Returns:
        One row per noise level: success rate, mean and median arrival of the
        successful runs, the fraction of runs ever arrived (if only for a
        sample) and their median first arrival, mean final distance, mean
        zig-zag count.
    """
    n_runs = _check_count("n_runs", n_runs)
    if len(noise_xy) != len(noise_deg) or not noise_xy:
        raise ValueError(
            f"noise_xy has {len(noise_xy)} levels and noise_deg {len(noise_deg)}; "
            "allowed: the same number, at least one"
        )
    for name, seq in (("noise_xy", noise_xy), ("noise_deg", noise_deg)):
        for value in seq:
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} level {value!r} is not allowed; allowed: >= 0")
    for name, value in (("radius_mismatch", radius_mismatch), ("mass_mismatch", mass_mismatch)):
        if not (math.isfinite(value) and 0 <= value < 1):
            raise ValueError(f"{name} = {value!r} is not allowed; allowed: 0 <= {name} < 1")
    name = controllers.get_controller(controller).name
    steps = horizon_steps(dt)
    refs, unit, mismatch = draw_disturbances(
        key, n_runs, steps, radius_mismatch=radius_mismatch, mass_mismatch=mass_mismatch
    )
    rows = []
    for sxy, sdeg in zip(noise_xy, noise_deg, strict=True):
        scale = np.array([sxy, sxy, math.radians(sdeg)])
        m = perturbed_metrics(
            Disturbance(refs, unit * scale, mismatch, np.float64(1.0 if latency else 0.0)),
            params,
            controller=name,
            dt=dt,
            velocity=velocity,
            x64=x64,
        )
        ok = m.success
        t = m.arrival[ok]
        rows.append(
            {
                "controller": name,
                "noise xy cm": float(sxy),
                "noise theta deg": float(sdeg),
                "radius mismatch": float(radius_mismatch),
                "mass mismatch": float(mass_mismatch),
                "latency": bool(latency),
                "runs": int(n_runs),
                "success": float(ok.mean()),
                "mean arrival s": float(t.mean()) if t.size else math.inf,
                "median arrival s": float(np.median(t)) if t.size else math.inf,
                "reached": float(np.isfinite(m.first_arrival).mean()),
                "median first arrival s": _median_finite(m.first_arrival),
                "mean final distance cm": float(m.final_distance.mean()),
                "mean zigzag": float(m.zigzag.mean()),
            }
        )
    return rows


def _median_finite(times: np.ndarray) -> float:
    finite = times[np.isfinite(times)]
    return float(np.median(finite)) if finite.size else math.inf


def _check_count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= 1")
    return int(value)


CONDITIONS = (
    ("noise", 0.0, 0.0, False),
    ("noise + mismatch", 0.03, 0.2, False),
    ("noise + mismatch + latency", 0.03, 0.2, True),
)


def robustness_study(
    out_dir: str | Path,
    *,
    seed: int = 0,
    controller_names: Sequence[str] | None = None,
    n_runs: int = 256,
    velocity: str = "ideal",
    noise_xy: Sequence[float] = DEFAULT_NOISE_XY,
    noise_deg: Sequence[float] = DEFAULT_NOISE_DEG,
) -> list[dict[str, Any]]:
    """Run the Monte Carlo for each controller and condition; write a figure and tables.

    Conditions: measurement noise alone; noise with ±3 % wheel-radius and
    ±20 % body-mass mismatch; and the same with one-sample latency. Each
    controller sees the same draws (one key per condition, from ``seed``).
    Writes ``robustness.png``, ``robustness.md`` and ``robustness.json``.

    Returns:
        The rows of every controller, condition and noise level.
    """
    from wmr_jax.paper import markdown_table
    from wmr_jax.plotting import plt
    from wmr_jax.waypoints import registered_names

    out = Path(out_dir)
    names = list(controller_names) if controller_names else registered_names()
    keys = jax.random.split(jax.random.PRNGKey(seed), len(CONDITIONS))
    rows = []
    for (label, radius, mass, latency), key in zip(CONDITIONS, keys, strict=True):
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
            ):
                rows.append({"condition": label, **row})

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    styles = ("-", "--", ":")
    for c, name in enumerate(names):
        for (label, *_), style in zip(CONDITIONS, styles, strict=True):
            sel = [r for r in rows if r["controller"] == name and r["condition"] == label]
            x = [r["noise xy cm"] for r in sel]
            colour = plt.get_cmap("tab10")(c)
            axes[0].plot(
                x,
                [r["success"] for r in sel],
                style,
                marker="o",
                color=colour,
                label=f"{name}, {label}",
            )
            axes[1].plot(x, [r["median arrival s"] for r in sel], style, marker="o", color=colour)
    axes[0].set_ylabel("success rate")
    axes[1].set_ylabel("median arrival time of successes [s]")
    for ax in axes:
        ax.set_xlabel(
            "measurement noise σ_xy [cm] (σ_θ = " + ", ".join(f"{d:g}" for d in noise_deg) + "°)"
        )
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle(
        f"Robustness, {velocity} loop: {n_runs} SPEC §6 poses per point, seed {seed}; "
        "mismatch ±3 % wheel radius, ±20 % mass; latency one sample",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, out / "robustness.png", dpi=110)
    plt.close(fig)
    atomic_write_json(
        out / "robustness.json",
        {"seed": seed, "velocity": velocity, "runs": n_runs, "horizon_s": HORIZON_S, "rows": rows},
    )
    columns = [
        "condition",
        "controller",
        "noise xy cm",
        "noise theta deg",
        "success",
        "mean arrival s",
        "median arrival s",
        "reached",
        "median first arrival s",
        "mean final distance cm",
        "mean zigzag",
    ]
    atomic_write_text(
        out / "robustness.md",
        f"Robustness Monte Carlo ({velocity} loop, seed {seed}, {n_runs} runs per row)\n\n"
        + markdown_table(rows, columns),
    )
    return rows


# ---------------------------------------------------------------- command line


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax robustness`` to ``parser``."""
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument("--runs", type=int, default=256, help="runs per noise level (256)")
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="controllers (repeatable; default: every registered one)",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.set_defaults(func=run_cli)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax robustness``; return the exit status."""
    from wmr_jax.paper import markdown_table
    from wmr_jax.waypoints import check_controllers, check_velocity

    if args.runs < 1:
        raise ValueError(f"--runs = {args.runs} is not allowed; allowed: an integer >= 1")
    if args.seed < 0:
        raise ValueError(f"--seed = {args.seed} is not allowed; allowed: an integer >= 0")
    names = check_controllers(args.controller)
    velocity = check_velocity(args.velocity)
    rows = robustness_study(
        args.out, seed=args.seed, controller_names=names, n_runs=args.runs, velocity=velocity
    )
    print(f"robustness -> {Path(args.out)}/robustness.png, robustness.md, robustness.json")
    columns = ["condition", "controller", "noise xy cm", "success", "median arrival s"]
    print(markdown_table(rows, columns), end="")
    return 0
