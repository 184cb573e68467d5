"""From a log to tuned gains: loops tuned for the base robot against those for the identified one.

A synthetic true robot (the base with wheel scales 1.015 / 0.99, half-track
+4 %, latency 2 samples, tracker noise σ_xy = 0.3 cm and σ_θ = 0.5°) drives
the 5-minute plan that ``wmr-jax identify --plan`` writes; its log (a CSV,
as a tracker would give it) goes through ``wmr-jax identify`` in a fresh
process (its wall time is recorded). Four loops are then tuned, each with
the command a user would type:

* ``tune --robot BASE`` and ``tune --robot identified.json``: the 7 fixed
  gains of the nominal problem, shortened (``--iters``, ``--poses``,
  ``--no-random-search``);
* ``tune --robust --fixed --robot BASE``: the robust tuner through the
  standard conditions (±3 % wheels, up to one sample of latency, noise up
  to twice 0.5 cm and 1°), and ``tune --robust --fixed --robot
  identified.json``: the same tuner with its training centred on the
  identified values (``tuning/centred.py``, docs/model.md §10); with
  ``--schedule-iters N`` both again without ``--fixed`` (the gain schedule
  and the EKF tuned together; far slower to compile and run).

Each is judged, with raw feedback and (where it was tuned without one)
with an EKF of default parameters added, which compensates the latency,
on held-out references on the true robot (its wheels,
half-track, latency and tracker noise; the controller believes the base,
as ``evaluate --robot`` an ``identified.json`` holding the truth runs it),
on the true robot without its tracker noise, and on the base robot itself.
Every stage is kept in ``--out`` and skipped when its file is there
(remove the folder to start again); the table goes to docs/robots.md §6.

    python experiments/identified_vs_base.py [--robot paper] [--iters 80] [--poses 64] \\
        [--robust-iters 120] [--schedule-iters 0] [--refs 200] [--out results/identified_vs_base]

With ``--log-only`` it writes the log and the truth and stops: ``--minutes 1``
gives ``docs/data/example_log.csv``, the log a newcomer can identify first.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

from wmr_jax._src.identify import plan
from wmr_jax._src.model.robots import load_robot, robot_json
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.studies.conditions import evaluate_loop

SCALE = (1.015, 0.99)
TRACK = 1.04
LATENCY = 2
SIGMA_XY, SIGMA_THETA = 0.3, math.radians(0.5)


def true_content(base) -> dict:
    """The true robot in the form of an ``identified.json`` (what ``evaluate --robot`` reads)."""
    return {
        "robot": {**robot_json(base), "half_track": float(base.half_track) * TRACK},
        "base_robot": robot_json(base),
        "wheel_scale": {"left": SCALE[0], "right": SCALE[1]},
        "latency_samples": LATENCY,
        "noise": {"sigma_xy": SIGMA_XY, "sigma_theta": SIGMA_THETA},
    }


def cli(*args: str) -> float:
    """Run ``python -m wmr_jax ARGS`` in a fresh process; return its wall time, s."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "wmr_jax", *args], check=True, env=env)
    return time.perf_counter() - start


def write_log(base, out: Path, robot: str, minutes: float, seed: int) -> Path:
    """The true robot driving the plan of ``identify --plan``: ``log.csv`` as a tracker logs it."""
    path = out / "log.csv"
    if path.exists():
        return path
    drive = out / "drive.csv"
    cli("identify", "--plan", str(drive), "--robot", robot, "--minutes", f"{minutes:g}",
        "--plan-dt", f"{DEFAULT_DT:g}", "--seed", str(seed))  # fmt: skip
    table = np.loadtxt(drive, delimiter=",", skiprows=1)
    truth = true_content(base)
    commands, measured, _ = plan.synthetic_log(
        table[:, 1:], base, np.array(SCALE), truth["robot"]["half_track"],
        float(base.speed_gain), LATENCY, DEFAULT_DT, SIGMA_XY, SIGMA_THETA,
        jax.random.PRNGKey(seed),
    )  # fmt: skip
    rows = np.column_stack([table[:, 0], np.asarray(commands), np.asarray(measured)])
    np.savetxt(path, rows, delimiter=",", header="t,v_cmd,omega_cmd,x,y,theta", comments="",
               fmt="%.6f")  # fmt: skip
    return path


