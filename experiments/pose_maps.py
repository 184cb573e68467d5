"""Pose-space maps and the Shim–Sung vs baselines comparison table (ideal loop).

Usage: ``python experiments/pose_maps.py [DIR] [N_RANDOM] [N_GRID]``
(defaults ``results/maps``, 200000 random SPEC §6 poses, 1000000 grid poses).

Writes ``DIR/sweep/`` (heat maps, first-to-arrive map, grid summary) and
``DIR/comparison.md`` / ``.json`` (random SPEC §6 poses, seed 0, each
controller with its published defaults and with the other driving direction).
"""

import sys
from pathlib import Path

from wmr_jax import maps
from wmr_jax.baselines import AicardiGains, AstolfiGains
from wmr_jax.io import atomic_write_json, atomic_write_text
from wmr_jax.paper import markdown_table

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/maps")
    n_random = int(sys.argv[2]) if len(sys.argv) > 2 else 200_000
    n_grid = int(sys.argv[3]) if len(sys.argv) > 3 else 1_000_000

    refs = maps.spec_poses(0, n_random)
    runs = {
        "shim-sung": ("shim-sung", None),
        "aicardi": ("aicardi", None),
        "aicardi (backward allowed)": ("aicardi", AicardiGains(backward=True)),
        "astolfi-corke": ("astolfi-corke", None),
        "astolfi-corke (forward only)": ("astolfi-corke", AstolfiGains(backward=False)),
    }
    results = {
        label: maps.evaluate_poses(refs, params, controller=name, progress=True)
        for label, (name, params) in runs.items()
    }
    rows = maps.summarize(results)
    head = f"{n_random} random SPEC §6 poses (seed 0), ideal loop, horizon 6 s\n\n"
    atomic_write_text(out / "comparison.md", head + markdown_table(rows))
    atomic_write_json(out / "comparison.json", {"poses": n_random, "seed": 0, "rows": rows})
    print(head + markdown_table(rows))

    summary = maps.sweep(out / "sweep", n_poses=n_grid)
    print(markdown_table(summary["rows"]))
