"""Time ``wmr_jax.sweep`` over many poses on whatever devices JAX finds.

Usage: ``python experiments/time_sweep.py [--poses N] [--steps S] [--chunk C]
[--repeats R] [--cpu-devices K] [--json FILE]`` (defaults: 10⁷ poses, 150
steps, chunks of 2²⁰, 3 timed runs after a first one; float32). Prints the
first call (tracing and compilation included), the median of the timed
calls, robot-steps per second and the process's peak resident memory, and
writes them with the devices and JAX's version to ``--json``. docs/scale.md
quotes it.
"""

import argparse
import json
import resource
import statistics
import sys
import time

import numpy as np


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10_000_000)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--chunk", type=int, default=2**20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu-devices", type=int, default=None, help="split the CPU first")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)

    import wmr_jax as w

    if args.cpu_devices is not None:
        w.studies.use_cpu_devices(args.cpu_devices)
    import jax

    refs = np.asarray(w.sample_poses(0, args.poses), dtype=np.float32)
    gains = w.Gains(kr=60.0)

    def once() -> float:
        start = time.perf_counter()
        out = w.sweep(refs, gains, steps=args.steps, chunk_size=args.chunk)
        assert out["success"].shape == (args.poses,)
        return time.perf_counter() - start

    first = once()
    runs = [once() for _ in range(args.repeats)]
    median = statistics.median(runs)
    devices = jax.local_devices()
    record = {
        "poses": args.poses,
        "steps": args.steps,
        "chunk": args.chunk,
        "first_call_s": first,
        "runs_s": runs,
        "median_s": median,
        "robot_steps_per_s": args.poses * args.steps / median,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "backend": jax.default_backend(),
        "device": devices[0].device_kind,
        "devices": len(devices),
        "jax": jax.__version__,
    }
    print(json.dumps(record, indent=1))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(record, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
