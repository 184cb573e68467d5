r"""Whether a run of ``wmr-jax tune --robust --compare`` reproduces a committed one.

At a given price (``--price 5``, ``docs/data/robust_compare_price.json``)
every method scores the same number of candidates on any machine, and
docs/robustness.md (**On a second machine**) expects the same rows to the
last digit wherever XLA's code rounds as it did there. To check it on
another machine::

    wmr-jax tune --out results/c5 --robust --compare --price 5
    python experiments/reproduction.py \
        docs/data/robust_compare_price.json results/c5/robust_compare.json

This prints, per method and seed, both judged scores (the hard-law mean
arrival over the standard conditions, failures at twice the horizon) and
their difference; how many rows are equal in every field but the timings;
whether the held-out poses were the same; and each run's ranking. Where
XLA rounds otherwise the rows part, and the check is on the scores. It
exits with status 1 if a judged score differs by more than
``--tolerance`` (relative, 2 % by default) or a row of one run is missing
from the other, 2 if the two runs' settings differ (the file format, the
price, the robot, the problem), so that they could not be compared, and 3
if a file cannot be read as a robust_compare.json.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from wmr_jax._src.tuning.robust import condition_score

# Fields that record the machine rather than the search: they differ on every run.
TIMING = {"budget_s", "measured_price", "cpu_s", "wall_s", "per_cpu_s", "loadavg"}


# What every row must hold to be compared.
_KEYS = ("method", "seed", "condition", "success", "mean arrival s", "horizon s", "held_out")


def load(path: str) -> dict:
    """A robust_compare.json, or a ``ValueError`` saying why ``path`` is not one."""
    try:
        with open(path, encoding="utf-8") as file:
            data = json.load(file)
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: cannot be read ({err})") from None
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
        raise ValueError(f"{path}: not a robust_compare.json (no list of 'rows')")
    if not isinstance(data.get("settings"), dict):
        raise ValueError(f"{path}: not a robust_compare.json (no 'settings')")
    for i, row in enumerate(data["rows"]):
        missing = [key for key in _KEYS if not isinstance(row, dict) or key not in row]
        if missing:
            raise ValueError(f"{path}: row {i} has no {', '.join(missing)}")
    return data


def settings_differences(committed: dict, fresh: dict) -> list[str]:
    """The settings that make two runs incomparable: the format, the config and the robot."""
    a, b = committed["settings"].get("format"), fresh["settings"].get("format")
    out = [] if a == b else [f"format: committed {a!r}, this run {b!r}"]
    for part in ("config", "robot"):
        a, b = committed["settings"].get(part, {}), fresh["settings"].get(part, {})
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                out.append(f"{part}.{key}: committed {a.get(key)!r}, this run {b.get(key)!r}")
    return out


def scores(rows: list[dict]) -> dict[tuple[str, int], float]:
    """Judged score per (method, seed): the mean of ``condition_score`` over the conditions."""
    per: dict[tuple[str, int], list[float]] = {}
    for row in rows:
        per.setdefault((row["method"], row["seed"]), []).append(condition_score(row))
    return {key: float(np.mean(values)) for key, values in per.items()}


def kept_fields(rows: list[dict]) -> dict[tuple, dict]:
    """Each row without its timings, keyed by (method, seed, condition)."""
    return {
        (r["method"], r["seed"], r["condition"]): {k: v for k, v in r.items() if k not in TIMING}
        for r in rows
    }


def compare(committed: dict, fresh: dict, tolerance: float) -> tuple[list[str], bool]:
    """The report's lines, and whether every row is in both and every score within ``tolerance``."""
    a, b = kept_fields(committed["rows"]), kept_fields(fresh["rows"])
    lines = [f"only in the committed run: {key}" for key in sorted(set(a) - set(b))]
    lines += [f"only in this run: {key}" for key in sorted(set(b) - set(a))]
    ok = set(a) == set(b)
    mine, theirs = scores(committed["rows"]), scores(fresh["rows"])
    lines += ["| method | seed | committed s | this run s | difference |", "|---|---|---|---|---|"]
    for key in sorted(set(mine) & set(theirs)):
        change = theirs[key] / mine[key] - 1.0
        within = abs(change) <= tolerance
        ok &= within
        mark = "" if within else f" (beyond {tolerance:.0%})"
        lines.append(
            f"| {key[0]} | {key[1]} | {mine[key]:.4f} | {theirs[key]:.4f} | {change:+.2%}{mark} |"
        )
    same = sum(a[key] == b.get(key) for key in a)
    lines.append(f"rows equal in every field but the timings: {same} of {len(a)}")
    digests = {r["held_out"] for r in committed["rows"]}, {r["held_out"] for r in fresh["rows"]}
    lines.append(
        "held-out poses: "
        + ("the same" if digests[0] == digests[1] else "different (XLA rounds otherwise here)")
    )
    for name, run in (("committed", mine), ("this run", theirs)):
        lines.append(f"{name}: {_ranking(run)}")
    return lines, ok


def _ranking(run: dict[tuple[str, int], float]) -> str:
    """The gradient's lead over CMA-ES on the mean of the seeds, and the seeds it leads at."""
    seeds = sorted(s for m, s in run if m == "gradient" and ("cma-es", s) in run)
    if not seeds:
        return "no seed has both the gradient and CMA-ES"
    gradient = np.mean([run["gradient", s] for s in seeds])
    cma = np.mean([run["cma-es", s] for s in seeds])
    ahead = [s for s in seeds if run["gradient", s] < run["cma-es", s]]
    return (
        f"gradient ahead of CMA-ES on the mean by {1.0 - gradient / cma:+.1%}, "
        f"at seeds {ahead} of {seeds}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("committed", help="the committed robust_compare.json")
    parser.add_argument("fresh", help="this machine's robust_compare.json")
    parser.add_argument("--tolerance", type=float, default=0.02, help="relative (default 0.02)")
    args = parser.parse_args(argv)
    if not 0.0 <= args.tolerance < 1.0:
        parser.error(f"--tolerance {args.tolerance!r} is not allowed; allowed: in [0, 1)")
    try:
        committed, fresh = load(args.committed), load(args.fresh)
    except ValueError as err:
        print(err)
        return 3
    differences = settings_differences(committed, fresh)
    if differences:
        print("the runs' settings differ, so their scores are not comparable:")
        print("\n".join(f"  {line}" for line in differences))
        return 2
    lines, ok = compare(committed, fresh, args.tolerance)
    print("\n".join(lines))
    verdict = "yes" if ok else "no"
    print(f"every row in both runs, every judged score within {args.tolerance:.0%}: {verdict}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
