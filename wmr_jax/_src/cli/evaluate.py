"""``wmr-jax evaluate``: judge a tuned loop on the user's references under one condition."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags

_CONDITIONS = ("nominal", "latency", "noise", "both")
# The runs keep their noise for the whole horizon (3 floats per reference and
# period): this many reference-periods are ~5 GB, as `robustness --runs 10^6`.
_MAX_SAMPLES = 2 * 10**8
_MAX_HORIZON_S = 3600.0


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax evaluate``."""
    gains_help = flags.GAINS_FILE_HELP + " (required, unless --c)"
    parser.add_argument("--gains", metavar="FILE.json", help=gains_help)
    parser.add_argument(
        "--refs",
        required=True,
        metavar="FILE",
        help="references, one row [x cm, y cm, theta rad] each: an (N, 3) .npy, or a .csv "
        "of 3 comma-separated numbers a line (a first line of names is skipped; one naming "
        "another unit, such as theta_deg, is refused)",
    )
    parser.add_argument(
        "--condition",
        default="nominal",
        metavar="NAME",
        help=f"standard condition (docs/model.md §7): {', '.join(_CONDITIONS)} (default: nominal)",
    )
    parser.add_argument(
        "--mismatch",
        default=0.03,
        metavar="D",
        help="bound of each wheel's relative radius error, drawn per run from U(-D, D), "
        "in [0, 1); 0 is the model robot",
    )
    parser.add_argument("--seed", default=0, metavar="N", help="seed of the noise and mismatch")
    parser.add_argument(
        "--horizon",
        metavar="S",
        help=f"simulated time per reference, s (at most {_MAX_HORIZON_S:g}; default: 6 on the "
        "paper robot, longer on a slower one: 6 s times (60 + 10 L) / V_max where that "
        "exceeds 1, the time the paper's gains take there, docs/robustness.md)",
    )
    flags.add_robot_flag(parser, default="the --gains file's robot, else paper")
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument(
        "--estimator",
        metavar="NAME",
        help="feedback, instead of the file's: none (raw), observer, ekf or a registered name "
        "(the file's parameters if it holds that one, else the defaults); default: the file's",
    )
    parser.add_argument("--float32", **flags.FLOAT32)
    parser.add_argument(
        "--json",
        metavar="OUT.json",
        help="write the result to this JSON file (if omitted, only print it)",
    )
    parser.add_argument(
        "--per-ref",
        metavar="OUT.csv",
        help="write one line per reference to this CSV: where it is in --refs, the reference, "
        "whether it arrived, its arrival time, its final distance and whether it settled only "
        "at the horizon",
    )
    parser.add_argument(
        "--c",
        metavar="DIR",
        help="judge the C controller wmr-jax export wrote into DIR, compiled with the system "
        "C compiler, in place of --gains (the same runs; float64 loop, docs/deploy.md)",
    )


def _refs_error(path: str, what: str) -> ValueError:
    return ValueError(f"--refs {path!r} is not allowed: {what}")


def _unreadable(path: str, err: Any) -> ValueError:
    return ValueError(f"--refs {path!r} cannot be read: {' '.join(str(err).split())}")


def _float_or_none(cell: str) -> float | None:
    try:
        return float(cell)
    except ValueError:
        return None


# Units a header may name, per column (x, y, theta): any other one is refused,
# since the numbers below it are read as cm, cm and rad whatever it says.
_HEADER_UNITS = ({"cm"}, {"cm"}, {"rad", "radian", "radians"})
_UNIT_WORDS = {"m", "mm", "cm", "metre", "metres", "meter", "meters", "in", "ft"} | {
    "rad", "radian", "radians", "deg", "degree", "degrees", "°"
}  # fmt: skip


