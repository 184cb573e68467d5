"""Paths and wheel-speed figures; the one module that imports matplotlib (others use ``plt``)."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; no display is assumed
# What the report modules take from here: matplotlib after its backend is set.
import matplotlib.animation as mpl_animation  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from wmr_jax._src import checks  # noqa: E402
from wmr_jax._src.io import save_figure  # noqa: E402
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R  # noqa: E402

__all__ = ["ListedColormap", "Patch", "mpl_animation", "plt"]  # matplotlib, as above


def image_formats() -> list[str]:
    """The file endings a figure can be saved as (``png``, ``pdf``, ``svg``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return sorted(FigureCanvasBase.get_supported_filetypes())


@contextlib.contextmanager
def closed_after(*args: Any, **kwargs: Any) -> Iterator[tuple[Any, Any]]:
    """``plt.subplots(*args, **kwargs)`` as ``(fig, axes)``, closed on leaving, error or not."""
    fig, axes = plt.subplots(*args, **kwargs)
    try:
        yield fig, axes
    finally:
        plt.close(fig)


def built(draw: Any, *args: Any, **kwargs: Any) -> Any:
    """``plt.subplots(*args, **kwargs)`` drawn by ``draw(fig, axes)``; closed if drawing fails."""
    fig, axes = plt.subplots(*args, **kwargs)
    try:
        draw(fig, axes)
    except BaseException:
        plt.close(fig)
        raise
    return fig


def save_closed(fig: Any, path: Any, **kwargs: Any) -> Any:
    """Save ``fig`` atomically (``io.save_figure``) and close it, saved or not; return the path."""
    try:
        return save_figure(fig, path, **kwargs)
    finally:
        plt.close(fig)


def reference_arrows(ax: Any, poses: np.ndarray, length: float, color: Any = "k", **kw) -> Any:
    """Draw each pose's heading as an arrow ``length`` cm long from its position."""
    tips = length * np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=-1)
    style = {"angles": "xy", "scale_units": "xy", "scale": 1, "width": 0.004}
    ax.quiver(*poses[:, :2].T, *tips.T, color=color, **style, **kw)
    return tips


def plot_paths(
    ax: Any,
    paths: Sequence[np.ndarray],
    refs: np.ndarray,
    *,
    color: Any = None,
    label: str | None = None,
    linestyle: str = "-",
    heading_spacing: float = 6.0,
    arrow_length: float = 3.0,
    mark_refs: bool = True,
) -> None:
    """Draw robot paths with heading arrows, and the references as marked poses.

    Args:
        ax: a matplotlib Axes.
        paths: each ``(steps + 1, 3)`` poses in cm, cm, rad.
        refs: ``(M, 3)`` reference poses, ``M ≥ len(paths)``: the paths' own,
            then any more to mark (waypoints).
        color: one colour for all paths (default: one per path).
        label: legend label of the paths (with one colour per path, each is
            entered by its reference and ``label`` is the legend's title).
        linestyle: matplotlib line style.
        heading_spacing: draw the heading every this many cm of travel.
        arrow_length: heading arrow length, cm.
        mark_refs: draw the references (a cross and a heading arrow).
    """
    allowed = "finite poses [x cm, y cm, θ rad], (steps + 1, 3)"
    paths = [checks.real_array(f"paths[{i}]", p, allowed) for i, p in enumerate(paths)]
    for i, poses in enumerate(paths):
        if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) == 0:
            raise ValueError(f"paths[{i}] has shape {poses.shape}; allowed: (steps + 1, 3)")
        # matplotlib would leave a gap at NaN: a run that left the range would look short.
        checks.require(f"paths[{i}]", poses, np.isfinite(poses), allowed)
    refs = checks.real_array("refs", refs, "reference poses [x cm, y cm, θ rad], (M, 3)")
    if mark_refs and (refs.ndim != 2 or refs.shape[1] != 3 or len(refs) < len(paths)):
        raise ValueError(
            f"refs has shape {refs.shape}; allowed: (M, 3) with M >= {len(paths)}, one per path "
            "and any more to mark"
        )
    checks.check_number("heading_spacing", heading_spacing, unit="cm")
    cmap = plt.get_cmap("tab10")
    # One colour per path: each its own legend entry, named by its reference.
    each = color is None and label is not None and len(paths) > 1 and mark_refs
    for i, poses in enumerate(paths):
        c = color if color is not None else cmap(i % 10)
        if each:
            x, y, theta = refs[i]
            name = f"to ({x:g}, {y:g}, {math.degrees(theta):g}°)"
        else:
            name = label if i == 0 else None
        ax.plot(poses[:, 0], poses[:, 1], linestyle, color=c, lw=1.3, label=name)
        # The heading every heading_spacing cm of travel, and at the last pose.
        step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
        travelled = np.concatenate([[0.0], np.cumsum(step)])
        marks = np.flatnonzero(np.diff(np.floor(travelled / heading_spacing), prepend=-1.0) > 0)
        marked = poses[np.union1d(marks, [len(poses) - 1])]
        reference_arrows(ax, marked, arrow_length, color=c, alpha=0.8)
    if mark_refs:
        ax.plot(refs[:, 0], refs[:, 1], "kx", ms=8, mew=2, label="reference" if label else None)
        tips = reference_arrows(ax, refs, 2.5 * arrow_length)
        # quiver does not widen the data limits: take the arrow tips in, or they are clipped.
        ax.update_datalim(refs[:, :2] + tips)
        ax.autoscale_view()
        if paths:
            _mark_backwards(ax, paths, refs)
    ax.set_aspect("equal")
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.grid(alpha=0.3)


