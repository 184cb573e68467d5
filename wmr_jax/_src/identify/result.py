"""What an identification writes: ``identified.json``, its table and ``fit.png``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import jax
import numpy as np

from wmr_jax._src.identify import fit as fitting
from wmr_jax._src.identify import model
from wmr_jax._src.model.params import Robot


def true_robot(base: Robot, result: fitting.Fit) -> Robot:
    """The identified robot: ``base`` with the fitted half-track and wheel-loop gain."""
    return base.replace(half_track=result.half_track, speed_gain=result.speed_gain)


def identified(base: Robot, result: fitting.Fit, sources: list[str], dt: float) -> dict[str, Any]:
    """The content of ``identified.json``."""
    robot = true_robot(base, result)
    fields = {f.name: float(getattr(robot, f.name)) for f in dataclasses.fields(Robot)}
    left, right = (float(x) for x in result.wheel_scale)
    return {
        "robot": fields,
        "base_robot": {f.name: float(getattr(base, f.name)) for f in dataclasses.fields(Robot)},
        "wheel_scale": {"left": left, "right": right},
        "latency_samples": int(result.latency),
        "noise": {"sigma_xy": result.sigma_xy, "sigma_theta": result.sigma_theta},
        "ci95": {k: list(v) for k, v in result.ci95.items()},
        "residual_rms": result.residual_rms,
        "ros": {
            # diff_drive_controller turns a rim speed into a wheel speed with
            # its radius times the multiplier: a wheel whose rim moves 1 + δ
            # times as fast as asked is that much larger.
            "left_wheel_radius_multiplier": left,
            "right_wheel_radius_multiplier": right,
            "wheel_separation_multiplier": result.half_track / float(base.half_track),
        },
        "dt": dt,
        "logs": sources,
        "latency_profile": [float(c) for c in result.profile],
    }


def table(content: dict[str, Any]) -> str:
    """The printed table: each fitted quantity, its 95 % interval, the base's value."""
    ci, base = content["ci95"], content["base_robot"]
    rows = [
        ("wheel scale left", content["wheel_scale"]["left"], ci["wheel_scale_left"], 1.0),
        ("wheel scale right", content["wheel_scale"]["right"], ci["wheel_scale_right"], 1.0),
        ("half-track (cm)", content["robot"]["half_track"], ci["half_track"], base["half_track"]),
        ("speed_gain (1/s)", content["robot"]["speed_gain"], ci["speed_gain"], base["speed_gain"]),
        ("sigma_xy (cm)", content["noise"]["sigma_xy"], ci["sigma_xy"], None),
        # In degrees, as --noise-theta and the docs give it (identified.json keeps radians).
        (
            "sigma_theta (deg)",
            np.degrees(content["noise"]["sigma_theta"]),
            np.degrees(ci["sigma_theta"]),
            None,
        ),
    ]
    lines = [f"{'quantity':<20}{'fitted':>12}{'95% interval':>26}{'base':>10}"]
    for name, value, (lo, hi), b in rows:
        shown = "" if b is None else f"{b:.6g}"
        lines.append(f"{name:<20}{value:>12.6g}{f'[{lo:.6g}, {hi:.6g}]':>26}{shown:>10}")
    lines.append(f"{'latency (samples)':<20}{content['latency_samples']:>12d}")
    ros = content["ros"]
    lines.append(
        "ROS diff_drive_controller: " + ", ".join(f"{k} = {v:.6f}" for k, v in ros.items())
    )
    return "\n".join(lines)


def plot_fit(path: Path, logs: list, base: Robot, result: fitting.Fit, dt: float) -> None:
    """``fit.png``: each log's measured path against the fitted replay, and the residuals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    with jax.enable_x64(True):
        robot = model.fitted_robot(
            jax.tree.map(lambda x: np.float64(x), base), result.half_track, result.speed_gain
        )
        for i, log in enumerate(logs):
            poses = np.asarray(
                model.replay(
                    log.commands,
                    np.asarray(log.poses[0]),
                    robot,
                    result.wheel_scale,
                    float(base.half_track),
                    result.latency,
                    dt,
                )
            )
            predicted = np.vstack([log.poses[:1], poses[:-1]])
            axes[0].plot(log.poses[:, 0], log.poses[:, 1], ".", ms=1, label=f"log {i + 1} measured")
            axes[0].plot(predicted[:, 0], predicted[:, 1], "-", lw=0.8, label=f"log {i + 1} replay")
    axes[0].set_aspect("equal", "datalim")
    axes[0].set_xlabel("x (cm)")
    axes[0].set_ylabel("y (cm)")
    axes[0].set_title("measured paths and the fitted model's replay (from the first pose)")
    axes[0].legend(fontsize=7)
    res = result.segment_residuals
    axes[1].plot(res[:, 0], ".", ms=1, label="x (cm)")
    axes[1].plot(res[:, 1], ".", ms=1, label="y (cm)")
    axes[1].plot(np.rad2deg(res[:, 2]), ".", ms=1, label="θ (deg)")
    axes[1].set_xlabel("window sample")
    axes[1].set_title("residuals of the segments (start pose fitted)")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(out: Path, content: dict[str, Any]) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "identified.json"
    path.write_text(json.dumps(content, indent=2) + "\n")
    return path