def _check_header_units(path: str, number: int, cells: list[str]) -> None:
    """Refuse a header line that names a unit other than the file's (cm, cm, rad)."""
    for column, (cell, allowed) in enumerate(zip(cells, _HEADER_UNITS, strict=False), start=1):
        words = {w for w in re.split(r"[^a-z°]+", cell.lower()) if w in _UNIT_WORDS}
        wrong = sorted(words - allowed)
        if wrong:
            unit = "cm" if column < 3 else "rad"
            raise _refs_error(
                path,
                f"line {number} names column {column} {cell!r}, in {wrong[0]}; allowed: "
                f"{unit} (the columns are read as x cm, y cm, theta rad)",
            )


def _read_csv(path: str) -> tuple[Any, list[str]]:
    """The rows of a ``.csv`` of references and their line numbers (a header line skipped)."""
    import numpy as np

    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise _unreadable(path, err) from None
    rows: list[list[float]] = []
    lines: list[str] = []
    first = True
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = [cell.strip() for cell in line.split(",")]
        values = [_float_or_none(cell) for cell in cells]
        # Three fields split by another separator: a file in another dialect.
        other = next(
            (sep for sep in (";", "\t", " ") if len(cells) == 1 and len(cells[0].split(sep)) == 3),
            None,
        )
        if other is not None:
            shown = {"\t": "tabs", " ": "spaces"}.get(other, repr(other))
            raise _refs_error(
                path,
                f"line {number} is separated by {shown} ({line.strip()!r:.40}); allowed: 3 "
                "comma-separated numbers a line (x cm, y cm, theta rad)",
            )
        if first and all(v is None for v in values):  # a header line of names
            _check_header_units(path, number, cells)
            first = False
            continue
        first = False
        for column, (cell, value) in enumerate(zip(cells, values, strict=True), start=1):
            if value is None:
                raise _refs_error(
                    path, f"line {number}, column {column} is {cell!r}; allowed: a number"
                )
        if len(values) != 3:
            raise _refs_error(
                path,
                f"line {number} has {len(values)} values; allowed: 3 on every line "
                "(x cm, y cm, theta rad)",
            )
        rows.append(values)
        lines.append(f"line {number}")
    return np.array(rows, dtype=float).reshape(-1, 3), lines


_NPY_MAGIC = b"\x93NUMPY"


def _read_npy(path: str) -> tuple[Any, list[str] | None]:
    """The array of a ``.npy`` of references (never unpickled)."""
    import numpy as np

    try:
        with open(path, "rb") as f:
            arr = None  # NumPy would take any file but a .npy for a pickle
            if f.read(len(_NPY_MAGIC)) == _NPY_MAGIC:
                f.seek(0)
                arr = np.load(f, allow_pickle=False)
    except ValueError as err:
        if "allow_pickle" in str(err):
            raise _refs_error(
                path, "it holds Python objects (a pickle); allowed: an array of numbers"
            ) from None
        raise _unreadable(path, err) from None
    except (OSError, EOFError) as err:  # unreadable, truncated
        raise _unreadable(path, err) from None
    if arr is None:
        raise _refs_error(path, "it is no .npy array (empty, another kind of file, or damaged)")
    if arr.dtype.kind not in "iuf":
        raise _refs_error(path, f"its dtype is {arr.dtype}; allowed: real numbers")
    return arr.astype(float), None