def _mark_backwards(ax: Any, paths: Sequence[np.ndarray], refs: np.ndarray) -> None:
    """Circle the references reached facing backwards (``θ = θ_r ± 180°``, arrived all the same)."""
    ends = np.asarray([np.asarray(p)[-1] for p in paths])
    close = np.hypot(*(ends[:, :2] - refs[: len(ends), :2]).T) <= DEFAULT_TOL_R
    turn = np.angle(np.exp(1j * (ends[:, 2] - refs[: len(ends), 2])))
    back = close & (np.abs(turn) > np.pi / 2)
    if back.any():
        ring = {"mfc": "none", "mec": "tab:purple", "ms": 16, "mew": 1.5}
        label = "arrived backwards (θ = θ_r ± 180°)"
        ax.plot(*refs[: len(ends)][back, :2].T, "o", **ring, label=label)


def plot_wheel_speeds(
    ax: Any,
    wheel_speeds: np.ndarray,
    *,
    dt: float,
    v_max: float | None = None,
    labels: Sequence[str] = ("left", "right"),
    linestyle: str = "-",
) -> None:
    """Plot rim speeds ``(steps, 2)`` against time, with the ``±v_max`` limits."""
    wheel_speeds = np.asarray(wheel_speeds, dtype=float)
    if wheel_speeds.ndim != 2 or wheel_speeds.shape[1] != 2:
        raise ValueError(f"wheel_speeds has shape {wheel_speeds.shape}; allowed: (steps, 2)")
    if isinstance(labels, str) or len(labels) != 2:
        raise ValueError(f"labels = {labels!r} is not allowed; allowed: two names (left, right)")
    dt = checks.check_dt(dt)
    if v_max is not None:
        v_max = checks.check_number("v_max", v_max, unit="cm/s")
    t = (np.arange(len(wheel_speeds)) + 1) * dt
    for j, name in enumerate(labels):
        ax.plot(t, wheel_speeds[:, j], linestyle, lw=1.2, label=name)
    if v_max is not None:
        limit = {"color": "r", "ls": "--", "lw": 1}
        ax.axhline(v_max, label=f"±V_max = ±{v_max:g} cm/s", **limit)
        ax.axhline(-v_max, **limit)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("rim speed [cm/s]")
    ax.grid(alpha=0.3)


def path_figure(path: Any, traj: Any, ref: Sequence[float], *, title: str) -> None:
    """Save the path of one run (a ``Trajectory``) to its reference as an image."""
    if getattr(traj, "poses", None) is None:
        raise ValueError(f"traj is a {type(traj).__name__}; allowed: a Trajectory of one run")
    with closed_after(figsize=(6, 6)) as (fig, ax):
        plot_paths(ax, [np.asarray(traj.poses)], np.asarray([ref]), label="robot path")
        ax.set_title(title)
        ax.legend(fontsize=8)
        save_figure(fig, path, dpi=120, bbox_inches="tight")
