"""``wmr-jax sweep``: map success, arrival, path, wheel speed and zig-zag over a pose space."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path
from typing import Any

from wmr_jax._src.cli import flags


def _flags() -> dict[str, dict[str, Any]]:
    """Flag -> ``add_argument`` keywords, in ``--help`` order (values are checked in ``run``)."""
    from wmr_jax._src.model.controllers import registered_names
    from wmr_jax._src.studies.maps import DEFAULT_CHUNK, DEFAULT_HEADINGS_DEG

    return {
        "--out": {"required": True, "metavar": "DIR", "help": "output folder"},
        "--poses": {
            "default": 20000,
            "metavar": "N",
            "help": "about how many reference poses in all (grid × headings)",
        },
        "--controller": {
            "nargs": "+",
            "action": "extend",
            "metavar": "NAME",
            "help": "controllers to compare, repeatable (none given: every registered one: "
            + ", ".join(registered_names())
            + ")",
        },
        "--velocity": {"default": "ideal", "help": "velocity loop: ideal or nonideal"},
        "--horizon": {
            "metavar": "S",
            "help": "simulated time per run, s (default: the paper robot's 6 s, docs/model.md "
            "§6; for a --robot whose wheels cannot follow the paper's feasible gains, "
            "60 + 10 L > v_max, 6 s × (60 + 10 L) / v_max rounded up to 0.1 s, as those gains are "
            "scaled to fit; printed with the robot)",
        },
        "--headings": {
            "nargs": "+",
            "action": "extend",
            "metavar": "DEG",
            "help": "reference headings of the maps, degrees, repeatable (default: "
            + " ".join(f"{h:g}" for h in DEFAULT_HEADINGS_DEG)
            + ")",
        },
        "--chunk": {"default": DEFAULT_CHUNK, "metavar": "N", "help": "poses per compiled call"},
        "--no-progress": {"action": "store_true", "help": "no progress bar"},
        "--float32": {
            "action": "store_true",
            "help": "compute in float32, JAX's default (default: float64)",
        },
        "--resume": {
            "action": "store_true",
            "help": "keep each finished chunk under OUT/chunks as it is done, and reuse those "
            "of the same settings when run again (an interrupted run says what it kept); "
            "without it, nothing is kept",
        },
    }


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax sweep``."""
    for flag, options in _flags().items():
        parser.add_argument(flag, **options)
    flags.add_robot_flag(parser)


def study_settings(args: Any) -> tuple[Any, dict[str, Any]]:
    """``--robot``'s ``LoadedRobot`` (or ``None``) and the checked keywords of a map study; said."""
    from wmr_jax._src.model.params import Robot
    from wmr_jax._src.studies.robustness import study_horizon

    velocity = flags.velocity_loop(args.velocity)
    chunk = flags.positive_int("--chunk", args.chunk)
    given = flags.robot_from(args.robot)
    robot = Robot() if given is None else given.robot
    if args.horizon is None:
        horizon = study_horizon(robot)
    else:
        horizon = flags.horizon("--horizon", args.horizon, robot)
    scaled = args.horizon is None and horizon > 6
    scaled = " (6 s × (60 + 10 L) / v_max, rounded up to 0.1 s)" if scaled else ""
    flags.say_robot(given, f"; horizon {horizon:.4g} s{scaled}")
    return given, {
        "velocity": velocity,
        "chunk": chunk,
        "progress": not args.no_progress,
        "x64": not args.float32,
        "robot": robot,
        "horizon": horizon,
    }


def _interrupted(finished: dict[str, tuple[int, int]], chunks: Path | None) -> str:
    """What an interrupted sweep kept, in one line (``chunks``: the folder, with --resume)."""
    done = ", ".join(
        f"{name} {count} of {total} chunk{'s' if total > 1 else ''}"
        for name, (count, total) in finished.items()
        if count
    )
    if chunks is None:
        what = f" ({done} finished)" if done else ""
        return (
            f"wmr-jax: interrupted; nothing was kept{what}: --resume keeps each finished chunk "
            "under OUT/chunks for the next run"
        )
    if not done:
        return f"wmr-jax: interrupted before a chunk was finished; nothing new kept in {chunks}"
    return (
        f"wmr-jax: interrupted; kept in {chunks}: {done} (the same command, with --resume, "
        "reuses them)"
    )


def run(args: Any) -> int:
    """Run ``wmr-jax sweep``; return the exit status (130 when interrupted)."""
    out = flags.output_dir("--out", args.out)
    chunks = out / "chunks" if args.resume else None
    finished: dict[str, tuple[int, int]] = {}
    try:
        return _run(args, out, chunks, finished)
    except KeyboardInterrupt:
        print(_interrupted(finished, chunks), file=sys.stderr)
        return 130


def _run(args: Any, out: Path, chunks: Path | None, finished: dict) -> int:
    """The sweep; ``finished[controller]`` counts its chunks done, as they are done."""
    from wmr_jax._src.report.maps import comparison_table, save_map_study
    from wmr_jax._src.studies.maps import DEFAULT_HEADINGS_DEG, map_study
    from wmr_jax._src.studies.sweep_files import OtherSettingsWarning

    n_poses = flags.positive_int("--poses", args.poses)
    headings = [
        flags.number("--headings", h, unit="degrees") for h in args.headings or DEFAULT_HEADINGS_DEG
    ]
    fractions = [h for h in headings if h != round(h)]
    if args.headings and fractions and all(abs(h) <= math.pi + 1e-3 for h in headings):
        flags.warn_if_radians("--headings", " ".join(args.headings), fractions[0])  # ±π: rad?
    names = flags.controller_names(args.controller)
    given, settings = study_settings(args)

    def on_chunk(name: str, done: int, total: int) -> None:
        finished[name] = (done, total)

    if chunks is not None:  # said before the run, progress bar or not
        found = {n: len(list((chunks / n).glob("chunk_*.npz"))) for n in names}
        if any(found.values()):
            counts = ", ".join(f"{n} {k}" for n, k in found.items() if k)
            print(
                f"--resume: finished chunks in {chunks} ({counts}): reused if they are of "
                "these settings (chunks of others are refused), the rest computed",
                flush=True,
            )
        else:  # a mistyped --out would otherwise start over without a word
            of = ", ".join(names)
            said = f"--resume: no finished chunks of {of} in {chunks}; starting from the first"
            print(said, flush=True)

    library_names = {
        "n_poses": "--poses",
        "headings_deg": "--headings",
        "chunk": "--chunk",
        "horizon": "--horizon",
    }
    with warnings.catch_warnings(), flags.as_flags(library_names):
        # --resume asks for the finished chunks: chunks of other settings are
        # refused, not replaced (as tune --resume refuses another run).
        warnings.simplefilter("error", OtherSettingsWarning)
        try:
            study = map_study(
                n_poses,
                controller_names=names,
                headings_deg=headings,
                cache=chunks,
                on_chunk=on_chunk,
                **settings,
            )
        except OtherSettingsWarning as err:
            raise ValueError(
                f"--resume: {err}; allowed: the same settings, or a fresh --out"
            ) from None
    if given is not None:
        study.summary["robot_label"] = given.label  # the preset's name or the file
    save_map_study(out, study)
    print(f"{study.summary['poses']} poses -> {out}/maps_*.png, summary.md, summary.json")
    print(comparison_table(study.rows), end="")
    return 0