def load_refs(path: str, *, x64: bool = True) -> tuple[Any, list[str]]:
    """The ``(N, 3)`` references of ``--refs`` (``.npy`` or ``.csv``), checked, and where each is.

    Where: ``line 3`` of a CSV, ``row 0 (from 0)`` of an array.
    """
    import jax
    import numpy as np

    from wmr_jax._src import checks

    file = Path(path)
    if file.is_dir():
        raise _refs_error(path, "it is a folder; allowed: a .npy or .csv file")
    reader = {".npy": _read_npy, ".csv": _read_csv}.get(file.suffix.lower())
    if reader is None:
        raise ValueError(f"--refs {path!r} is not allowed; allowed: a file ending in .npy or .csv")
    if not file.exists():
        raise _unreadable(path, "there is no such file")
    refs, labels = reader(path)
    if refs.ndim == 1 and refs.shape[0] == 3:
        refs = refs[None, :]
    if refs.ndim != 2 or refs.shape[1] != 3:
        raise _refs_error(
            path, f"it has shape {refs.shape}; allowed: (N, 3) rows of x cm, y cm, theta rad"
        )
    if refs.shape[0] == 0:
        raise _refs_error(path, "it holds no references; allowed: at least one row of 3 numbers")
    labels = labels or [f"row {i} (from 0)" for i in range(len(refs))]
    bad = np.flatnonzero(~np.isfinite(refs).all(axis=1))
    if bad.size:
        row = int(bad[0])
        more = f"; {bad.size} such rows" if bad.size > 1 else ""
        raise _refs_error(
            path,
            f"{labels[row]} = {refs[row].tolist()} is not finite; allowed: finite numbers{more}",
        )
    # The library's own limits (heading; distance, for the dtype), named as the flag.
    try:
        with jax.enable_x64(x64):
            checks.as_poses("refs", refs, batch=True)
    except ValueError as err:
        text = str(err).replace(checks._FLOAT64_HINT, ", or without --float32")
        raise _refs_error(path, text) from None
    return refs, labels


def unit_warnings(path: str, refs: Any, reach: float) -> list[str]:
    """Warnings for references that look like metres or degrees (legal, so not refused).

    ``reach``: the farthest a robot can drive within the horizon, cm (``V_max`` times
    it); a file whose every reference lies beyond it is warned of as well.
    """
    import numpy as np

    from wmr_jax._src.sim.metrics import DEFAULT_TOL_R

    out = []
    distance = np.hypot(refs[:, 0], refs[:, 1])
    if float(distance.max()) <= DEFAULT_TOL_R:
        out.append(
            f"--refs {path!r}: every reference lies within {DEFAULT_TOL_R:g} cm of the start "
            f"(the farthest {float(distance.max()):.3g} cm), inside the arrival tolerance; the "
            "columns are read as x cm, y cm, theta rad (a file in metres needs x and y times 100)"
        )
    if float(distance.min()) > reach:
        out.append(
            f"--refs {path!r}: every reference lies beyond {reach:.4g} cm, as far as V_max "
            f"drives within the horizon (the nearest {float(distance.min()):.4g} cm): a robot "
            "within V_max cannot arrive; x and y are read as cm"
        )
    heading = np.abs(refs[:, 2])
    if float(heading.max()) > 2 * np.pi:
        out.append(
            f"--refs {path!r}: headings up to {float(heading.max()):g} look like degrees; the "
            "third column is read as radians (a file in degrees needs theta times pi/180)"
        )
    return out


def _mismatch(text: Any) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    if not 0.0 <= value < 1.0:  # NaN too
        raise ValueError(f"--mismatch {text!r} is not allowed; allowed: a number >= 0 and < 1")
    return value


def _horizon(args: Any, refs: Any, robot: Any, note: str | None = None) -> float:
    """``--horizon``, else the robot's default (``study_horizon``), checked with the refs.

    Then prints the robot file's ``note`` and warns of references no run can reach.
    """
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.sim.metrics import DEFAULT_TOL_R
    from wmr_jax._src.sim.poses import horizon_steps
    from wmr_jax._src.sim.rollout import DEFAULT_DT
    from wmr_jax._src.studies.robustness import study_horizon

    text = study_horizon(robot) if args.horizon is None else args.horizon
    horizon = flags.number("--horizon", text, low=0.0, high=_MAX_HORIZON_S, closed=False, unit="s")
    with flags.as_flags({"horizon": "--horizon"}):
        steps = horizon_steps(DEFAULT_DT, horizon)
    if len(refs) * steps > _MAX_SAMPLES:
        raise ValueError(
            f"--horizon {text!r} with {len(refs)} references is {len(refs) * steps} "
            f"reference-periods; allowed: at most {_MAX_SAMPLES:.0e} (fewer references or a "
            "shorter horizon)"
        )
    if note:
        print(note)
    reach = float((Robot() if robot is None else robot).v_max) * horizon + DEFAULT_TOL_R
    for text in unit_warnings(args.refs, refs, reach):
        flags.unit_slip(text)
    return horizon