def tune(robot: str, out: Path, args, robust: str | None) -> Path:
    """``tune`` (``robust`` None), ``tune --robust --fixed`` ("fixed") or ``tune --robust``."""
    if (out / "tuned_gains.json").exists():
        return out / "tuned_gains.json"
    flags = ["tune", "--out", str(out), "--robot", robot]
    if robust == "fixed":
        flags += ["--robust", "--fixed", "--iters", str(args.robust_iters)]
    elif robust == "schedule":
        flags += ["--robust", "--iters", str(args.schedule_iters)]
    else:
        flags += ["--iters", str(args.iters), "--poses", str(args.poses)]
        flags += ["--no-random-search", "--eval-poses", "50"]
    cli(*flags)
    return out / "tuned_gains.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="paper")
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--iters", type=int, default=80)
    parser.add_argument("--poses", type=int, default=64)
    parser.add_argument("--robust-iters", type=int, default=120, help="0: no --fixed rows")
    parser.add_argument(
        "--schedule-iters", type=int, default=0, help="of the schedule and EKF; 0: no rows"
    )
    parser.add_argument("--refs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="results/identified_vs_base")
    parser.add_argument(
        "--log-only",
        action="store_true",
        help="write the true robot's log.csv and truth.json, then stop (docs/data/example_log.csv "
        "is the 1-minute one)",
    )
    args = parser.parse_args()
    if args.log_only:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        base = load_robot(args.robot)
        (out / "log.csv").unlink(missing_ok=True)  # written anew at these minutes
        write_log(base, out, args.robot, args.minutes, args.seed)
        (out / "truth.json").write_text(json.dumps(true_content(base), indent=2) + "\n")
        return

    from wmr_jax._src.tuning.evaluation import held_out_poses
    from wmr_jax._src.tuning.saved import load_tuned, tuned_json

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record_path = out / "identified_vs_base.json"
    record = json.loads(record_path.read_text()) if record_path.exists() else {}
    base = load_robot(args.robot)
    log = write_log(base, out, args.robot, args.minutes, args.seed)
    identified = out / "identified" / "identified.json"
    if not identified.exists():
        load = os.getloadavg()[0]
        wall = cli("identify", "--log", str(log), "--robot", args.robot, "--out",
                   str(identified.parent))  # fmt: skip
        record["identify"] = {"wall_s": wall, "load_average": load, "cores": os.cpu_count()}
    fitted = json.loads(identified.read_text())
    record["fitted"] = {
        k: fitted[k] for k in ("wheel_scale", "latency_samples", "noise", "ci95")
    } | {"half_track": fitted["robot"]["half_track"], "speed_gain": fitted["robot"]["speed_gain"]}
    record["truth"] = true_content(base)
    files = {
        "`tune --robot BASE`": tune(args.robot, out / "tune_base", args, None),
        "`tune --robot identified.json`": tune(
            str(identified), out / "tune_identified", args, None
        ),
    }
    for problem, count, flag in (
        ("fixed", args.robust_iters, "--robust --fixed"),
        ("schedule", args.schedule_iters, "--robust"),
    ):
        if count:
            files[f"`tune {flag} --robot BASE`"] = tune(
                args.robot, out / f"robust_{problem}_base", args, problem
            )
            files[f"`tune {flag} --robot identified.json`"] = tune(
                str(identified), out / f"robust_{problem}_identified", args, problem
            )
    with jax.enable_x64(True):
        refs = np.asarray(held_out_poses(args.refs, eval_seed=args.seed + 1))
    truth = record["truth"]
    quiet = {**truth, "noise": {"sigma_xy": 0.0, "sigma_theta": 0.0}}
    rows = []
    loops = {}
    for name, file in files.items():
        # The controller believes the base robot whichever robot its gains were tuned for.
        loops[name] = load_tuned(str(file))._replace(robot=None)
        if loops[name].estimator is None:
            # Beside raw feedback, an EKF of default parameters: it compensates the latency.
            loops[name + ", EKF added"] = loops[name]._replace(estimator="ekf")
    for name, loop in loops.items():
        judged = evaluate_loop(loop, refs, robot=base, identified=truth)
        still = evaluate_loop(loop, refs, robot=base, identified=quiet)
        nominal = evaluate_loop(loop, refs, robot=base, mismatch=0.0)
        rows.append(
            {
                "gains": name,
                "success_true": judged["success"],
                "mean_arrival_true_s": judged["mean_arrival_s"],
                "success_true_no_noise": still["success"],
                "mean_arrival_true_no_noise_s": still["mean_arrival_s"],
                "success_base": nominal["success"],
                "mean_arrival_base_s": nominal["mean_arrival_s"],
                "gains_values": tuned_json(loop.params, loop.estimator),
            }
        )
    record.update(
        robot=args.robot, iters=args.iters, robust_iters=args.robust_iters,
        schedule_iters=args.schedule_iters, poses=args.poses, refs=args.refs,
        minutes=args.minutes, rows=rows,
    )  # fmt: skip
    record_path.write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps({k: record[k] for k in ("identify", "fitted") if k in record}, indent=2))
    print(
        "| gains | true robot: success | mean arrival | true robot, no tracker noise: "
        "success | mean arrival | base robot: success | mean arrival |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['gains']} | {100 * r['success_true']:.1f} % | {_s(r['mean_arrival_true_s'])} "
            f"| {100 * r['success_true_no_noise']:.1f} % "
            f"| {_s(r['mean_arrival_true_no_noise_s'])} "
            f"| {100 * r['success_base']:.1f} % | {_s(r['mean_arrival_base_s'])} |"
        )
    print(f"-> {record_path}")


def _s(value) -> str:
    return "none arrived" if value is None else f"{value:.3f} s"


if __name__ == "__main__":
    main()
