"""Flag values of the command line, checked: one line naming the flag when one is bad.

Flags arrive as text and are checked here rather than by ``argparse`` types,
so that a bad value gives the same one-line error as every other mistake
(``wmr-jax: error: --steps '0' is not allowed; allowed: ...``), in the flag's
own unit (degrees stay degrees).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "add_gain_flags",
    "choice",
    "controller_names",
    "gains_file",
    "gains_from",
    "number",
    "output_dir",
    "output_file",
    "pose_from_degrees",
    "positive_int",
    "velocity_loop",
]


def positive_int(flag: str, text: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """Return the integer value of a flag, in ``[minimum, maximum]``."""
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
    """Return a flag's finite value in ``[low, high]`` (``(low, high]`` unless ``closed``)."""
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


def _writable(flag: str, text: str, *, folder: bool) -> Path:
    """Return ``text`` as a path the command may write (a folder or a file), or say why not."""
    from wmr_jax._src.io import writable_path

    return writable_path(f"{flag} {text!r}", text, folder=folder)


def output_dir(flag: str, text: str) -> Path:
    """Return a folder the command may write to (created later), or say why not."""
    return _writable(flag, text, folder=True)


def output_file(flag: str, text: str) -> Path:
    """Return a file path the command may write to, or say why not."""
    return _writable(flag, text, folder=False)


def image_file(flag: str, text: str) -> Path:
    """Return a writable path whose ending names an image format matplotlib can save."""
    from wmr_jax._src.report.figures import image_formats

    path = output_file(flag, text)
    formats = image_formats()
    if path.suffix.lower().lstrip(".") not in formats:
        raise ValueError(
            f"{flag} {text!r} is not allowed; allowed: a path ending in "
            + ", ".join(f".{f}" for f in formats)
        )
    return path


def choice(flag: str, text: str, allowed: Sequence[str]) -> str:
    """Return ``text`` if it is one of ``allowed``."""
    if text not in allowed:
        raise ValueError(f"{flag} {text!r} is not allowed; allowed: {', '.join(allowed)}")
    return text


def velocity_loop(text: str) -> str:
    """Return the name of a velocity loop given to ``--velocity``."""
    from wmr_jax._src.loops import VELOCITY_LOOPS

    return choice("--velocity", text, VELOCITY_LOOPS)


def controller_names(names: Sequence[str] | None) -> list[str]:
    """Return the controllers given to ``--controller`` (default: every registered one)."""
    from wmr_jax._src.controllers import registered_names

    known = registered_names()
    if not names:
        return known
    for name in names:
        if name not in known:
            raise ValueError(f"--controller {name!r} is not known; allowed: {', '.join(known)}")
    return list(dict.fromkeys(names))


def pose_from_degrees(flag: str, values: Sequence[Any]) -> list[float]:
    """Return ``[x cm, y cm, θ rad]`` from a flag's ``X Y THETA_DEG``."""
    x = number(f"{flag} X", values[0], unit="cm")
    y = number(f"{flag} Y", values[1], unit="cm")
    theta = number(f"{flag} THETA_DEG", values[2], unit="degrees")
    return [x, y, math.radians(theta)]


_GAIN_FLAGS = (
    # flag, field, default, unit, help
    ("--kr", "kr", 120.0, "cm/s", "k_r, cm/s"),
    ("--k-theta", "k_theta", 10.0, "rad/s", "k_θ, rad/s"),
    ("--phi-m", "phi_m", 70.0, "degrees", "Φ_m, degrees"),
    ("--r-m", "r_m", 20.0, "cm", "R_m, cm"),
    ("--r-a", "r_a", 20.0, "cm", "R_a, cm"),
    ("--r-e", "r_e", 1.0, "cm", "R_e, cm"),
    ("--alpha", "alpha", 0.25, "", "α"),
)


def add_gain_flags(parser: Any) -> None:
    """Add the Shim–Sung gain flags (defaults: the paper's Fig. 7) to a parser."""
    group = parser.add_argument_group("gains (docs/model.md §3; defaults are the paper's Fig. 7)")
    for flag, _, default, _, text in _GAIN_FLAGS:
        group.add_argument(flag, default=default, metavar="V", help=text)


def gains_from(args: Any) -> Any:
    """Return the ``Gains`` of the gain flags; out-of-range values are named in flag units.

    With a ``--gains FILE`` flag (``args.gains``), the gains come from that file
    instead, and a gain flag given beside it is an error.
    """
    from wmr_jax._src.params import Gains, validate_gains

    if getattr(args, "gains", None) is not None:
        # A flag given on the command line is text; one left alone keeps its float default.
        given = [flag for flag, field, *_ in _GAIN_FLAGS if isinstance(getattr(args, field), str)]
        if given:
            raise ValueError(f"{given[0]} is not allowed with --gains; allowed: one or the other")
        return gains_file("--gains", args.gains)
    values = {}
    for flag, field, _, unit, _ in _GAIN_FLAGS:
        value = number(flag, getattr(args, field), unit=unit)
        values[field] = math.radians(value) if field == "phi_m" else value
    gains = Gains(**values)
    try:
        validate_gains(gains)
    except ValueError as err:
        if "gains.phi_m" in str(err):
            raise ValueError(
                f"--phi-m {args.phi_m} is not allowed; allowed: 0 < degrees < 90"
            ) from None
        for flag, field, *_ in _GAIN_FLAGS:
            if str(err).startswith(f"gains.{field} "):
                raise ValueError(f"{flag}: {err}") from None
        raise
    return gains


def gains_file(flag: str, text: str) -> Any:
    """Return the ``Gains`` stored in a JSON file, such as ``tuned_gains.json`` of ``wmr-jax tune``.

    The file holds one object whose keys are ``Gains`` field names (``kr``
    cm/s, ``k_theta`` rad/s, ``phi_m`` in radians, ``r_m``, ``r_a``, ``r_e``
    cm, ``alpha``); a field it leaves out keeps the paper's value.
    """
    import dataclasses
    import json

    from wmr_jax._src.io import json_object_once as once
    from wmr_jax._src.params import Gains, validate_gains

    fields = [f.name for f in dataclasses.fields(Gains)]
    try:
        values = json.loads(Path(text).read_text(encoding="utf-8"), object_pairs_hook=once)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise ValueError(f"{flag} {text!r} cannot be read: {err}") from None
    numbers = isinstance(values, dict) and all(isinstance(v, (int, float)) for v in values.values())
    if not numbers or not set(values) <= set(fields):
        raise ValueError(
            f"{flag} {text!r} is not allowed; allowed: a JSON object of numbers with keys "
            "among " + ", ".join(fields)
        )
    try:
        return validate_gains(Gains(**values))
    except ValueError as err:
        raise ValueError(f"{flag} {text!r}: {err}") from None


@contextlib.contextmanager
def as_flags(names: dict[str, str]) -> Iterator[None]:
    """Name the command's flags in the library's errors raised inside the block.

    A library error reads ``"n_poses = 10 is not allowed; ..."``; a command
    line user typed ``--poses``, so it becomes ``"--poses: n_poses = 10 is not
    allowed; ..."``. Advice to switch JAX to float64, which no flag does, is
    left out.
    """
    from wmr_jax._src.checks import _FLOAT64_HINT

    try:
        yield
    except ValueError as err:
        text = str(err).replace(_FLOAT64_HINT, "")
        name = text.split(" ", 1)[0]
        flag = names.get(name)
        raise ValueError(f"{flag}: {text}" if flag else text) from None