def _loop(path: str, estimator: str | None) -> Any:
    """The closed loop of ``--gains``, its estimator replaced by ``--estimator`` if given."""
    from wmr_jax._src.sim.sensing.estimators import ESTIMATORS, resolve_estimator

    loop = flags.tuned_file("--gains", path)[0]
    if estimator is None:
        return loop
    if estimator == "none":
        return loop._replace(estimator=None)
    saved, params = resolve_estimator(loop.estimator)
    # The file's tuned parameters when it holds this estimator, else its defaults.
    chosen = params if saved is ESTIMATORS[estimator] else estimator
    return loop._replace(estimator=chosen)


def _percent(value: float) -> str:
    return f"{100 * value:.1f} %"


def _seconds(value: float | None) -> str:
    return "none arrived" if value is None else f"{value:.3f} s"


_SHOWN_FAILURES = 5


def _failed(result: dict[str, Any], labels: list[str]) -> str:
    """Where the references that did not arrive are in ``--refs``; the first few named."""
    failed = [i for i, r in enumerate(result["per_reference"]) if not r["success"]]
    if not failed:
        return "none"
    names = [labels[i] for i in failed[:_SHOWN_FAILURES]]
    more = len(failed) - len(names)
    return ", ".join(names) + (f" and {more} more (--per-ref lists them all)" if more else "")


def summary_rows(result: dict[str, Any], labels: list[str]) -> list[dict[str, str]]:
    """The printed table of a result: one quantity a row; ``labels`` name the references."""
    from wmr_jax._src.model.robots import describe_robot, robot_from_values

    mismatch = result["mismatch"]
    off = f"{100 * mismatch:.3g} %"
    identified = result["condition"] == "identified"  # fitted wheel scales, not a ± bound
    wheels = ("wheel-radius mismatch", f"±{100 * mismatch:g} %")
    robot = base = describe_robot(robot_from_values(result["robot"], "robot"))
    if result.get("robot_file"):
        robot += f", from {result['robot_file']}"
    if identified:
        robot = (
            f"runs on the robot identified in {result.get('robot_file', 'identified.json')} "
            f"(wheel scales, half-track, wheel lag, latency, tracker noise); the loop believes "
            f"its base: {base}"
        )
        wheels = ("wheel scales", f"the identified ones (up to {off} off the model)")
    versus = "none arrived"
    if result["vs_turn_drive_turn"] is not None:
        versus = (
            f"{result['vs_turn_drive_turn']:.3f}× (its mean {result['turn_drive_turn_s']:.3f} s "
            "over the references that arrived, docs/model.md §8)"
        )
    peak = f"{result['peak_wheel_speed']:.1f} cm/s"
    within = "exceeded: the gains ask more of the wheels than this robot has"
    if result["peak_wheel_speed_ok"]:
        within = "every wheel command within it"
    if mismatch != 0:
        peak += " at the rims, wheel-radius mismatch included"
        if result["peak_wheel_speed_ok"]:
            bound = result["v_max"] * (1.0 + mismatch)
            within += (
                f" (the identified wheels, up to {off} off the model, turn that into up to "
                f"{bound:.4g} cm/s at their rims)"
                if identified
                else f" (a wheel up to {off} larger than modelled turns that into up to "
                f"{bound:.4g} cm/s at its rim)"
            )
    rows = [("success", _percent(result["success"])), ("not arrived", _failed(result, labels))]
    settled = _percent(result["settled_at_horizon"]) + " of the runs (counted as arrived)"
    rows += [
        ("mean arrival", _seconds(result["mean_arrival_s"])),
        ("median arrival", _seconds(result["median_arrival_s"])),
        ("vs turn–drive–turn time", versus),
        ("settled only at the horizon", settled),
        ("peak wheel speed", peak),
        ("V_max", f"{result['v_max']:g} cm/s, {within}"),
        ("robot", robot),
        ("references (n)", str(result["n"])),
        ("condition", result["condition"]),
        wheels,
        ("seed", str(result["seed"])),
        ("horizon", f"{result['horizon_s']:g} s"),
        ("velocity loop", result["velocity"]),
        ("controller", result["controller"]),
        ("feedback", result["feedback"]),
    ]
    return [{"quantity": quantity, "value": value} for quantity, value in rows]


