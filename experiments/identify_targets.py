"""The figures of ``wmr-jax identify`` against its targets (docs/model.md §10, docs/robots.md).

Synthetic logs from robots the fit does not know (wheel scales within
±1.5 %, half-track within ±4 %, wheel-loop gain 40–150 1/s, latency 0–3
samples), σ_xy = 0.3 cm and σ_θ = 0.5°, driving the plan of
``identify --plan``:

* accuracy and wall time of one 5-minute log at 20 and 30 Hz;
* coverage of the 95 % intervals over a batch of robots fitted in one ``vmap``;
* UMBmark (Borenstein & Feng 1996) and finite-difference Gauss–Newton on the
  same logs: error and wall time side by side.

    python experiments/identify_targets.py [--robots 100] [--coverage-minutes 1] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import os
import time

import jax
import numpy as np

from wmr_jax._src.identify import fit, plan, umbmark
from wmr_jax._src.model.robots import load_robot

SIGMA_XY, SIGMA_THETA = 0.3, math.radians(0.5)


def draw(rng, base):
    scale = 1 + rng.uniform(-0.015, 0.015, 2)
    return {
        "scale": scale,
        "half_track": float(base.half_track) * rng.uniform(0.96, 1.04),
        "speed_gain": rng.uniform(40, 150),
        "latency": int(rng.integers(0, 4)),
    }


def log_of(commands, base, truth, dt, seed):
    return plan.synthetic_log(
        commands, base, truth["scale"], truth["half_track"], truth["speed_gain"],
        truth["latency"], dt, SIGMA_XY, SIGMA_THETA, jax.random.PRNGKey(seed),
    )  # fmt: skip


def errors(found, truth):
    return {
        "scale_left_%": 100 * abs(found.wheel_scale[0] / truth["scale"][0] - 1),
        "scale_right_%": 100 * abs(found.wheel_scale[1] / truth["scale"][1] - 1),
        "half_track_%": 100 * abs(found.half_track / truth["half_track"] - 1),
        "speed_gain_%": 100 * abs(found.speed_gain / truth["speed_gain"] - 1),
        "latency_ok": found.latency == truth["latency"],
        "sigma_xy_%": 100 * abs(found.sigma_xy / SIGMA_XY - 1),
        "sigma_theta_%": 100 * abs(found.sigma_theta / SIGMA_THETA - 1),
    }


def show(label, errs, seconds=None, cpu=None):
    text = "  ".join(
        f"{k}={v:.4f}" if isinstance(v, float) else f"{k}={v}" for k, v in errs.items()
    )
    tail = "" if seconds is None else f"  [{seconds:.1f} s"
    tail += "" if cpu is None else f", process CPU {cpu:.1f} s"
    tail += "" if seconds is None else "]"
    print(f"{label:<28}{text}{tail}", flush=True)


def accuracy(base, rng, minutes):
    for hz in (20, 30):
        dt = 1 / hz
        truth = draw(rng, base)
        commands = plan.plan_commands(base, dt, minutes, seed=hz)
        c, z, _ = log_of(commands, base, truth, dt, hz)
        for attempt in ("first (compiles)", "second"):
            start, cpu = time.perf_counter(), time.process_time()
            found = fit.fit_log([(c, z)], base, dt)
            seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
            show(f"{hz} Hz, {minutes:g} min, {attempt}", errors(found, truth), seconds, cpu)
        ros = (
            found.wheel_scale[0] / truth["scale"][0] - 1,
            found.wheel_scale[1] / truth["scale"][1] - 1,
            found.half_track / truth["half_track"] - 1,
        )
        print(f"  ROS multipliers' errors (%): {', '.join(f'{100 * abs(e):.4f}' for e in ros)}")


def coverage(base, rng, robots, minutes, seed=0):
    dt = 0.04
    commands = plan.plan_commands(base, dt, minutes, seed=1)
    truths, segs = [], []
    for i in range(robots):
        truth = draw(rng, base)
        c, z, _ = log_of(commands, base, truth, dt, 1000 * (seed + 1) + i)
        truths.append(truth)
        segs.append(fit.segments_of(c, z))
    start, cpu = time.perf_counter(), time.process_time()
    found = fit.fit_batch(segs, base, dt)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    names = {
        "wheel_scale_left": lambda t: t["scale"][0],
        "wheel_scale_right": lambda t: t["scale"][1],
        "half_track": lambda t: t["half_track"],
        "speed_gain": lambda t: t["speed_gain"],
        "sigma_xy": lambda t: SIGMA_XY,
        "sigma_theta": lambda t: SIGMA_THETA,
    }
    print(
        f"coverage: {robots} robots, {minutes:g} min each, "
        f"one batch in {seconds:.1f} s (process CPU {cpu:.1f} s)"
    )
    for name, value in names.items():
        inside = [
            f.ci95[name][0] <= value(t) <= f.ci95[name][1]
            for f, t in zip(found, truths, strict=True)
        ]
        # The error in units of the interval's σ: a bias moves the mean, a σ too small the spread.
        z = [
            (sum(f.ci95[name]) / 2 - value(t)) / ((f.ci95[name][1] - f.ci95[name][0]) / 2 / 1.96)
            for f, t in zip(found, truths, strict=True)
        ]
        print(
            f"  95 % interval of {name:<18} covers the truth in {100 * np.mean(inside):.0f} % "
            f"(error / σ: mean {np.mean(z):+.2f}, spread {np.std(z):.2f})"
        )
    latency = np.mean([f.latency == t["latency"] for f, t in zip(found, truths, strict=True)])
    print(f"  latency exact in {100 * latency:.0f} %")


def baselines(base, rng, minutes):
    dt = 0.04
    truth = draw(rng, base)
    side = min(200.0, 4 * 0.5 * float(base.v_max))
    cw = plan.square_commands(base, dt, side, True)
    ccw = plan.square_commands(base, dt, side, False)
    runs = max(1, int(minutes * 60 / dt) // (len(cw) + len(ccw)))
    commands = np.concatenate([cw, ccw] * runs)
    c, z, _ = log_of(commands, base, truth, dt, 77)
    n = len(cw)
    starts_cw = [2 * n * k for k in range(runs)]
    starts_ccw = [2 * n * k + n for k in range(runs)]
    start = time.perf_counter()
    left, right, track = umbmark.umbmark(
        umbmark.square_ends(z, starts_cw, [s + n - 1 for s in starts_cw]),
        umbmark.square_ends(z, starts_ccw, [s + n - 1 for s in starts_ccw]),
        side,
        float(base.half_track),
    )
    seconds = time.perf_counter() - start
    print(f"baselines on {runs} squares each way ({len(commands) * dt / 60:.1f} min of squares):")
    umb = {
        "scale_left_%": 100 * abs(left / truth["scale"][0] - 1),
        "scale_right_%": 100 * abs(right / truth["scale"][1] - 1),
        "half_track_%": 100 * abs(track / truth["half_track"] - 1),
        "ratio_R/L_%": 100 * abs((right / left) / (truth["scale"][1] / truth["scale"][0]) - 1),
    }
    show("UMBmark", umb, seconds)
    for jacobian, attempt in [(j, a) for j in ("exact", "fd") for a in ("first", "second")]:
        start = time.perf_counter()
        found = fit.fit_batch([fit.segments_of(c, z)], base, dt, jacobian=jacobian)[0]
        seconds = time.perf_counter() - start
        errs = errors(found, truth)
        ratio = (found.wheel_scale[1] / found.wheel_scale[0]) / (
            truth["scale"][1] / truth["scale"][0]
        )
        errs["ratio_R/L_%"] = 100 * abs(ratio - 1)
        label = "identify (jacfwd)" if jacobian == "exact" else "finite-difference GN"
        show(f"{label}, {attempt}", errs, seconds)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--robot", default="pioneer-3dx")
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--coverage-minutes", type=float, default=1.0)
    parser.add_argument("--parts", default="accuracy,baselines,coverage")
    # Another seed draws other robots and other noise: an independent sample.
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    base = load_robot(args.robot)
    rng = np.random.default_rng(args.seed)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; base {args.robot}")
    parts = args.parts.split(",")
    if "accuracy" in parts:
        accuracy(base, rng, args.minutes)
    if "baselines" in parts:
        baselines(base, rng, args.minutes)
    if "coverage" in parts:
        coverage(base, rng, args.robots, args.coverage_minutes, args.seed)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
