"""Animated GIF of a batch of robots driving to their reference poses.

Robots are discs with a heading tick and a trail; references crosses, green while arrived.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.io import atomic_write_bytes
from wmr_jax._src.report.figures import mpl_animation, plt, reference_arrows
from wmr_jax._src.sim import metrics
from wmr_jax._src.sim.rollout import DEFAULT_DT


def _pitch(poses: np.ndarray, refs: np.ndarray, title: str, arrow: float) -> tuple[Any, Any]:
    """``(fig, ax)`` framing the runs, with the references' heading arrows (``arrow`` cm)."""
    span = np.concatenate([poses[..., :2].reshape(-1, 2), refs[:, :2]])
    lo, hi = span.min(axis=0) - 8, span.max(axis=0) + 8
    # A pitch taller than wide is widened to a square: 6 in wide, at most 6.3 in high
    # with the title, so a frame is at most SQUARE_PIXELS and never a sliver.
    widen = max(0.0, (hi[1] - lo[1]) - (hi[0] - lo[0])) / 2
    lo, hi = lo - [widen, 0.0], hi + [widen, 0.0]
    fig, ax = plt.subplots(figsize=(6, 6 * (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9) + 0.3))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.set_title(title, fontsize=9, pad=16)
    reference_arrows(ax, refs, arrow)
    return fig, ax


# A GIF stores a frame's delay in hundredths of a second, as a 16-bit integer.
_MAX_FRAME_MS = 655_350


def frame_timing(dt: float, stride: int | None = None, speed: float = 1.0) -> tuple[int, int]:
    """``(stride, frame_ms)``: samples per frame and the GIF's delay per frame, ms.

    GIF delays are whole hundredths of a second (browsers play those under 20 ms
    at 100 ms): ``stride=None`` takes the smallest stride whose delay is within
    2 % of ``stride · dt / speed``.
    """
    dt = checks.check_dt(dt)
    speed = checks.check_number("speed", speed, unit="× real time")
    candidates = range(1, 10_000) if stride is None else [checks.check_int("stride", stride)]
    for k in candidates:
        want_ms = 1000.0 * k * dt / speed
        if not want_ms < _MAX_FRAME_MS + 5:  # would round to more than a GIF can store
            given = f"stride = {k!r}, " if stride is not None else ""
            raise ValueError(
                f"dt = {dt!r} s ({given}speed = {speed!r}) is not allowed: each frame would "
                f"show for {want_ms / 1000:.3g} s; allowed: at most {_MAX_FRAME_MS / 1000:g} s "
                "per frame (stride · dt / speed; a GIF stores a frame's delay in hundredths "
                "of a second as a 16-bit integer)"
            )
        delay_ms = 10 * max(2, round(want_ms / 10))
        if stride is not None or abs(delay_ms - want_ms) <= 0.02 * want_ms:
            return k, delay_ms
    raise ValueError(f"no frame stride plays dt = {dt} s at speed {speed} within 2 %")


# The frames a GIF is encoded from are all held in memory, 4 bytes a pixel.
MAX_FRAMES_BYTES = 2**30
# A square pitch's figure, in pixels (``_pitch``, at matplotlib's 100 dpi): the largest.
SQUARE_PIXELS = (600, 630)


def max_frames(pixels: tuple[int, int]) -> int:
    """The most frames of ``pixels`` a GIF is encoded from (``MAX_FRAMES_BYTES``)."""
    return MAX_FRAMES_BYTES // (4 * pixels[0] * pixels[1])


def check_frames(
    samples: int, stride: int, pixels: tuple[int, int], shown: str, remedy: str = ""
) -> int:
    """The number of frames of ``samples`` at ``stride``, if their pixels fit in memory.

    Raises:
        ValueError: naming ``shown`` (and ``remedy``, the way out), if they would hold
            more than ``MAX_FRAMES_BYTES``.
    """
    frames = len(range(0, samples - 1, stride)) + 1
    if frames > max_frames(pixels):
        held = frames * 4 * pixels[0] * pixels[1] / 2**30
        raise ValueError(
            f"{shown} makes {frames} frames of {pixels[0]}×{pixels[1]} pixels, {held:.1f} GiB "
            f"held in memory while the GIF is encoded; allowed: at most {max_frames(pixels)} "
            f"frames{remedy}"
        )
    return frames


