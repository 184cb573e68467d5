"""What each committed docs figure and data file was computed with, and whether it still holds.

``experiments/reproduce_readme.sh`` calls ``python experiments/docs_fingerprint.py
record STAGE`` after each stage. That stores, in ``docs/data/fingerprints.json``:

* a *probe* of every simulation the stage's outputs depend on: a few fixed
  references run through that loop (the law, a baseline, the non-ideal
  robot, an estimator under noise, ...), their final poses, arrival times
  and path lengths in float64;
* the SHA-256 of every file the stage copied into ``docs/``.

``check`` (and ``tests/test_readme.py``) recomputes the probes with the code
as it is and compares: a change to the law, a baseline, a loop or an
estimator that moves any probe beyond 1e-9 names the stale stage and the
command that regenerates it; an edit to a committed file that did not come
from its stage is caught by its checksum. The probes cover the simulation,
not the optimisers: the tuned gains themselves are checked through the
tables of README.md and the docs pages.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "data" / "fingerprints.json"
TOLERANCE = 1e-9

# The references every probe runs: near and far, ahead and behind, pure turns.
_PROBE_REFS_DEG = (
    (30.0, 20.0, 90.0),
    (-40.0, 10.0, 180.0),
    (5.0, -60.0, -45.0),
    (0.0, 3.0, 0.0),
    (70.0, 0.0, -170.0),
)
_STEPS = 150

# Which loops each stage's outputs depend on, and the files it writes to docs/.
STAGES: dict[str, dict[str, tuple[str, ...]]] = {
    "paper": {
        "probes": ("shim-sung", "shim-sung-nonideal"),
        "files": (
            "fig6.png",
            "fig7.png",
            "fig8.png",
            "fig9.png",
            "fig10.png",
            "wheels_k120.png",
            "data/paper_table.json",
        ),
    },
    "compare": {
        "probes": ("shim-sung", "aicardi", "astolfi-corke"),
        "files": ("data/comparison.json",),
    },
    "maps": {
        "probes": ("shim-sung", "aicardi", "astolfi-corke"),
        "files": ("maps_shim-sung.png", "winner.png", "data/maps_summary.json"),
    },
    "waypoints": {"probes": ("shim-sung",), "files": ("soccer.png", "data/soccer.json")},
    "animate": {"probes": ("shim-sung",), "files": ("robots.gif",)},
    "tune": {"probes": ("shim-sung", "schedule"), "files": ("tuning_curve.png",)},
    "robustness": {
        "probes": (
            "shim-sung",
            "aicardi",
            "astolfi-corke",
            "shim-sung-nonideal",
            "schedule",
            "noisy-raw",
            "noisy-ekf",
        ),
        "files": (
            "robustness.png",
            "standard_conditions.png",
            "noise_curve.png",
            "data/standard_conditions.json",
        ),
    },
}


def _refs() -> np.ndarray:
    refs = np.array(_PROBE_REFS_DEG, dtype=np.float64)
    refs[:, 2] = np.deg2rad(refs[:, 2])
    return refs


def _trajectory_probe(controller: str, velocity: str = "ideal") -> list[float]:
    import wmr_jax as w

    params = None
    if controller == "schedule":
        from wmr_jax.controllers import SCHEDULE, ScheduleParams

        controller, params = SCHEDULE, ScheduleParams()
    traj = w.batch_rollout(_refs(), params, steps=_STEPS, controller=controller, velocity=velocity)
    return _summary(np.asarray(traj.poses), _refs(), traj)


def _summary(poses: np.ndarray, refs: np.ndarray, traj=None) -> list[float]:
    import wmr_jax as w

    values = [poses[:, -1, :].ravel()]
    if traj is not None:
        values.append(np.asarray(w.arrival_time(traj, refs, dt=w.DEFAULT_DT)))
    steps = np.diff(poses[..., :2], axis=1)
    values.append(np.hypot(steps[..., 0], steps[..., 1]).sum(axis=1))
    return [float(v) for v in np.concatenate(values)]


def _noisy_probe(estimator: str | None) -> list[float]:
    import jax

    from wmr_jax import studies

    refs = _refs()
    disturbance = studies.sample_disturbance(
        jax.random.key(0),
        refs,
        _STEPS,
        noise_xy=1.0,
        noise_theta=float(np.deg2rad(2.0)),
        latency=1.0,
        radius_mismatch=0.03,
    )
    run = studies.disturbed_rollout(disturbance, estimator=estimator)
    return _summary(np.asarray(run["poses"]), refs)


PROBES: dict[str, Callable[[], list[float]]] = {
    "shim-sung": lambda: _trajectory_probe("shim-sung"),
    "shim-sung-nonideal": lambda: _trajectory_probe("shim-sung", "nonideal"),
    "aicardi": lambda: _trajectory_probe("aicardi"),
    "astolfi-corke": lambda: _trajectory_probe("astolfi-corke"),
    "schedule": lambda: _trajectory_probe("schedule"),
    "noisy-raw": lambda: _noisy_probe(None),
    "noisy-ekf": lambda: _noisy_probe("ekf"),
}


def probe(name: str) -> list[float]:
    """The probe ``name`` computed with the code as it is, in float64."""
    import warnings

    import jax

    with jax.enable_x64(True), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the paper's Fig. 7 gains exceed V_max, as they do there
        return PROBES[name]()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _read() -> dict:
    return json.loads(RECORD.read_text()) if RECORD.is_file() else {}


def record(stage: str) -> None:
    """Store the probes and checksums of ``stage``'s outputs as they are now."""
    spec = STAGES[stage]
    entry = {
        "probes": {name: probe(name) for name in spec["probes"]},
        "files": {name: _sha256(ROOT / "docs" / name) for name in spec["files"]},
    }
    stored = _read()
    stored[stage] = entry
    RECORD.write_text(json.dumps(dict(sorted(stored.items())), indent=1) + "\n")


