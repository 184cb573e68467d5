"""Animated GIF of a batch of robots driving to their reference poses (matplotlib only).

Each robot is drawn as its body (a disc of the robot's diameter, scaled up so
it shows at the pitch's scale) with a heading tick and a fading trail; its
reference is a cross with a heading arrow, green while the robot is within
the SPEC §6 arrival tolerances. Frames come from ``matplotlib.animation`` and
are encoded by its ``PillowWriter`` (Pillow is a dependency of matplotlib),
into a temporary file that then atomically replaces the target.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import jax
import numpy as np

from wmr_jax import controllers, metrics, simulation
from wmr_jax.io import atomic_write_bytes
from wmr_jax.maps import horizon_steps, spec_poses
from wmr_jax.params import Robot
from wmr_jax.simulation import DEFAULT_DT

__all__ = ["animate", "configure_parser", "run_cli", "write_gif"]


def write_gif(
    path: str | os.PathLike,
    poses: np.ndarray,
    refs: np.ndarray,
    *,
    dt: float = DEFAULT_DT,
    title: str = "",
    fps: int = 15,
    stride: int = 2,
    trail: int = 30,
    body_radius: float = 2.5,
    tol_r: float = metrics.DEFAULT_TOL_R,
    tol_theta: float = metrics.DEFAULT_TOL_THETA,
) -> Path:
    """Write an animated GIF of recorded runs, atomically.

    Args:
        path: the ``.gif`` to write.
        poses: ``(N, steps + 1, 3)`` recorded poses ``[x cm, y cm, θ rad]``.
        refs: ``(N, 3)`` their references.
        dt: control period of the samples, s (for the clock).
        title: text above the pitch.
        fps: frames per second of the GIF.
        stride: samples per frame (2 at 33 ms and 15 fps is real time).
        trail: samples of path drawn behind each robot.
        body_radius: drawn radius of each robot, cm.
        tol_r: arrival distance for the reference marker, cm.
        tol_theta: arrival folded-heading error, rad.

    Returns:
        The path written.
    """
    import matplotlib.animation as mpl_animation

    from wmr_jax.plotting import plt

    poses = np.asarray(poses, dtype=float)
    refs = np.asarray(refs, dtype=float)
    if poses.ndim != 3 or poses.shape[2] != 3 or refs.shape != (poses.shape[0], 3):
        raise ValueError(
            f"poses has shape {poses.shape} and refs {refs.shape}; "
            "allowed: poses (N, steps + 1, 3) with refs (N, 3)"
        )
    n, samples, _ = poses.shape
    arrived = np.asarray(metrics.arrived(poses, refs[:, None, :], tol_r=tol_r, tol_theta=tol_theta))
    colours = [plt.get_cmap("tab10")(i % 10) for i in range(n)]
    span = np.concatenate([poses[..., :2].reshape(-1, 2), refs[:, :2]])
    lo, hi = span.min(axis=0) - 8, span.max(axis=0) + 8

    fig, ax = plt.subplots(figsize=(6, 6 * (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9) + 0.3))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.set_title(title, fontsize=9)
    arrow = 2.5 * body_radius
    ax.quiver(
        refs[:, 0],
        refs[:, 1],
        arrow * np.cos(refs[:, 2]),
        arrow * np.sin(refs[:, 2]),
        angles="xy",
        scale_units="xy",
        scale=1,
        color="k",
        width=0.004,
    )
    markers = ax.scatter(refs[:, 0], refs[:, 1], marker="x", s=50, c="k", zorder=6)
    trails = [ax.plot([], [], "-", lw=1.0, color=c, alpha=0.6)[0] for c in colours]
    bodies = [plt.Circle((0, 0), body_radius, fc=c, ec="k", lw=0.6, zorder=4) for c in colours]
    for body in bodies:
        ax.add_patch(body)
    ticks = [ax.plot([], [], "k-", lw=1.4, zorder=5)[0] for _ in range(n)]
    clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=9)
    frames = list(range(0, samples, max(1, stride)))
    if frames[-1] != samples - 1:
        frames.append(samples - 1)

    def draw(k: int):
        for i in range(n):
            x, y, th = poses[i, k]
            bodies[i].center = (x, y)
            ticks[i].set_data(
                [x, x + body_radius * math.cos(th)], [y, y + body_radius * math.sin(th)]
            )
            start = max(0, k - trail)
            trails[i].set_data(poses[i, start : k + 1, 0], poses[i, start : k + 1, 1])
        done = arrived[:, k]
        markers.set_color(["tab:green" if d else "k" for d in done])
        clock.set_text(f"t = {k * dt:.2f} s   arrived {int(done.sum())}/{n}")
        return [*bodies, *ticks, *trails, markers, clock]

    anim = mpl_animation.FuncAnimation(fig, draw, frames=frames, blit=False)
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=f".{target.name}.") as tmp:
        tmp_path = Path(tmp) / "frames.gif"
        anim.save(tmp_path, writer=mpl_animation.PillowWriter(fps=fps))
        plt.close(fig)
        atomic_write_bytes(target, tmp_path.read_bytes())
    return target


def animate(
    path: str | os.PathLike,
    refs: Any = None,
    params: Any = None,
    *,
    n_robots: int = 8,
    seed: int = 0,
    controller: Any = controllers.SHIM_SUNG,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int | None = None,
    robot: Robot | None = None,
    velocity: str = "ideal",
    fps: int = 15,
    stride: int = 2,
) -> Path:
    """Simulate a batch of robots and write the GIF of them driving to their poses.

    Args:
        path: the ``.gif`` to write (atomically).
        refs: ``(N, 3)`` references; default ``n_robots`` random SPEC §6 poses.
        params: the controller's parameters (its defaults if ``None``).
        n_robots: number of random references when ``refs`` is ``None``.
        seed: seed of the random references.
        controller: a ``Controller`` or its registered name.
        init: ``(3,)`` or ``(N, 3)`` initial poses.
        dt: control period, s.
        steps: control periods; default the SPEC §6 horizon (6 s).
        robot: robot parameters; default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        fps: frames per second.
        stride: samples per frame.

    Returns:
        The path written.
    """
    if refs is None:
        if isinstance(n_robots, bool) or not isinstance(n_robots, int) or n_robots < 1:
            raise ValueError(f"n_robots = {n_robots!r} is not allowed; allowed: an integer >= 1")
        refs = spec_poses(seed, n_robots)
    for name, value in (("fps", fps), ("stride", stride)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= 1")
    steps = horizon_steps(dt) if steps is None else steps
    name = controllers.get_controller(controller).name
    with jax.enable_x64(True):  # as the maps (see maps.evaluate_poses)
        traj = simulation.batch_rollout(
            refs,
            params,
            init=init,
            dt=dt,
            steps=steps,
            robot=robot,
            velocity=velocity,
            controller=name,
        )
    refs = np.asarray(refs, dtype=float)
    if refs.ndim == 1:
        refs = np.broadcast_to(refs, (traj.poses.shape[0], 3))
    return write_gif(
        path,
        np.asarray(traj.poses),
        refs,
        dt=dt,
        title=f"{name}, {velocity} loop: {len(refs)} robots from (0, 0, 0°)",
        fps=fps,
        stride=stride,
    )


# ---------------------------------------------------------------- command line


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax animate`` to ``parser``."""
    parser.add_argument("--out", required=True, metavar="FILE.gif", help="GIF to write")
    parser.add_argument("--controller", default=controllers.SHIM_SUNG.name, help="controller name")
    parser.add_argument("--robots", type=int, default=8, help="random references (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the references (default 0)")
    parser.add_argument(
        "--paper", action="store_true", help="use the paper's seven Fig. 7 references instead"
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated time, s (default 4)")
    parser.add_argument("--fps", type=int, default=15, help="frames per second (default 15)")
    parser.set_defaults(func=run_cli)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax animate``; return the exit status."""
    from wmr_jax.waypoints import check_controllers, check_velocity

    if not str(args.out).lower().endswith(".gif"):
        raise ValueError(f"--out = {args.out!r} is not allowed; allowed: a path ending in .gif")
    name = check_controllers([args.controller])[0]
    velocity = check_velocity(args.velocity)
    if args.robots < 1:
        raise ValueError(f"--robots = {args.robots} is not allowed; allowed: an integer >= 1")
    if args.seed < 0:
        raise ValueError(f"--seed = {args.seed} is not allowed; allowed: an integer >= 0")
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise ValueError(f"--seconds = {args.seconds} is not allowed; allowed: a number > 0")
    if args.fps < 1:
        raise ValueError(f"--fps = {args.fps} is not allowed; allowed: an integer >= 1")
    refs = None
    if args.paper:
        from wmr_jax.paper import paper_refs

        refs = paper_refs()
    path = animate(
        args.out,
        refs,
        n_robots=args.robots,
        seed=args.seed,
        controller=name,
        velocity=velocity,
        steps=max(1, math.ceil(args.seconds / DEFAULT_DT)),
        fps=args.fps,
    )
    print(f"animation -> {path}")
    return 0