def _save(anim: Any, fig: Any, path: str | os.PathLike, frame_ms: int) -> Path:
    """Encode the animation into a temporary file, then atomically replace ``path``."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=f".{target.name}.") as tmp:
        tmp_path = Path(tmp) / "frames.gif"
        # PillowWriter gives Pillow a delay of int(1000 / fps) ms per frame.
        anim.save(tmp_path, writer=mpl_animation.PillowWriter(fps=1000.0 / frame_ms))
        plt.close(fig)
        atomic_write_bytes(target, tmp_path.read_bytes())
    return target


def gif_path(name: str, path: Any) -> Path:
    """``path`` if it ends in ``.gif``, else refused naming ``name``."""
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if not isinstance(text, str) or Path(text).suffix.lower() != ".gif":
        shown = path if text is None else text
        raise ValueError(f"{name} {shown!r} is not allowed; allowed: a path ending in .gif")
    return Path(text)


def write_gif(
    path: str | os.PathLike,
    poses: np.ndarray,
    refs: np.ndarray,
    *,
    dt: float = DEFAULT_DT,
    title: str = "",
    speed: float = 1.0,
    stride: int | None = None,
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
        dt: control period of the samples, s.
        title: text above the pitch.
        speed, stride: playback speed (1: real time) and samples per frame (``frame_timing``).
        trail: samples of path drawn behind each robot.
        body_radius: drawn radius of each robot, cm.
        tol_r, tol_theta: arrival distance, cm, and folded-heading error, rad.

    Returns:
        The path written.
    """
    path = gif_path("path =", path)

    for name, value in (("poses", poses), ("refs", refs)):
        kind = checks.array_kind(value)
        if kind not in "iuf":
            held = {"b": "bools", "c": "complex numbers"}.get(kind, "values that are not numbers")
            raise ValueError(f"{name} holds {held}; allowed: real numbers [x cm, y cm, theta rad]")
    poses = np.asarray(poses, dtype=float)
    refs = np.asarray(refs, dtype=float)
    shaped = poses.ndim == 3 and poses.shape[2] == 3 and refs.shape == (poses.shape[0], 3)
    if not shaped or 0 in poses.shape:
        raise ValueError(
            f"poses has shape {poses.shape} and refs {refs.shape}; "
            "allowed: poses (N, steps + 1, 3) with refs (N, 3), N >= 1 and steps + 1 >= 1"
        )
    stride, frame_ms = frame_timing(dt, stride, speed)
    trail = checks.check_int("trail", trail, minimum=0)
    body_radius = checks.check_number("body_radius", body_radius, unit="cm")
    n, samples, _ = poses.shape
    arrived = np.asarray(metrics.arrived(poses, refs[:, None, :], tol_r=tol_r, tol_theta=tol_theta))
    colours = [plt.get_cmap("tab10")(i % 10) for i in range(n)]
    fig, ax = _pitch(poses, refs, title, 2.5 * body_radius)
    try:
        shown = f"poses of {samples} samples at stride {stride}"
        remedy = " (fewer samples, a larger stride or a higher speed)"
        check_frames(samples, stride, fig.canvas.get_width_height(), shown, remedy)
        markers = ax.scatter(refs[:, 0], refs[:, 1], marker="x", s=50, c="k", zorder=6)
        trails = [ax.plot([], [], "-", lw=1.0, color=c, alpha=0.6)[0] for c in colours]
        bodies = [plt.Circle((0, 0), body_radius, fc=c, ec="k", lw=0.6, zorder=4) for c in colours]
        for body in bodies:
            ax.add_patch(body)
        ticks = [ax.plot([], [], "k-", lw=1.4, zorder=5)[0] for _ in range(n)]
        # Above the pitch, where no robot can cover it.
        clock = ax.text(0.0, 1.01, "", transform=ax.transAxes, va="bottom", fontsize=9)

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
            clock.set_text(
                f"t = {k * dt:.2f} s (real time × {speed:g})   arrived {int(done.sum())}/{n}"
            )
            return [*bodies, *ticks, *trails, markers, clock]

        frames = [*range(0, samples - 1, stride), samples - 1]  # and always the last sample
        anim = mpl_animation.FuncAnimation(fig, draw, frames=frames, blit=False)
        return _save(anim, fig, path, frame_ms)
    finally:
        plt.close(fig)  # also when drawing or encoding failed


def run_title(controller: str, velocity: str, n: int, init: Any = (0.0, 0.0, 0.0)) -> str:
    """The title of a GIF of ``n`` runs of ``controller`` in the ``velocity`` loop from ``init``."""
    return f"{controller}, {velocity} loop: {n} robots from {_start(init)}"


def _start(init: Any) -> str:
    """The initial pose(s) for a title: ``(x, y, θ°)``, or "their initial poses"."""
    arr = np.asarray(init, dtype=float)
    if arr.ndim == 2 and not np.all(arr == arr[0]):
        return "their initial poses"
    x, y, theta = arr.reshape(-1, 3)[0]
    return f"({x:g}, {y:g}, {math.degrees(theta):g}°)"
