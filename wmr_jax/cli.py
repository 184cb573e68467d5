"""The ``wmr-jax`` command line: simulate one pose, reproduce the paper, and more.

Every user error (a bad flag value, out-of-range gains, a non-finite pose)
ends in one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main"]


def _add_gain_flags(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("gains (SPEC §3; defaults are the paper's Fig. 7)")
    g.add_argument("--kr", type=float, default=120.0, help="k_r, cm/s (default 120)")
    g.add_argument("--k-theta", type=float, default=10.0, help="k_θ, rad/s (default 10)")
    g.add_argument("--phi-m", type=float, default=70.0, help="Φ_m, degrees (default 70)")
    g.add_argument("--r-m", type=float, default=20.0, help="R_m, cm (default 20)")
    g.add_argument("--r-a", type=float, default=20.0, help="R_a, cm (default 20)")
    g.add_argument("--r-e", type=float, default=1.0, help="R_e, cm (default 1)")
    g.add_argument("--alpha", type=float, default=0.25, help="α (default 0.25)")


def _gains_from(args: argparse.Namespace):
    from wmr_jax.params import Gains

    return Gains(
        kr=args.kr,
        k_theta=args.k_theta,
        phi_m=math.radians(args.phi_m),
        r_m=args.r_m,
        r_a=args.r_a,
        r_e=args.r_e,
        alpha=args.alpha,
    )


def _pose_from_degrees(values: Sequence[float]) -> list[float]:
    return [values[0], values[1], math.radians(values[2])]


def _cmd_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from wmr_jax import metrics
    from wmr_jax.simulation import rollout

    gains = _gains_from(args)
    ref = _pose_from_degrees(args.ref)
    init = _pose_from_degrees(args.init)
    traj = rollout(ref, gains, init=init, dt=args.dt, steps=args.steps, velocity=args.velocity)
    t_arrive = float(metrics.arrival_time(traj, np.asarray(ref), dt=args.dt))
    per_region = np.asarray(metrics.region_time(traj, dt=args.dt))
    final = np.asarray(traj.poses[-1])
    print(f"reference      : x={ref[0]:.3f} cm  y={ref[1]:.3f} cm  θ={args.ref[2]:.2f}°")
    print(
        f"final pose     : x={final[0]:.3f} cm  y={final[1]:.3f} cm  "
        f"θ={math.degrees(final[2]):.2f}° after {args.steps * args.dt:.3f} s"
    )
    arrival = "never (not arrived at the end)" if math.isinf(t_arrive) else f"{t_arrive:.3f} s"
    print(f"arrival time   : {arrival}")
    print(
        "time per region: "
        + "  ".join(f"R{k}={per_region[k]:.3f} s" for k in range(4))
        + f"  (peak wheel speed {float(np.abs(np.asarray(traj.wheel_speeds)).max()):.1f} cm/s)"
    )
    if args.plot:
        from wmr_jax.io import save_figure
        from wmr_jax.plotting import plot_paths, plt

        fig, ax = plt.subplots(figsize=(6, 6))
        plot_paths(ax, [np.asarray(traj.poses)], np.asarray([ref]), label="robot path")
        ax.set_title(f"ref = ({args.ref[0]:g}, {args.ref[1]:g}, {args.ref[2]:g}°)")
        ax.legend(fontsize=8)
        save_figure(fig, args.plot, dpi=120, bbox_inches="tight")
        plt.close(fig)
        print(f"plot           : {args.plot}")
    return 0


def _cmd_paper(args: argparse.Namespace) -> int:
    from wmr_jax import paper

    out = Path(args.out)
    result = paper.paper_figures(out)
    print(f"Figs. 6-10, wheel speeds and the table -> {out}/")
    for case in ("kr=120", "kr=60"):
        s = result["summary"][case]
        print(
            f"  {case}: k_r + L k_theta = {s['k_r + L k_theta']:g} cm/s ({s['condition']}); "
            f"ideal vs non-ideal path gap: max {s['max_deviation_cm']:.2f} cm, "
            f"mean {s['mean_deviation_cm']:.2f} cm; zig-zag ideal {s['ideal_zigzag']:.1f}, "
            f"non-ideal {s['nonideal_zigzag']:.1f}"
        )
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from wmr_jax import paper

    out = Path(args.out)
    rows = paper.figure_7(out)
    print(f"Fig. 7 (ideal velocity loop, paper gains) -> {out / 'fig7.png'}")
    print(paper.markdown_table(rows), end="")
    return _cmd_paper(args)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from err
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not allowed; allowed: an integer >= 1")
    return value


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``wmr-jax``."""
    parser = argparse.ArgumentParser(
        prog="wmr-jax",
        description="Differentiable, batched simulator of the Shim–Sung (2003) pose controller.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser("simulate", help="drive the robot to one reference pose and report")
    sim.add_argument("--ref", nargs=3, type=float, required=True, metavar=("X", "Y", "THETA_DEG"))
    sim.add_argument(
        "--init",
        nargs=3,
        type=float,
        default=[0.0, 0.0, 0.0],
        metavar=("X", "Y", "THETA_DEG"),
        help="initial pose (default 0 0 0)",
    )
    sim.add_argument("--dt", type=float, default=0.033, help="control period, s (default 0.033)")
    sim.add_argument("--steps", type=_positive_int, default=150, help="control periods (150)")
    sim.add_argument(
        "--velocity", default="ideal", help="velocity loop: ideal (default) or nonideal"
    )
    sim.add_argument("--plot", metavar="FILE.png", help="save the path to this image")
    _add_gain_flags(sim)
    sim.set_defaults(func=_cmd_simulate)

    demo = sub.add_parser("demo", help="the main job: reproduce the paper into a folder, tabulate")
    demo.add_argument("--out", default="results", help="output folder (default results/)")
    demo.set_defaults(func=_cmd_demo)

    paper = sub.add_parser("paper", help="Figs. 6-10, wheel speeds and the paper table")
    paper.add_argument("--out", default="results", help="output folder (default results/)")
    paper.set_defaults(func=_cmd_paper)

    for name, module, summary in _MODULE_COMMANDS:
        command = sub.add_parser(name, help=summary)
        module = importlib.import_module(f"wmr_jax.{module}")
        module.configure_parser(command)
        command.set_defaults(func=module.run_cli)
    return parser


# Sweep-like commands spread their batches over every local device; on a CPU
# that means splitting it into several JAX devices first (wmr_jax.sharding).
_ALL_DEVICE_COMMANDS = ("sweep", "bench")

# Commands whose flags and work live with the library module that does the work.
_MODULE_COMMANDS = (
    ("tune", "tuning", "tune gains by gradient descent under k_r + L k_theta <= V_max"),
    ("sweep", "maps", "map success, arrival, path, wheel speed and zig-zag over a pose space"),
    ("waypoints", "waypoints", "consecutive motions through a chain of waypoints"),
    ("robustness", "robustness", "Monte Carlo of noise, model mismatch and latency"),
    ("animate", "animation", "animated GIF of a batch of robots driving to their poses"),
    ("bench", "bench", "robot-steps per second against NumPy baselines"),
)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in _ALL_DEVICE_COMMANDS:
        from wmr_jax.sharding import use_cpu_devices

        use_cpu_devices()  # before any JAX computation; a no-op on accelerators
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = _one_line_warning
            return args.func(args)
    except ValueError as err:
        print(f"wmr-jax: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("wmr-jax: interrupted", file=sys.stderr)
        return 130


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"wmr-jax: warning: {message}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
