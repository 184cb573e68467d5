"""``wmr-jax bench``: robot-steps per second against NumPy baselines."""

from __future__ import annotations

import functools
import sys
from typing import Any

from wmr_jax._src.cli import flags
from wmr_jax._src.sim.poses import MAX_SAMPLES
from wmr_jax._src.studies import bench

# The integer flags: (flag, attribute, default, metavar, help).
_INT_FLAGS = (
    (
        "--steps",
        "steps",
        bench.DEFAULT_STEPS,
        "N",
        "control periods per run (the same for any --robot: throughput does not depend on how "
        "far a run gets)",
    ),
    ("--repeats", "repeats", bench.DEFAULT_REPEATS, "N", "timed calls per case (the median)"),
    (
        "--reference-poses",
        "reference_poses",
        bench.DEFAULT_REFERENCE_POSES,
        "K",
        "poses the scalar NumPy reference is timed on",
    ),
)


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax bench``."""
    parser.add_argument(
        "--sizes",
        nargs="+",
        action="extend",
        metavar="N",
        help="batch sizes, repeatable (default: "
        + " ".join(str(n) for n in bench.DEFAULT_SIZES)
        + ")",
    )
    for flag, _, default, metavar, text in _INT_FLAGS:
        parser.add_argument(flag, default=default, metavar=metavar, help=text)
    parser.add_argument("--dtype", default="float32", help=" or ".join(bench.DTYPES))
    parser.add_argument(
        "--cases",
        nargs="+",
        action="extend",
        metavar="CASE",
        help="only these cases, among "
        + ", ".join(bench.CASES)
        + " (default: all of them); a grad_* case also times its loss's forward pass and "
        "one forward-mode derivative (jvp_*), and grad_tuning_loss final_poses through the "
        "same relaxed law",
    )
    parser.add_argument(
        "--cpu-devices",
        metavar="K",
        help="split the CPU into K JAX devices for the sharded case (None: two per "
        "core; 1 keeps one). Only before JAX starts; see wmr_jax.studies.use_cpu_devices",
    )
    parser.add_argument(
        "--wait-idle",
        default=0.0,
        metavar="S",
        help="on a shared machine: before each round of timed calls, wait up to S s "
        "for other processes to leave the CPU (0: do not wait)",
    )
    parser.add_argument(
        "--json",
        metavar="FILE",
        help="also write the results here (atomically), the robot included",
    )
    flags.add_robot_flag(parser)


def _config_from(args: Any, robot: Any = None) -> bench.BenchConfig:
    """Return the ``BenchConfig`` of the flags, each checked (one line naming a bad one)."""
    ints = {name: flags.positive_int(flag, getattr(args, name)) for flag, name, *_ in _INT_FLAGS}
    cases = tuple(flags.choice("--cases", c, bench.CASES) for c in args.cases or ())
    if cases and "scalar_reference" not in cases and isinstance(args.reference_poses, str):
        raise ValueError(
            "--reference-poses is not allowed without the scalar_reference case, which it sizes"
        )
    return bench.BenchConfig(
        robot=robot,
        sizes=tuple(
            flags.positive_int("--sizes", n, 1, MAX_SAMPLES)
            for n in args.sizes or bench.DEFAULT_SIZES
        ),
        dtype=flags.choice("--dtype", args.dtype, bench.DTYPES),
        cases=cases,
        wait_idle=flags.number("--wait-idle", args.wait_idle, low=0.0, unit="s"),
        **ints,
    )


def run(args: Any) -> int:
    """Run ``wmr-jax bench``: print the table (progress on stderr); return 0."""
    from wmr_jax._src.io import atomic_write_json
    from wmr_jax._src.report.bench import bench_table
    from wmr_jax._src.sim.sharding import MAX_CPU_DEVICES, use_cpu_devices

    out = None if args.json is None else flags.output_file("--json", args.json)
    given = flags.robot_from(args.robot)
    config = _config_from(args, None if given is None else given.robot)
    cpu_devices = args.cpu_devices
    if cpu_devices is not None:
        cpu_devices = flags.positive_int("--cpu-devices", cpu_devices, 1, MAX_CPU_DEVICES)
    use_cpu_devices(cpu_devices)
    detail = f"; {config.steps} control periods per run and the paper robot's poses (5-80 cm)"
    flags.say_robot(given, detail + ", as for any robot", gains=False)

    def labelled(result: dict) -> dict:
        if given is not None:
            result["robot_label"] = given.label  # the preset's name or the file
        return result

    # Each finished size is written at once: an interrupted run keeps them ("finished": false).
    partial = None if out is None else (lambda so_far: atomic_write_json(out, labelled(so_far)))
    log = functools.partial(print, file=sys.stderr, flush=True)
    result = labelled(bench.run_benchmark(config, log=log, on_size=partial))
    print(bench_table(result), end="")
    if out is not None:
        atomic_write_json(out, result)
        print(f"results: {args.json}")
    return 0