# Below this share of runs arrived under noise before the horizon, the hint
# to tune for it is printed: a run that settles only at the horizon counts as
# arrived, but the noise held it until the end.
_HINT_BELOW = 0.95


def hint(result: dict[str, Any], args: Any) -> str:
    """What to do about a loop that fails under noise, or ``""``."""
    noisy = result["condition"] in ("noise", "both")
    if not noisy or result["success"] - result["settled_at_horizon"] >= _HINT_BELOW:
        return ""
    from wmr_jax._src.model.robots import robot_from_values, robot_name

    name = robot_name(robot_from_values(result["robot"], "robot"))
    if args.robot:
        robot = f" --robot {args.robot}"
    elif name != "paper":
        robot = f" --robot {name or 'YOUR_ROBOT_FILE'}"
    else:
        robot = ""
    # Raw feedback: gains tuned without noise. With an estimator: tuned for another noise.
    why = (
        "these gains were not tuned for this noise"
        if result["feedback"] == "raw"
        else "fewer than 95 % of the runs arrived before the horizon under this noise"
    )
    after = "then evaluate DIR/tuned_gains.json"
    if getattr(args, "c", None) is not None:
        after = "then wmr-jax export --gains DIR/tuned_gains.json and evaluate --c its folder"
    return (
        f"hint: {why}; wmr-jax tune --robust{robot} --out DIR tunes gains and an estimator "
        f"for it (docs/robustness.md), {after}"
    )


def per_ref_csv(result: dict[str, Any], labels: list[str]) -> str:
    """The ``--per-ref`` table: one line per reference, in the order of ``--refs``."""
    lines = ["where,x_cm,y_cm,theta_rad,arrived,arrival_s,final_distance_cm,settled_at_horizon"]
    for label, r in zip(labels, result["per_reference"], strict=True):
        arrival = "" if r["arrival_s"] is None else f"{r['arrival_s']:.6g}"
        x, y, theta = (f"{v:.10g}" for v in r["ref"])
        lines.append(
            f"{label},{x},{y},{theta},{str(r['success']).lower()},{arrival},"
            f"{r['final_distance_cm']:.6g},{str(r['settled_at_horizon']).lower()}"
        )
    return "\n".join(lines) + "\n"


def _settings(args: Any) -> tuple[Any, Any, dict[str, Any]]:
    """The paths of ``--json`` and ``--per-ref`` and the checked run settings, ``--c`` or not."""
    out = None if args.json is None else flags.output_file("--json", args.json, ".json")
    settings = {
        "condition": flags.choice("--condition", args.condition, _CONDITIONS),
        "mismatch": _mismatch(args.mismatch),
        "seed": flags.positive_int("--seed", args.seed, 0, 2**32 - 1),
        "velocity": flags.velocity_loop(args.velocity),
    }
    per_ref = None if args.per_ref is None else flags.output_file("--per-ref", args.per_ref, ".csv")
    return out, per_ref, settings


# The library's names of the flags, in its errors.
_AS_FLAGS = {"refs": "--refs", "horizon": "--horizon", "mismatch": "--mismatch"}


def _finish(args: Any, out: Any, per_ref: Any, result: dict[str, Any], labels: Any) -> int:
    """Write ``--json`` and ``--per-ref`` where given, print the table and any hint; 0."""
    from wmr_jax._src.io import atomic_write_json, atomic_write_text
    from wmr_jax._src.report.tables import markdown_table

    if out is not None:
        atomic_write_json(out, result)
        print(f"evaluate -> {out}")
    if per_ref is not None:
        atomic_write_text(per_ref, per_ref_csv(result, labels))
        print(f"per reference -> {per_ref}")
    print(markdown_table(summary_rows(result, labels), ["quantity", "value"]), end="")
    advice = hint(result, args)
    if advice:
        print(advice)
    return 0


