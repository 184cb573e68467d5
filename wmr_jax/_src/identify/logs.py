"""Read a robot's log: a CSV of commands and tracked poses, or a ROS 2 bag, checked.

Every problem is one ``ValueError`` naming the file, the line or topic and
what is wrong, before anything is fitted.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

HEADER = ("t", "v_cmd", "omega_cmd", "x", "y", "theta")
# A period is uniform when every step is within this fraction of the median.
_UNIFORM = 1e-3


class Log(NamedTuple):
    """One log on a uniform period.

    Attributes:
        dt: the period, s.
        commands: ``(N, 2)`` ``[v cm/s, ω rad/s]`` sent at each sample.
        poses: ``(N, 3)`` ``[x cm, y cm, θ rad]`` measured there, θ unwrapped.
        source: the file it came from.
    """

    dt: float
    commands: np.ndarray
    poses: np.ndarray
    source: str


def write_csv(path: Any, dt: float, commands: np.ndarray, poses: np.ndarray) -> None:
    """Write a log as the CSV ``read_csv`` reads."""
    t = np.arange(len(commands)) * dt
    table = np.column_stack([t, commands, poses])
    with open(path, "w", newline="") as f:
        f.write(",".join(HEADER) + "\n")
        for row in table:
            f.write(",".join(repr(float(x)) for x in row) + "\n")


def read_csv(path: Any, minimum: int = 2) -> Log:
    """Read a CSV log with the header ``t,v_cmd,omega_cmd,x,y,theta`` (s, cm/s, rad/s, cm, rad)."""
    where = str(path)
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as err:
        raise ValueError(f"{where} cannot be read: {err.strerror}") from None
    if not rows or tuple(c.strip() for c in rows[0]) != HEADER:
        got = ",".join(rows[0]) if rows else "an empty file"
        raise ValueError(f"{where}: line 1 is {got!r}; allowed: the header {','.join(HEADER)}")
    values = []
    for number, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(HEADER):
            raise ValueError(
                f"{where}: line {number} has {len(row)} values; allowed: {len(HEADER)} "
                f"({','.join(HEADER)})"
            )
        try:
            parsed = [float(c) for c in row]
        except ValueError:
            raise ValueError(
                f"{where}: line {number} = {','.join(row)!r} is not all numbers"
            ) from None
        for name, value in zip(HEADER, parsed, strict=True):
            if not math.isfinite(value):
                raise ValueError(
                    f"{where}: line {number}: {name} = {value} is not allowed; "
                    "allowed: a finite number"
                )
        values.append(parsed)
    table = np.asarray(values, dtype=float).reshape(-1, len(HEADER))
    return check_log(table[:, 0], table[:, 1:3], table[:, 3:6], where, minimum, first_line=2)


def check_log(
    t: np.ndarray,
    commands: np.ndarray,
    poses: np.ndarray,
    where: str,
    minimum: int,
    *,
    first_line: int | None = None,
) -> Log:
    """Check one log's time, length and units; unwrap its headings."""

    def at(i: int) -> str:
        return f"line {first_line + i}" if first_line is not None else f"sample {i}"

    if len(t) < minimum:
        raise ValueError(
            f"{where} is too short: {len(t)} samples; allowed: at least {minimum} "
            "(the fit cuts the log into segments of that length)"
        )
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0:
        raise ValueError(f"{where}: the time t does not increase; allowed: a uniform period > 0 s")
    off = np.flatnonzero(np.abs(steps - dt) > _UNIFORM * dt)
    if off.size:
        i = int(off[0]) + 1
        raise ValueError(
            f"{where}: {at(i)}: t = {float(t[i])!r} after {float(t[i - 1])!r} is a step of "
            f"{steps[i - 1]:.6g} s; "
            f"allowed: a uniform period ({dt:.6g} s, to {_UNIFORM:.0e} of it)"
        )
    _check_units(dt, commands, poses, where)
    poses = poses.copy()
    poses[:, 2] = np.unwrap(poses[:, 2])
    return Log(dt, commands, poses, where)


