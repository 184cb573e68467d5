"""What identification buys: gains tuned for the base robot against gains tuned for the fitted one.

A synthetic true robot (the base with wheel scales 1.02 / 0.985, half-track
+4 %, latency 2 samples, tracker noise σ_xy = 0.3 cm and σ_θ = 0.5°) drives
the 5-minute plan of ``identify --plan``; ``identify`` fits it from that log.
``tune`` then tunes the fixed gains twice, for the base robot and for the
identified one (``--robot identified.json``: its fitted half-track and
wheel-loop gain), and a third time with ``tune --robust --fixed`` on the
identified robot (the standard noise, latency and mismatch of
docs/model.md §7, not the identified ones). All are judged on the *true*
robot with ``evaluate``'s machinery (``conditions.evaluate_loop`` with the
true robot as an identified one: each reference with its own noise draw,
the controller believing the base), on held-out references, with and
without the tracker noise, and on the base robot itself, each with raw
feedback and with an EKF (default parameters) that compensates the latency
of the robot it runs on. The table goes to docs/robots.md §6 (about 5
minutes on a loaded machine; ``--iters 80 --poses 64`` and
``--robust-iters 60`` keep the tuning short).

    python experiments/identify_payoff.py [--robot paper] [--iters 80] [--poses 64] \\
        [--robust-iters 60] [--refs 200] [--out results/identify_payoff]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np

from wmr_jax._src.identify import fit, plan
from wmr_jax._src.identify import result as output
from wmr_jax._src.model.robots import load_robot
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.studies.conditions import evaluate_loop

SCALE = (1.02, 0.985)
TRACK = 1.04
LATENCY = 2
SIGMA_XY, SIGMA_THETA = 0.3, math.radians(0.5)


def true_content(base) -> dict:
    """The true robot in the form of an ``identified.json``."""
    return {
        "robot": {
            "half_track": float(base.half_track) * TRACK,
            "speed_gain": float(base.speed_gain),
        },
        "wheel_scale": {"left": SCALE[0], "right": SCALE[1]},
        "latency_samples": LATENCY,
        "noise": {"sigma_xy": SIGMA_XY, "sigma_theta": SIGMA_THETA},
    }


def identify(base, out: Path, minutes: float, seed: int) -> Path:
    commands = plan.plan_commands(base, DEFAULT_DT, minutes, seed)
    truth = true_content(base)
    commands, measured, _ = plan.synthetic_log(
        commands, base, np.array(SCALE), truth["robot"]["half_track"],
        truth["robot"]["speed_gain"], LATENCY, DEFAULT_DT, SIGMA_XY, SIGMA_THETA,
        jax.random.PRNGKey(seed),
    )  # fmt: skip
    found = fit.fit_log([(np.asarray(commands), np.asarray(measured))], base, DEFAULT_DT)
    content = output.identified(base, found, ["synthetic"], DEFAULT_DT)
    return output.write(out, content)


def tune(robot: str, out: Path, iters: int, poses: int, robust: bool = False) -> Path:
    from wmr_jax._src.cli.main import main

    args = ["tune", "--out", str(out), "--robot", robot, "--iters", str(iters)]
    if robust:  # its own poses per iteration, no random search or before/after table
        args += ["--robust", "--fixed"]
    else:
        args += ["--poses", str(poses), "--no-random-search", "--eval-poses", "50"]
    if main(args) != 0:
        raise SystemExit(f"tune --robot {robot} failed")
    return out / "tuned_gains.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="paper")
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--iters", type=int, default=80)
    parser.add_argument("--poses", type=int, default=64)
    parser.add_argument("--robust-iters", type=int, default=60, help="0: no robust row")
    parser.add_argument("--refs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="results/identify_payoff")
    args = parser.parse_args()

    from wmr_jax._src.tuning.evaluation import held_out_poses
    from wmr_jax._src.tuning.saved import load_tuned

    out = Path(args.out)
    base = load_robot(args.robot)
    start = time.perf_counter()
    path = identify(base, out / "identified", args.minutes, args.seed)
    fitted = json.loads(path.read_text())
    print(f"identified in {time.perf_counter() - start:.1f} s: {path}")
    files = {
        "tuned for the base robot": tune(args.robot, out / "tune_base", args.iters, args.poses),
        "tuned for the identified robot": tune(
            str(path), out / "tune_identified", args.iters, args.poses
        ),
    }
    if args.robust_iters:
        files["tuned --robust --fixed for the identified robot"] = tune(
            str(path), out / "tune_identified_robust", args.robust_iters, args.poses, robust=True
        )
    with jax.enable_x64(True):
        refs = np.asarray(held_out_poses(args.refs, eval_seed=args.seed + 1))
    truth = true_content(base)
    rows = []
    quiet = {**truth, "noise": {"sigma_xy": 0.0, "sigma_theta": 0.0}}
    for name, file in files.items():
        for feedback in ("raw", "ekf"):
            # The controller believes the base robot whichever robot its gains were tuned for;
            # an EKF (its default parameters) compensates the latency of the robot it runs on.
            loop = load_tuned(str(file))._replace(robot=None)
            if feedback == "ekf":
                loop = loop._replace(estimator="ekf")
            judged = evaluate_loop(loop, refs, robot=base, identified=truth)
            still = evaluate_loop(loop, refs, robot=base, identified=quiet)
            nominal = evaluate_loop(loop, refs, robot=base, mismatch=0.0)
            rows.append(
                {
                    "gains": name + (", EKF" if feedback == "ekf" else ""),
                    "success_true": judged["success"],
                    "mean_arrival_true_s": judged["mean_arrival_s"],
                    "success_true_no_noise": still["success"],
                    "mean_arrival_true_no_noise_s": still["mean_arrival_s"],
                    "success_base": nominal["success"],
                    "mean_arrival_base_s": nominal["mean_arrival_s"],
                    "gains_values": {
                        f: float(getattr(loop.params, f)) for f in ("kr", "k_theta", "phi_m")
                    },
                }
            )
    record = {
        "robot": args.robot,
        "truth": truth,
        "fitted": {
            "wheel_scale": fitted["wheel_scale"],
            "half_track": fitted["robot"]["half_track"],
            "speed_gain": fitted["robot"]["speed_gain"],
            "latency_samples": fitted["latency_samples"],
            "noise": fitted["noise"],
        },
        "iters": args.iters,
        "robust_iters": args.robust_iters,
        "poses": args.poses,
        "refs": args.refs,
        "minutes": args.minutes,
        "rows": rows,
        "wall_s": time.perf_counter() - start,
    }
    (out / "identify_payoff.json").write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record["fitted"], indent=2))
    print(
        "| gains | true robot: success | mean arrival | true robot without tracker noise: "
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
    print(f"wall {record['wall_s']:.0f} s -> {out / 'identify_payoff.json'}")


def _s(value) -> str:
    return "none arrived" if value is None else f"{value:.3f} s"


if __name__ == "__main__":
    main()