def run(args: Any) -> int:
    """Run ``wmr-jax evaluate``; return the exit status."""
    import warnings

    with warnings.catch_warnings():
        # unit_warnings names the file and its column instead.
        warnings.filterwarnings("ignore", message="refs has heading .* most likely degrees")
        return run_compiled(args) if args.c is not None else _run_jax(args)


def _run_jax(args: Any) -> int:
    if args.gains is None:
        raise ValueError("--gains is required; allowed: a tuned_gains.json (or --c DIR)")
    out, per_ref, settings = _settings(args)
    estimator = None
    if args.estimator is not None:
        estimator = flags.estimator(args.estimator) or "none"
    x64 = not args.float32
    from wmr_jax._src.identify.closed_loop import loaded_identified, tuned_for_identified

    identified = loaded_identified(args.robot)
    if identified is not None and (
        settings["condition"] != "nominal" or isinstance(args.mismatch, str)
    ):
        flag = "--condition" if settings["condition"] != "nominal" else "--mismatch"
        raise ValueError(
            f"{flag} is not allowed with --robot {args.robot}; allowed: the identified robot's "
            "own latency, tracker noise and wheel scales"
        )
    given = flags.robot_from(args.robot) if identified is None else identified[0]
    refs, labels = load_refs(args.refs, x64=x64)
    loop = _loop(args.gains, estimator)
    if identified is not None and tuned_for_identified(loop.robot, identified[1]):
        # Gains tuned with --robot identified.json run on the controller that believes the base.
        loop = loop._replace(robot=identified[0].robot)
    robot = flags.robot_for_gains(given, loop.robot, "--gains", args.gains)
    horizon = _horizon(args, refs, robot, None if given is None else given.note)

    from wmr_jax._src.studies.conditions import evaluate_loop
    from wmr_jax._src.tuning.saved import tuned_json

    with flags.as_flags(_AS_FLAGS):
        content = None if identified is None else identified[1]
        result = evaluate_loop(
            loop, refs, horizon=horizon, x64=x64, robot=robot, identified=content, **settings
        )
    # The gains themselves, not only where they were: the file may be tuned again.
    gains = tuned_json(loop.params, loop.estimator)
    result = {**result, "gains_file": str(args.gains), "gains": gains, "refs_file": str(args.refs)}
    if given is not None and flags.is_robot_file(args.robot):
        result["robot_file"] = str(args.robot)
    return _finish(args, out, per_ref, result, labels)


def run_compiled(args: Any) -> int:
    """``wmr-jax evaluate --c DIR``: the runs of ``--gains``, the commands of the compiled C."""
    from wmr_jax._src.export.compiled import compile_controller
    from wmr_jax._src.export.host import evaluate_compiled, exported_loop

    for flag, value in (("--gains", args.gains), ("--estimator", args.estimator)):
        if value is not None:
            raise ValueError(f"{flag} is not allowed with --c; allowed: the loop baked into the C")
    if args.float32:
        raise ValueError("--float32 is not allowed with --c; allowed: wmr-jax export --real float")
    out, per_ref, settings = _settings(args)
    given = flags.robot_from(args.robot)
    refs, labels = load_refs(args.refs)
    with flags.as_flags({"folder": "--c"}):
        loop, meta = exported_loop(args.c)
    robot = flags.robot_for_gains(given, loop.robot, "--c", args.c)
    horizon = _horizon(args, refs, robot)
    with flags.as_flags({"folder": "--c"}):
        compiled = compile_controller(args.c)
    with flags.as_flags(_AS_FLAGS):
        result = evaluate_compiled(compiled, loop, refs, horizon=horizon, robot=robot, **settings)
    result = {**result, "c_folder": str(args.c), "gains": meta["gains"], "refs_file": args.refs}
    return _finish(args, out, per_ref, result, labels)
