"""``wmr-jax paper`` and ``wmr-jax demo``: the paper's Figs. 6–10 and their table."""

from __future__ import annotations

from typing import Any

from wmr_jax._src.cli import flags


def add_arguments(parser: Any) -> None:
    """Add the flags of ``wmr-jax paper`` and ``demo``."""
    parser.add_argument("--out", default="results", metavar="DIR", help="output folder")


def run_paper(args: Any) -> int:
    """Run ``wmr-jax paper``: simulate, write the figures and table, print the summary."""
    from wmr_jax._src.report.paper import paper_summary_table, save_paper
    from wmr_jax._src.studies import paper

    out = flags.output_dir("--out", args.out)
    runs = paper.paper_runs()
    save_paper(out, runs)
    print(f"Figs. 6-10, wheel speeds and the table -> {out}/")
    for kr in paper.PAPER_KR:  # the wheel-speed condition, the path gap and the zig-zags
        s = runs.summary[f"kr={kr:g}"]
        print(
            f"  kr={kr:g}: k_r + L k_theta = {s['k_r + L k_theta']:g} cm/s ({s['condition']}); "
            f"ideal vs non-ideal path gap: max {s['max_deviation_cm']:.2f} cm, "
            f"mean {s['mean_deviation_cm']:.2f} cm; zig-zag ideal {s['ideal_zigzag']:.1f}, "
            f"non-ideal {s['nonideal_zigzag']:.1f}"
        )
    print("\nMeans over the seven references (the table of docs/paper.md):\n")
    print(paper_summary_table(runs.summary, float(runs.robot.v_max)), end="")
    return 0


def run_demo(args: Any) -> int:
    """Run ``wmr-jax demo``: Fig. 7 and its table, then ``paper``; return the exit status."""
    from wmr_jax._src.report.paper import save_fig7
    from wmr_jax._src.report.tables import markdown_table
    from wmr_jax._src.studies import paper

    out = flags.output_dir("--out", args.out)
    fig7 = paper.fig7_runs()
    save_fig7(out, fig7)
    print(f"Fig. 7 (ideal velocity loop, paper gains) -> {out / 'fig7.png'}")
    print(markdown_table(fig7.rows), end="")
    return run_paper(args)
