"""The XLA programs the benchmark's JAX cases compile to, for comparing two checkouts.

Two checkouts whose cases compile to the same optimised programs run the same
machine code: any difference in their timings is the host's share of a call
or the machine's noise. Run it once with each checkout first on the path, then
compare the two folders::

    PYTHONPATH=/path/to/a python experiments/compiled_programs.py dump A
    PYTHONPATH=/path/to/b python experiments/compiled_programs.py dump B
    python experiments/compiled_programs.py compare A B

Each case runs in a process of its own with XLA's dump of the programs it
compiles (``--xla_dump_to``, after optimisation, as text). The programs are
kept without their names and source locations (``normalised``): what is left
is every instruction, shape and layout XLA will run. The cases call the public
API only, which both checkouts share: ``final_poses`` (ideal and non-ideal
loop, and the smooth law of the tuning loss), ``batch_rollout``,
``tuning_loss`` and the benchmark's final-pose loss with their gradients and
derivatives along the gains, and the disturbed loop with each estimator.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

CASES = (
    "final_poses",
    "final_poses_nonideal",
    "final_poses_relaxed",
    "batch_rollout",
    "tuning_loss",
    "grad_tuning_loss",
    "jvp_tuning_loss",
    "final_pose_loss",
    "grad_final_pose_loss",
    "jvp_final_pose_loss",
    "disturbed_raw",
    "disturbed_observer",
    "disturbed_ekf",
)
TEMPERATURE = 0.05  # the benchmark's smooth-law temperature
STEPS, DT = 100, 0.033  # the benchmark's default steps, and the control period


def run_case(case: str, n: int) -> None:
    """Compile and run ``case`` once on ``n`` poses (float32, as the benchmark)."""
    import warnings

    import jax
    import jax.numpy as jnp

    import wmr_jax as w
    from wmr_jax import studies, tuning

    # The paper's gains ask more than the wheel budget on purpose (docs/model.md §3).
    warnings.simplefilter("ignore", w.WheelSpeedWarning)

    refs = jnp.asarray(w.sample_poses(0, n), jnp.float32)
    gains, steps = w.Gains(), STEPS
    horizon = steps * DT

    def tuning_loss(g, r):
        return tuning.tuning_loss(g, r, temperature=TEMPERATURE, horizon=horizon)

    def final_pose_loss(g, r):
        err = w.final_poses(r, g, steps=steps) - r
        return jnp.mean(err[:, 0] ** 2 + err[:, 1] ** 2 + (1.0 - jnp.cos(err[:, 2])))

    def along_gains(loss):
        return lambda g, r: jax.jvp(lambda g: loss(g, r), (g,), (g,))

    calls = {
        "final_poses": lambda g, r: w.final_poses(r, g, steps=steps),
        "final_poses_nonideal": lambda g, r: w.final_poses(r, g, steps=steps, velocity="nonideal"),
        "final_poses_relaxed": lambda g, r: w.final_poses(
            r, g, steps=steps, temperature=TEMPERATURE
        ),
        "batch_rollout": lambda g, r: w.batch_rollout(r, g, steps=steps),
        "tuning_loss": tuning_loss,
        "grad_tuning_loss": jax.value_and_grad(tuning_loss),
        "jvp_tuning_loss": along_gains(tuning_loss),
        "final_pose_loss": final_pose_loss,
        "grad_final_pose_loss": jax.value_and_grad(final_pose_loss),
        "jvp_final_pose_loss": along_gains(final_pose_loss),
    }
    if case in calls:
        jax.block_until_ready(jax.jit(calls[case])(gains, refs))
        return
    # The disturbed loop as the benchmark's case: σ 0.5 cm and 1°, ±3 % wheel
    # radius, one sample of latency; its metrics, through the public call.
    metrics = getattr(studies, "disturbed_metrics", None) or studies.perturbed_metrics
    spec = studies.sample_disturbance(
        jax.random.PRNGKey(0), refs, steps, noise_xy=0.5, noise_theta=math.radians(1.0),
        radius_mismatch=0.03, latency=1.0,
    )  # fmt: skip
    estimator = {"disturbed_raw": None}.get(case, case.removeprefix("disturbed_"))
    metrics(spec, gains, estimator=estimator, x64=False)


_DROPPED = ("HloModule", "FileNames", "FunctionNames", "FileLocations", "StackFrames")


def normalised(text: str) -> str:
    """An optimised HLO module without names, metadata and source locations."""
    lines = []
    for line in text.splitlines():
        if line.startswith(_DROPPED) or re.match(r'^\d+ ["{]', line):
            continue  # the module's name and its tables of source locations
        line = re.sub(r"%[A-Za-z0-9_.-]+", "%_", line)
        line = re.sub(r", (metadata|frontend_attributes)=\{[^}]*\}", "", line)
        if line.strip():
            lines.append(line)
    return "\n".join(lines)


def dump(out: Path, sizes: list[int]) -> None:
    """Write ``out/<case>.<n>.hlo``: the normalised programs each case compiles, sorted."""
    out.mkdir(parents=True, exist_ok=True)
    for n in sizes:
        for case in CASES:
            with tempfile.TemporaryDirectory() as tmp:
                flags = f"--xla_dump_to={tmp} --xla_dump_hlo_as_text"
                env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {flags}"}
                subprocess.run([sys.executable, __file__, "run", case, str(n)], env=env, check=True)
                modules = sorted(
                    normalised(p.read_text()) for p in Path(tmp).glob("*after_optimizations.txt")
                )
            (out / f"{case}.{n}.hlo").write_text("\n\n".join(modules) + "\n")
            print(f"{case} N={n}: {len(modules)} programs", flush=True)


def compare(a: Path, b: Path) -> int:
    """Print, per case and size, which of the programs in ``a`` and ``b`` are the same.

    Returns the number of cases whose programs differ.
    """
    differ = 0
    for path in sorted(a.glob("*.hlo")):
        other = b / path.name
        if not other.exists():
            print(f"{path.stem}: only in {a}")
            continue
        mine = path.read_text().strip().split("\n\n")
        theirs = other.read_text().strip().split("\n\n")
        only_mine = [m for m in mine if m not in theirs]
        only_theirs = [m for m in theirs if m not in mine]
        largest = max(len(m.splitlines()) for m in mine)
        if not only_mine and not only_theirs:
            print(f"{path.stem}: the same {len(mine)} programs (largest {largest} lines)")
            continue
        differ += 1
        sizes = [len(m.splitlines()) for m in only_mine]
        other_sizes = [len(m.splitlines()) for m in only_theirs]
        print(
            f"{path.stem}: {len(mine) - len(only_mine)} of {len(mine)} programs the same "
            f"(largest {largest} lines); differ: {sizes} lines against {other_sizes}"
        )
    return differ


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump", help="write the programs of the checkout first on the path")
    d.add_argument("out", type=Path)
    d.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    c = sub.add_parser("compare", help="compare two dumps")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    r = sub.add_parser("run", help="compile and run one case (used by dump)")
    r.add_argument("case", choices=CASES)
    r.add_argument("n", type=int)
    args = parser.parse_args()
    if args.command == "dump":
        dump(args.out, args.sizes)
        return 0
    if args.command == "compare":
        return 1 if compare(args.a, args.b) else 0
    run_case(args.case, args.n)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
