"""Pose-space maps and the Shim–Sung vs baselines comparison table (ideal loop).

Usage: ``python experiments/pose_maps.py [DIR] [N_RANDOM] [N_GRID]``
(defaults ``results/maps``, 200000 random docs/model.md §6 poses, 1000000 grid poses).

Writes ``DIR/sweep/`` (heat maps, first-to-arrive map, grid summary: what
``wmr-jax sweep --out DIR/sweep --poses N_GRID`` writes) and
``DIR/comparison.md`` / ``.json`` (random docs/model.md §6 poses drawn by
``wmr_jax.sample_poses(0, N_RANDOM)``, each controller with its published
defaults and with the other driving direction).
"""

import sys
from pathlib import Path

import numpy as np

import wmr_jax as w
from wmr_jax.controllers import AicardiGains, AstolfiGains
from wmr_jax.report import atomic_write_json, atomic_write_text, markdown_table, save_map_study
from wmr_jax.studies import evaluate_poses, map_study, summarize

RUNS = {
    "shim-sung": ("shim-sung", None),
    "aicardi": ("aicardi", None),
    "aicardi (backward allowed)": ("aicardi", AicardiGains(backward=True)),
    "astolfi-corke": ("astolfi-corke", None),
    "astolfi-corke (forward only)": ("astolfi-corke", AstolfiGains(backward=False)),
}

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/maps")
    n_random = int(sys.argv[2]) if len(sys.argv) > 2 else 200_000
    n_grid = int(sys.argv[3]) if len(sys.argv) > 3 else 1_000_000

    refs = np.asarray(w.sample_poses(0, n_random), dtype=float)
    results = {
        label: evaluate_poses(refs, params, controller=name, progress=True)
        for label, (name, params) in RUNS.items()
    }
    rows = summarize(results)
    head = f"{n_random} random docs/model.md §6 poses (seed 0), ideal loop, horizon 6 s\n\n"
    atomic_write_text(out / "comparison.md", head + markdown_table(rows))
    atomic_write_json(out / "comparison.json", {"poses": n_random, "seed": 0, "rows": rows})
    print(head + markdown_table(rows))

    study = map_study(n_grid, progress=True)
    save_map_study(out / "sweep", study)
    print(markdown_table(study.rows))