def check(stages: list[str] | None = None) -> list[str]:
    """The stale stages, each as one line saying what moved; empty if all hold."""
    stored = _read()
    problems = []
    cache: dict[str, list[float]] = {}
    for stage in stages or list(STAGES):
        spec, entry = STAGES[stage], stored.get(stage)
        rerun = f"rerun experiments/reproduce_readme.sh results/readme {stage}"
        if entry is None:
            problems.append(f"{stage}: no fingerprint recorded; {rerun}")
            continue
        for name in spec["probes"]:
            if name not in cache:
                cache[name] = probe(name)
            was = np.asarray(entry["probes"].get(name, []), dtype=np.float64)
            now = np.asarray(cache[name], dtype=np.float64)
            if was.shape != now.shape or not np.allclose(
                now, was, rtol=TOLERANCE, atol=TOLERANCE, equal_nan=True
            ):
                gap = np.max(np.abs(now - was)) if was.shape == now.shape else "shape"
                problems.append(f"{stage}: the {name} loop moved (by {gap}); {rerun}")
        for name in spec["files"]:
            path = ROOT / "docs" / name
            if not path.is_file() or _sha256(path) != entry["files"].get(name):
                problems.append(f"{stage}: docs/{name} is not the file its stage wrote; {rerun}")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="store a stage's probes and file checksums")
    rec.add_argument("stage", choices=list(STAGES))
    chk = sub.add_parser("check", help="name the stages whose outputs no longer hold")
    # No ``choices`` here: Python < 3.12 checks the empty list (every stage) against them.
    chk.add_argument("stage", nargs="*", help=f"default: every stage ({', '.join(STAGES)})")
    args = parser.parse_args(argv)
    if args.command == "check":
        unknown = [stage for stage in args.stage if stage not in STAGES]
        if unknown:
            parser.error(f"stage = {unknown[0]!r} is not allowed; allowed: {', '.join(STAGES)}")
    if args.command == "record":
        record(args.stage)
        return 0
    problems = check(args.stage)
    print("\n".join(problems) or "every docs stage holds")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