def _check_units(dt: float, commands: np.ndarray, poses: np.ndarray, where: str) -> None:
    """Catch a log in metres (poses or commands) or degrees by how its poses follow its commands."""
    hop = max(1, round(1.0 / dt))
    moved = np.abs(np.diff(poses[::hop, 0] + 1j * poses[::hop, 1]))
    travel = np.cumsum(np.abs(commands[:, 0]) * dt)[::hop]
    commanded = np.diff(travel)
    busy = commanded > 1e-6
    if np.sum(busy) >= 3 and np.sum(commanded[busy]) > 0:
        ratio = float(np.sum(moved[busy]) / np.sum(commanded[busy]))
        if ratio < 0.1 and dt >= 1.0:  # a "period" of a second or more: t in ms
            raise ValueError(
                f"{where}: its period is {dt:.6g} s, and x, y moved {ratio:.3g} times the "
                "distance v_cmd asked for over it: t looks like milliseconds; allowed: t in s"
            )
        if ratio < 0.1:
            raise ValueError(
                f"{where}: x, y moved {ratio:.3g} times the distance v_cmd asked for: the poses "
                "look like metres; allowed: x, y in cm (multiply metres by 100)"
            )
        if ratio > 10:
            raise ValueError(
                f"{where}: x, y moved {ratio:.3g} times the distance v_cmd asked for: v_cmd looks "
                "like m/s, or its column is omega_cmd's; allowed: the columns "
                f"{','.join(HEADER)} with v_cmd in cm/s (multiply m/s by 100)"
            )
    turn = commands[:-1, 1] * dt  # each sample's commanded turn, rad
    if np.sum(np.abs(turn)) > 0.5:
        step = np.diff(poses[:, 2])

        def follows(measured: np.ndarray, scale: float) -> bool:
            """Whether the heading's steps follow the commanded turns scaled by ``scale``.

            Step by step, not in total: over minutes the heading drifts from the
            integrated command (the wheels' mismatch, the speed limits). The gain
            must stand five standard errors clear of the tracker's noise: a log that
            hardly turns tells nothing of its units.
            """
            asked = turn * scale
            size = float(np.dot(asked, asked))
            gain = float(np.dot(measured, asked)) / size
            spread = float(np.std(measured - gain * asked)) / np.sqrt(size)
            return 0.2 < gain < 5 and gain > 5 * spread

        as_rad = np.angle(np.exp(1j * step))  # each step wrapped, as np.unwrap would
        as_deg = np.deg2rad((step + 180.0) % 360.0 - 180.0)
        if follows(as_rad, 1.0):
            return
        if follows(as_deg, np.pi / 180):
            raise ValueError(
                f"{where}: theta and omega_cmd look like degrees and deg/s (their turns agree "
                "in degrees only); allowed: theta in rad, omega_cmd in rad/s"
            )
        if follows(as_deg, 1.0):
            raise ValueError(
                f"{where}: theta turns about 57 times what omega_cmd asks for: it looks like "
                "degrees; allowed: theta in rad"
            )
        if follows(as_rad, np.pi / 180):
            raise ValueError(
                f"{where}: theta turns about 1/57 of what omega_cmd asks for: omega_cmd looks "
                "like deg/s; allowed: omega_cmd in rad/s"
            )


