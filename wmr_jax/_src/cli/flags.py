"""Flag values of the command line, checked: one line naming the flag when one is bad.

Checked here rather than by ``argparse`` types: the same one-line error as every other mistake.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import re
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from wmr_jax._src import io


def positive_int(flag: str, text: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """The integer value of a flag, in ``[minimum, maximum]``."""
    try:
        value = int(str(text), 10)
    except ValueError:
        value = None
    if value is None or value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise ValueError(f"{flag} {text!r} is not allowed; allowed: an integer >= {minimum}{upper}")
    return value


def number(
    flag: str,
    text: Any,
    *,
    low: float = -math.inf,
    high: float = math.inf,
    closed: bool = True,
    unit: str = "",
) -> float:
    """A flag's finite value in ``[low, high]`` (``(low, high]`` unless ``closed``)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    above = value >= low if closed else value > low
    if not (math.isfinite(value) and above and value <= high):
        parts = []
        if math.isfinite(low):
            parts.append(f"{'>=' if closed else '>'} {low:g}")
        if math.isfinite(high):
            parts.append(f"<= {high:g}")
        allowed = "a finite number" + (" " + " and ".join(parts) if parts else "")
        raise ValueError(
            f"{flag} {text!r} is not allowed; allowed: {allowed}{' ' + unit if unit else ''}"
        )
    return value


def output_dir(flag: str, text: str) -> Path:
    """A folder the command may write to (created later), or say why not."""
    return io.writable_path(f"{flag} {text!r}", text, folder=True)


def output_file(flag: str, text: str, *endings: str) -> Path:
    """A file path the command may write to, ending in one of ``endings`` if any, or say why not."""
    path = io.writable_path(f"{flag} {text!r}", text, folder=False)
    if endings and path.suffix.lower() not in endings:
        allowed = ", ".join(endings)
        raise ValueError(f"{flag} {text!r} is not allowed; allowed: a path ending in {allowed}")
    return path


def image_file(flag: str, text: str) -> Path:
    """A writable path whose ending names an image format matplotlib can save."""
    from wmr_jax._src.report.figures import image_formats

    return output_file(flag, text, *(f".{f}" for f in image_formats()))


def choice(flag: str, text: str, allowed: Sequence[str]) -> str:
    """Return ``text`` if it is one of ``allowed``."""
    if text not in allowed:
        raise ValueError(f"{flag} {text!r} is not allowed; allowed: {', '.join(allowed)}")
    return text


def velocity_loop(text: str) -> str:
    """The velocity loop given to ``--velocity``."""
    from wmr_jax._src.sim.loops import VELOCITY_LOOPS

    return choice("--velocity", text, VELOCITY_LOOPS)


def estimator(text: str) -> str | None:
    """The estimator given to ``--estimator``: a registered name, or ``None`` for raw feedback."""
    from wmr_jax._src.sim.sensing.estimators import ESTIMATORS

    if text in ("none", "raw"):
        return None
    if text not in ESTIMATORS:
        raise ValueError(
            f"--estimator {text!r} is not allowed; allowed: {', '.join(['none', *ESTIMATORS])} "
            "(one's own: registered by wmr_jax.studies.register_estimator in a script that then "
            "calls wmr_jax.cli.main)"
        )
    return text


def controller_names(names: Sequence[str] | None) -> list[str]:
    """The controllers given to ``--controller`` (default: every registered one)."""
    from wmr_jax._src.model.controllers import registered_names

    known = registered_names()
    if not names:
        return known
    for name in names:
        if name not in known:
            raise ValueError(f"--controller {name!r} is not known; allowed: {', '.join(known)}")
    return list(dict.fromkeys(names))


def unit_slip(text: str) -> None:
    """Warn that a flag's value, taken as given, was most likely written in another unit."""
    warnings.warn(text, UserWarning, stacklevel=3)


def _read_in_degrees(flag: str, text: Any, degrees: float) -> str:
    return f"{flag} {text} is read in degrees ({degrees:g}°); a value in radians needs times 180/pi"


def warn_if_radians(flag: str, text: Any, degrees: float) -> None:
    """Warn that ``degrees``, a fraction within ±π, was most likely given in radians."""
    if 0 < abs(degrees) <= math.pi + 1e-3 and degrees != round(degrees):
        unit_slip(_read_in_degrees(flag, text, degrees))


def pose_from_degrees(flag: str, values: Sequence[Any]) -> list[float]:
    """``[x cm, y cm, θ rad]`` from a flag's ``X Y THETA_DEG``."""
    x = number(f"{flag} X", values[0], unit="cm")
    y = number(f"{flag} Y", values[1], unit="cm")
    theta = number(f"{flag} THETA_DEG", values[2], unit="degrees")
    warn_if_radians(f"{flag} THETA_DEG", values[2], theta)
    return [x, y, math.radians(theta)]


