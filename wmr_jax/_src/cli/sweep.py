"""``wmr-jax sweep``: map success, arrival, path, wheel speed and zig-zag over a pose space.

Runs ``wmr_jax.studies.map_study`` on a grid of reference poses for every
controller asked for (a square grid inside the 5–80 cm annulus at a few
headings: its means differ from ``wmr-jax compare``'s random poses), then
writes ``maps_<controller>.png``, ``winner.png``, ``summary.md`` and
``summary.json`` into ``--out`` (``wmr_jax.report.save_map_study``) and
prints the summary table.
"""

from __future__ import annotations

import warnings
from typing import Any

from wmr_jax._src.cli import flags

__all__ = ["SUBCOMMANDS"]


def _flags() -> dict[str, dict[str, Any]]:
    """Flag -> ``add_argument`` keywords, in ``--help`` order (values are checked in ``run``)."""
    from wmr_jax._src.controllers import registered_names
    from wmr_jax._src.maps import DEFAULT_CHUNK, DEFAULT_HEADINGS_DEG

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
            "default": None,
            "metavar": "NAME",
            "help": "controllers to compare, repeatable (none given: every registered one: "
            + ", ".join(registered_names())
            + ")",
        },
        "--velocity": {"default": "ideal", "help": "velocity loop: ideal or nonideal"},
        "--headings": {
            "nargs": "+",
            "action": "extend",
            "default": None,
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
            "help": "keep finished chunks under OUT/chunks and reuse them when run again",
        },
    }


def run(args: Any) -> int:
    """Run ``wmr-jax sweep``; return the exit status."""
    from wmr_jax._src.maps import DEFAULT_HEADINGS_DEG, map_study
    from wmr_jax._src.report.maps import comparison_table, save_map_study
    from wmr_jax._src.sweep import OtherSettingsWarning

    out = flags.output_dir("--out", args.out)
    n_poses = flags.positive_int("--poses", args.poses)
    chunk = flags.positive_int("--chunk", args.chunk)
    headings = [
        flags.number("--headings", h, unit="degrees") for h in args.headings or DEFAULT_HEADINGS_DEG
    ]
    names = flags.controller_names(args.controller)
    velocity = flags.velocity_loop(args.velocity)
    library_names = {"n_poses": "--poses", "headings_deg": "--headings", "chunk": "--chunk"}
    with warnings.catch_warnings(), flags.as_flags(library_names):
        # --resume asks for the finished chunks: chunks of other settings are
        # refused, not replaced (as tune --resume refuses another run).
        warnings.simplefilter("error", OtherSettingsWarning)
        try:
            study = map_study(
                n_poses,
                controller_names=names,
                velocity=velocity,
                headings_deg=headings,
                chunk=chunk,
                progress=not args.no_progress,
                x64=not args.float32,
                cache=out / "chunks" if args.resume else None,
            )
        except OtherSettingsWarning as err:
            raise ValueError(
                f"--resume: {err}; allowed: the same settings, or a fresh --out"
            ) from None
    save_map_study(out, study)
    print(f"{study.summary['poses']} poses -> {out}/maps_*.png, summary.md, summary.json")
    print(comparison_table(study.rows), end="")
    return 0


SUBCOMMANDS = {
    "sweep": {
        "help": "map success, arrival, path, wheel speed and zig-zag over a pose space",
        "flags": _flags,
        "run": run,
    },
}