def read_bag(path: Any, cmd_topic: str, pose_topic: str, dt: float | None, minimum: int = 2) -> Log:
    """Read a ROS 2 bag (``.mcap`` or a ``.db3`` folder/file) onto the control period.

    Commands (``geometry_msgs/msg/Twist`` or ``TwistStamped``, m/s and rad/s)
    are held from each message on; poses (``geometry_msgs/msg/PoseStamped``
    or ``nav_msgs/msg/Odometry``, m) are interpolated at each sample. The
    period is ``dt`` or the commands' median spacing.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    where = str(path)
    path = Path(path)
    bag = path.parent if path.suffix in (".mcap", ".db3") and path.is_file() else path
    cmds, poses = [], []
    first = None
    try:
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            topics = {c.topic: c for c in reader.connections}
            for topic in (cmd_topic, pose_topic):
                if topic not in topics:
                    raise ValueError(
                        f"{where}: topic {topic!r} is not in the bag; allowed: one of "
                        f"{', '.join(sorted(topics))}"
                    )
            wanted = [topics[cmd_topic], topics[pose_topic]]
            for conn, stamp, raw in reader.messages(connections=wanted):
                msg = reader.deserialize(raw, conn.msgtype)
                first = stamp if first is None else first
                t = (stamp - first) * 1e-9  # from the first message: ns stay exact
                if conn.topic == cmd_topic:
                    twist = getattr(msg, "twist", msg)
                    if not hasattr(twist, "linear"):
                        raise ValueError(
                            f"{where}: topic {cmd_topic!r} has {conn.msgtype}; allowed: "
                            "geometry_msgs/msg/Twist or TwistStamped"
                        )
                    cmds.append((t, twist.linear.x * 100.0, twist.angular.z))
                else:
                    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
                    if not hasattr(pose, "orientation"):
                        raise ValueError(
                            f"{where}: topic {pose_topic!r} has {conn.msgtype}; allowed: "
                            "geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry"
                        )
                    q = pose.orientation
                    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))
                    poses.append((t, pose.position.x * 100.0, pose.position.y * 100.0, yaw))
    except ValueError:
        raise
    except Exception as err:  # rosbags raises its own errors for unreadable bags
        raise ValueError(f"{where} cannot be read as a ROS 2 bag: {err}") from None
    for topic, got in ((cmd_topic, cmds), (pose_topic, poses)):
        if len(got) < 2:
            raise ValueError(
                f"{where}: topic {topic!r} has {len(got)} messages; allowed: at least 2"
            )
    c, p = np.asarray(cmds), np.asarray(poses)
    if not np.all(np.isfinite(c)) or not np.all(np.isfinite(p)):
        bad = cmd_topic if not np.all(np.isfinite(c)) else pose_topic
        raise ValueError(f"{where}: topic {bad!r} holds NaN or infinite values; allowed: finite")
    period = float(np.median(np.diff(c[:, 0]))) if dt is None else float(dt)
    start, end = max(c[0, 0], p[0, 0]), min(c[-1, 0], p[-1, 0])
    t = start + np.arange(int(math.floor((end - start) / period + 1e-9)) + 1) * period
    held = np.clip(np.searchsorted(c[:, 0], t + 1e-9 * period, side="right") - 1, 0, len(c) - 1)
    commands = c[held, 1:]
    heading = np.unwrap(p[:, 3])
    measured = np.column_stack(
        [np.interp(t, p[:, 0], p[:, k]) for k in (1, 2)] + [np.interp(t, p[:, 0], heading)]
    )
    return check_log(
        t - t[0], commands, measured, f"{where} (topics {cmd_topic}, {pose_topic})", minimum
    )


def read_log(
    path: Any,
    *,
    cmd_topic: str | None = None,
    pose_topic: str | None = None,
    dt: float | None = None,
    minimum: int = 2,
) -> Log:
    """Read a CSV log, or a ROS 2 bag with its topics."""
    p = Path(path)
    if p.suffix.lower() == ".csv":
        return read_csv(p, minimum)
    if p.suffix in (".mcap", ".db3") or p.is_dir():
        if not cmd_topic or not pose_topic:
            raise ValueError(f"{path}: a ROS 2 bag needs --cmd-topic and --pose-topic")
        return read_bag(p, cmd_topic, pose_topic, dt, minimum)
    raise ValueError(
        f"--log {path} is not allowed; allowed: a .csv log, or a ROS 2 bag (.mcap, .db3)"
    )