# One style for every gain flag: the field's name, hyphenated, with each part
# apart (--k-r, --k-theta, --phi-m, ...). Older spellings stay as aliases.
_GAIN_FLAGS = (
    # flag, field, default, unit, help, older spellings
    ("--k-r", "kr", 120.0, "cm/s", "k_r, cm/s", ("--kr",)),
    ("--k-theta", "k_theta", 10.0, "rad/s", "k_θ, rad/s", ()),
    ("--phi-m", "phi_m", 70.0, "degrees", "Φ_m, degrees", ()),
    ("--r-m", "r_m", 20.0, "cm", "R_m, cm", ()),
    ("--r-a", "r_a", 20.0, "cm", "R_a, cm", ()),
    ("--r-e", "r_e", 1.0, "cm", "R_e, cm", ()),
    ("--alpha", "alpha", 0.25, "", "α", ()),
)

# The gain flag of each Gains field, in the style above.
GAIN_FLAG = {field: flag for flag, field, *_ in _GAIN_FLAGS}
# Where args records the spelling each given gain flag was typed in.
_TYPED = "gain_flag_spelling"


class _GainFlag(argparse.Action):
    """Store a gain flag's text and the spelling it was typed in (for messages)."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None):
        typed = dict(getattr(namespace, _TYPED, None) or {})
        if typed.get(self.dest, option_string) != option_string:  # --kr 90 after --k-r 60
            parser.error(
                f"{option_string} is not allowed with {typed[self.dest]}: both set "
                f"{self.dest}; allowed: one of them"
            )
        setattr(namespace, self.dest, values)
        typed[self.dest] = option_string
        setattr(namespace, _TYPED, typed)


def gain_flag(args: Any, field: str) -> str:
    """The flag of a gain field as the command line gave it (``--kr``), else its own name."""
    typed = getattr(args, _TYPED, None) or {}
    return typed.get(field) or GAIN_FLAG[field]


def given_gain_flags(args: Any) -> list[str]:
    """The gain flags given on the command line, as typed (a flag left alone keeps its float)."""
    return [gain_flag(args, f) for f in GAIN_FLAG if isinstance(getattr(args, f, None), str)]


def add_gain_flags(parser: Any) -> None:
    """Add the Shim–Sung gain flags (defaults: the paper's Fig. 7) to a parser."""
    group = parser.add_argument_group("gains (docs/model.md §3; defaults are the paper's Fig. 7)")
    for flag, field, default, _, text, older in _GAIN_FLAGS:
        group.add_argument(
            flag, *older, dest=field, default=default, metavar="V", help=text, action=_GainFlag
        )


def gain_flag_values(params: Any) -> list[str]:
    """``Gains`` as the gain flags that give them, six digits: ``["--k-r", "65.592", ...]``."""
    argv = []
    for flag, field, *_ in _GAIN_FLAGS:
        value = float(getattr(params, field))
        value = math.degrees(value) if field == "phi_m" else value
        argv += [flag, f"{value:.6g}"]
    return argv


def period(flag: str, text: Any) -> float:
    """A control period in s (> 0); one of a second or more is warned of as milliseconds meant."""
    value = number(flag, text, low=0.0, closed=False, unit="s")
    if value >= 1.0:  # no robot is controlled at a second a sample
        unit_slip(f"{flag} {text} is read in s; a value in milliseconds needs /1000")
    return value


def horizon(flag: str, text: Any, robot: Any) -> float:
    """A run's horizon in s (> 0); one of 100 times the robot's study horizon is warned of."""
    from wmr_jax._src.studies.robustness import study_horizon

    value = number(flag, text, low=0.0, closed=False, unit="s")
    usual = study_horizon(robot)
    if value > 100 * usual:  # hours of runs for one slip of the unit
        unit_slip(
            f"{flag} {text} is read in s, {value / usual:.0f} times this robot's study horizon "
            f"({usual:g} s); a value in milliseconds needs /1000"
        )
    return value


def gains_from(args: Any) -> Any:
    """The ``Gains`` of the gain flags, given in the flags' units."""
    from wmr_jax._src.model.params import Gains, validate_gains

    values = {}
    for _, field, _, unit, *_ in _GAIN_FLAGS:
        value = number(gain_flag(args, field), getattr(args, field), unit=unit)
        values[field] = math.radians(value) if field == "phi_m" else value
    gains = Gains(**values)
    try:
        validate_gains(gains)
    except ValueError as err:
        if "gains.phi_m" in str(err):
            raise ValueError(
                f"{gain_flag(args, 'phi_m')} {args.phi_m} is not allowed; allowed: 0 < degrees < 90"
            ) from None
        for _, field, *_ in _GAIN_FLAGS:
            if str(err).startswith(f"gains.{field} "):
                shown = gain_flag(args, field)
                if not isinstance(getattr(args, field), str):  # not given: its default
                    shown += f" (not given: its default, {getattr(args, field):g})"
                raise ValueError(f"{shown}: {err}") from None
        raise
    degrees = math.degrees(values["phi_m"])
    if degrees <= math.pi / 2:  # a Φ_m of a degree or so: radians given where degrees belong
        unit_slip(_read_in_degrees(gain_flag(args, "phi_m"), args.phi_m, degrees))
    return gains


_JSON_AT = re.compile(r"^(Expecting|Extra data|Unterminated|Invalid)\b.*?(line \d+ column \d+)")


def tuned_file(flag: str, path: Any) -> Any:
    """``load_tuned_and_tuning(path)`` for a command's flag, its errors naming ``flag``."""
    from wmr_jax._src.tuning.saved import load_tuned_and_tuning

    try:
        return load_tuned_and_tuning(path)
    except ValueError as err:
        text = str(err)
        head, sep, reason = text.partition(" cannot be read: ")
        if not sep:
            raise ValueError(f"{flag} {text}") from None
        parsed = _JSON_AT.search(reason)
        if parsed is not None:
            raise ValueError(
                f"{flag} {head} is not a JSON gains file (not JSON at {parsed[2]}); allowed: "
                "the tuned_gains.json of wmr-jax tune, or a JSON object of Gains fields"
            ) from None
        raise ValueError(f"{flag} {head} cannot be read: {io.os_reason(reason)}") from None


# The add_argument keywords of --float32 for a command that computes in float64 by default.
FLOAT32 = {"action": "store_true", "help": "compute in float32 instead of float64"}
# What --gains FILE takes, in the help of every command that reads one.
GAINS_FILE_HELP = (
    "tuned_gains.json of wmr-jax tune (fixed gains or a schedule, with its estimator) "
    "or a JSON of Gains fields"
)


def add_robot_flag(parser: Any, default: str = "paper") -> None:
    """Add ``--robot NAME|FILE``; ``default`` names what runs without it, in the help only."""
    from wmr_jax._src.model.robots import ROBOTS

    parser.add_argument(
        "--robot",
        metavar="NAME|FILE",
        help=f"the robot: a preset ({', '.join(ROBOTS)}), a .json of Robot fields in cm, kg, "
        "s (any subset; the rest the paper robot's) or a ROS diff_drive_controller .yaml "
        f"(docs/robots.md) (default: {default})",
    )


def say_robot(given: Any, detail: str = "", gains: bool = True) -> None:
    """Print ``--robot``'s robot (and its note), if given, then ``detail``.

    ``gains``: also what Shim–Sung runs there in a study given no gains (``robot_defaults``).
    """
    from wmr_jax._src.model.robots import describe_robot
    from wmr_jax._src.studies.robustness import robot_defaults

    if given is None:
        return
    if given.note:
        print(given.note)
    scaled = robot_defaults("shim-sung", given.robot) if gains else None
    if scaled is not None:
        kr, k_theta = float(scaled.kr), float(scaled.k_theta)
        detail += (
            f"; shim-sung at k_r = {kr:.4g} cm/s, k_theta = {k_theta:.4g} rad/s (the paper's "
            "feasible gains within its wheel budget)"
        )
    print(f"robot {given.label!r}: {describe_robot(given.robot)}{detail}")


def robot_from(text: Any) -> Any:
    """The robot of ``--robot`` (a ``robots.LoadedRobot``), or ``None`` if not given."""
    from wmr_jax._src.model.robots import read_robot

    if text is None:
        return None
    try:
        return read_robot(text)
    except ValueError as err:
        raise ValueError(f"--robot {err}") from None


def is_robot_file(text: Any) -> bool:
    """Whether ``--robot``'s value names a file rather than a preset."""
    from wmr_jax._src.model.robots import ROBOTS

    return text is not None and text not in ROBOTS


def robot_for_gains(given: Any, saved: Any, gains_flag: str, path: Any) -> Any:
    """``--robot``'s robot, else the file's (``None``: neither); gains fit one robot, no other."""
    from wmr_jax._src.model.robots import same_robot

    if given is None:
        return saved
    if saved is not None and not same_robot(given.robot, saved):
        raise ValueError(
            f"--robot {given.label!r} is not allowed with {gains_flag} {str(path)!r}, tuned for "
            f"{short_robot(saved)} (gains fit one robot's wheel budget); allowed: that robot, "
            "or no --robot"
        )
    return given.robot


def short_robot(robot: Any) -> str:
    """A robot in a few words: its preset's name, else its track and wheel limit."""
    from wmr_jax._src.model.robots import robot_name

    name = robot_name(robot)
    if name is not None:
        return name
    return (
        f"a robot with L = {float(robot.half_track):.4g} cm, V_max = {float(robot.v_max):.4g} cm/s"
    )


@contextlib.contextmanager
def as_flags(names: dict[str, str]) -> Iterator[None]:
    """Name the flag in the library's errors: ``"--poses: n_poses = 10 is not allowed ..."``.

    The advice to switch JAX to float64, which no flag does, is left out.
    """
    from wmr_jax._src.checks import _FLOAT64_HINT

    try:
        yield
    except ValueError as err:
        text = str(err).replace(_FLOAT64_HINT, "")
        name = text.split(" ", 1)[0]
        flag = names.get(name)
        raise ValueError(f"{flag}: {text}" if flag else text) from None
