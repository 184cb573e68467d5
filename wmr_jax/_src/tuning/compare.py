"""Gradient descent against black-box search at equal CPU time, on both tuning problems.

CMA-ES needs ``evosax`` (the optional extra ``[search]``); all three are judged
with the hard law on the same held-out poses beside the ``docs/model.md §8`` yardsticks.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from wmr_jax._src import io, provenance
from wmr_jax._src.checks import check_callable, check_int
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.model.robots import describe_robot, robot_from_values, robot_json
from wmr_jax._src.sim.poses import sample_poses
from wmr_jax._src.studies.optimal import time_bounds
from wmr_jax._src.studies.robustness import named_warnings
from wmr_jax._src.tuning.evaluation import evaluate, held_out_poses, poses_digest, report_ratios
from wmr_jax._src.tuning.problems import get_problem
from wmr_jax._src.tuning.robust import RobustConfig
from wmr_jax._src.tuning.search import _evosax_cma_es, cma_es_search, random_search
from wmr_jax._src.tuning.training import TuneConfig, train

# The methods compared, in the order of each (problem, seed)'s rows.
METHODS = ("gradient", "cma-es", "random search")
# The seeds of a resumable comparison (this one's and the robust one's).
COMPARE_SEEDS = (0, 1, 2)
# 3: budgets in process CPU time, rows with CPU and wall time beside each other.
COMPARE_FORMAT = 3


def _checked_plan(seeds: Any, problems: Any, configs: Any) -> dict[str, TuneConfig]:
    """The checked ``TuneConfig`` of each problem to compare (before anything runs)."""
    for name, value, what in (("seeds", seeds, "seeds"), ("problems", problems, "problem names")):
        if isinstance(value, (str, bytes)) or not isinstance(value, (tuple, list)) or not value:
            raise ValueError(
                f"{name} = {value!r} is not allowed; allowed: a non-empty tuple or list of {what}"
            )
    for i, seed in enumerate(seeds):
        check_int(f"seeds[{i}]", seed, 0, 2**32 - 1)
    if configs is not None and not isinstance(configs, dict):
        raise ValueError(f"configs = {configs!r:.80} is not allowed; allowed: a dict or None")
    configs = dict(configs or {})
    names = [get_problem(name).name for name in problems]
    unused = sorted(set(configs) - set(names))
    if unused:
        raise ValueError(
            f"configs[{unused[0]!r}] is for no problem compared; allowed: keys among {names}"
        )
    bases = {}
    for name in names:
        base = configs.get(name, TuneConfig.for_problem(name))
        if not isinstance(base, TuneConfig) or base.problem != name:
            raise ValueError(
                f"configs[{name!r}] = {base!r:.80} is not allowed; allowed: a TuneConfig of the "
                f"{name!r} problem (TuneConfig.for_problem({name!r}, ...))"
            )
        bases[name] = base.validate()
    return bases


def compare(
    *,
    seeds: tuple[int, ...] = (0, 1, 2),
    problems: tuple[str, ...] = ("fixed", "schedule"),
    configs: dict[str, TuneConfig] | None = None,
    robot: Robot | None = None,
    progress: Callable[[str], Any] | None = None,
) -> list[dict[str, Any]]:
    """Gradient vs CMA-ES vs random search at equal CPU time, per problem and seed.

    The gradient tuner runs first (``configs[problem]``, its seed replaced); its
    CPU time (``search.clock``, compile included) is the budget of the other two,
    which score candidates on ``config.poses`` training poses.

    Args:
        seeds: seeds of the training poses and the searches.
        problems: ``"fixed"`` and/or ``"schedule"``.
        configs: the ``TuneConfig`` per problem; default
            ``TuneConfig.for_problem(problem)``. A schedule's ``knots``
            sizes the tables all three methods search.
        robot: robot parameters; default ``Robot()``.
        progress: called with a line after each method's run.

    Returns:
        One row per (problem, seed, method): ``problem``, ``parameters`` (the
        dimension searched), ``seed``, ``method``, ``budget_s`` (the
        gradient's CPU time), ``cpu_s`` and ``wall_s`` spent, ``candidates``
        (``None`` for the gradient), ``per_cpu_s`` (candidates, or gradient
        iterations, per CPU-second), ``minimises`` (in words), ``held_out``
        (``evaluation.poses_digest`` of the held-out poses), the hard-law
        ``mean_arrival``, ``success_rate``, ``peak_wheel_speed`` and the
        ratios of ``report_ratios`` (``None``, with a ``"…_reason"``, where
        none arrived).

    Raises:
        ValueError: for bad settings, or without evosax (CMA-ES), before any run.
    """
    robot = validate_one_robot(robot, "tuning")
    bases = [c.for_robot(robot) for c in _checked_plan(seeds, problems, configs).values()]
    check_callable("progress", progress)
    _evosax_cma_es()  # refused now, not after the first gradient run
    rows, said = [], set()
    for base in bases:
        problem = base.space  # for a schedule, of base.knots knots
        held_out = held_out_poses(base.eval_poses, base.eval_seed)
        bounds = time_bounds(held_out, robot=robot, dt=base.dt)
        run = base.hard_run
        held_digest = poses_digest(held_out)
        for seed in seeds:
            config = base.replace(seed=seed, random_search=False)
            last = []
            began = time.perf_counter()
            result = train(
                config, robot=robot, progress_fn=lambda _s, at=last: at.append(time.perf_counter())
            )
            budget = result.tune_cpu_s  # process CPU time (trainer.iterate counts it so)
            refs = sample_poses(jax.random.fold_in(jax.random.key(seed), 3), config.poses)
            key = jax.random.fold_in(jax.random.key(seed), 2)
            found = {METHODS[0]: (result.gains, budget, last[-1] - began, None)}
            for method, search in zip(METHODS[1:], (cma_es_search, random_search), strict=True):
                s = search(key, refs, budget_s=budget, problem=problem, robot=robot, **run)
                found[method] = (s.gains, s.cpu_s, s.wall_s, s.candidates)
            for method, (params, cpu, wall, candidates) in found.items():
                # A warning about one method's gains says whose they are.
                with named_warnings(f"{problem.name}, seed {seed}, {method}", said):
                    ev = evaluate(params, held_out, robot=robot, **run)
                done = config.iters if candidates is None else candidates
                rows.append(
                    {
                        "problem": problem.name,
                        "parameters": problem.dim,
                        "seed": seed,
                        "method": method,
                        "budget_s": budget,
                        "cpu_s": cpu,
                        "wall_s": wall,
                        "candidates": candidates,
                        "per_cpu_s": done / cpu if cpu > 0 else None,
                        "minimises": minimised(config, method),
                        "held_out": held_digest,
                        **ev._asdict(),
                        **report_ratios(ev.mean_arrival, bounds),
                    }
                )
                if progress is not None:
                    mean = (
                        f"{ev.mean_arrival:.3f} s"
                        if math.isfinite(ev.mean_arrival)
                        else "none arrived"
                    )
                    progress(
                        f"{problem.name} seed {seed} {method}: {mean}, "
                        f"{100 * ev.success_rate:.1f} %, {cpu:.0f} CPU s, {wall:.0f} s"
                    )
    return rows


def minimised(config: Any, method: str) -> str:
    """What ``method`` minimises in a comparison of ``config`` (a tuning or robust config)."""
    robust = isinstance(config, RobustConfig)
    if method == "gradient" and robust:
        return (
            f"relaxed surrogate: soft arrival of the smooth law (temperature "
            f"{config.temperature_start:g} to {config.temperature_end:g}), mean over "
            f"{config.poses} + {config.nonideal_poses} fresh poses per iteration under "
            "conditions sampled anew (noise up to twice the sensor's, latency, mismatch)"
        )
    if method == "gradient":
        return (
            "relaxed surrogate: soft arrival of the smooth law (annealed temperature) "
            f"on {config.poses} fresh training poses per iteration"
        )
    if robust:
        return (
            "robust_score: hard law, mean arrival (failures at twice the horizon) over the "
            f"5 standard conditions on {config.search_poses} fixed search poses, one draw"
        )
    return (
        "hard law: mean arrival (failures at twice the horizon) on "
        f"{config.poses} fixed training poses"
    )


def saved_rows(
    rows: Any, where: str, problems: dict[str, int], seeds: tuple[int, ...]
) -> list[dict[str, Any]]:
    """``rows`` of a saved ``compare.json`` if a resumed comparison may keep them, else say why.

    Each row must be one ``compare`` writes for ``problems`` (name → parameter
    count) and ``seeds``, each (problem, seed) with all of ``METHODS`` once.
    """
    from wmr_jax._src.report.tuning import _compare_numbers

    def bad(text: str) -> ValueError:
        return ValueError(f"{where} {text}")

    if not isinstance(rows, list):
        raise bad(f"rows are a JSON {_json_type(rows)}; allowed: an array of comparison rows")
    runs: dict[tuple[str, int], list[str]] = {}
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise bad(f"row {i} is a JSON {_json_type(row)}; allowed: an object (a comparison row)")
        for key in ("problem", "seed", "method"):
            if key not in row:
                raise bad(f"row {i} has no {key!r}; allowed: rows of wmr-jax tune --compare")
        problem, seed, method = row["problem"], row["seed"], row["method"]

        def refuse(key, value, allowed, i=i):
            return bad(f"row {i}: {key} = {value!r:.40} is not allowed; allowed: {allowed}")

        if not isinstance(problem, str) or problem not in problems:
            names = ", ".join(map(repr, problems))
            raise refuse("problem", problem, f"{names} (the problems compared now)")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed not in seeds:
            raise refuse("seed", seed, f"{', '.join(map(str, seeds))} (the seeds compared)")
        if not isinstance(method, str) or method not in METHODS:
            raise refuse("method", method, ", ".join(map(repr, METHODS)))
        size = row.get("parameters", problems[problem])
        if isinstance(size, bool) or size != problems[problem]:
            raise refuse(
                "parameters", size, f"{problems[problem]} (the {problem!r} problem compared now)"
            )
        try:
            _compare_numbers(i, row)
        except ValueError as err:
            raise bad(str(err).replace(f"rows[{i}]", f"row {i}", 1)) from None
        done = runs.setdefault((problem, seed), [])
        if method in done:
            raise bad(f"row {i}: {problem} seed {seed} {method} is given twice; allowed: once")
        done.append(method)
    for (problem, seed), done in runs.items():
        missing = [m for m in METHODS if m not in done]
        if missing:
            raise bad(
                f"holds {problem} seed {seed} without {missing[0]!r}; allowed: each problem "
                "and seed with all three methods (as wmr-jax tune --compare writes them)"
            )
    return rows


def _json_type(value: Any) -> str:
    names = {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null"}
    return names.get(type(value), "number")


def comparison_settings(robot: Robot, **fields: Any) -> dict[str, Any]:
    """What a resumed comparison must match: ``fields``, the robot and the code (JSON as read)."""
    settings = {"format": COMPARE_FORMAT, **fields, "robot": robot_json(robot)}
    return json.loads(json.dumps({**settings, "code": provenance.code_version()}))


def run_comparison(
    out: Path,
    configs: dict[str, TuneConfig],
    *,
    robot: Robot | None = None,
    resume: bool = False,
    progress: Callable[[str], Any] | None = print,
) -> list[dict[str, Any]]:
    """``compare`` for seeds 0–2 of each problem in ``configs``, into ``out/compare.{json,md}``.

    Each (problem, seed) is kept as ``resumable`` keeps a run.

    Returns:
        All rows, kept and new.
    """
    from wmr_jax._src.report.tuning import comparison_table

    robot = validate_one_robot(robot, "tuning")
    configs = {name: config.for_robot(robot) for name, config in configs.items()}
    settings = comparison_settings(
        robot,
        seeds=list(COMPARE_SEEDS),
        configs={name: config.as_dict() for name, config in configs.items()},
    )
    problems = {name: config.space.dim for name, config in configs.items()}

    def run(name: str, seed: int) -> list[dict[str, Any]]:
        return compare(
            seeds=(seed,), problems=(name,), configs={name: configs[name]}, robot=robot,
            progress=progress,
        )  # fmt: skip

    return resumable(
        out / "compare.json",
        settings,
        {f"{name} seed {seed}": (name, seed) for name in configs for seed in COMPARE_SEEDS},
        run,
        run_of=lambda row: f"{row['problem']} seed {row['seed']}",
        check=lambda rows, where: saved_rows(rows, where, problems, COMPARE_SEEDS),
        table=comparison_table,
        resume=resume,
        progress=progress,
    )


def resumable(
    path: Path,
    settings: dict[str, Any],
    runs: dict[str, Any],
    run: Callable[..., list[dict[str, Any]]],
    *,
    run_of: Callable[[dict[str, Any]], str],
    check: Callable[[Any, str], list[dict[str, Any]]],
    table: Callable[[list[dict[str, Any]]], str],
    resume: bool,
    progress: Callable[[str], Any] | None,
) -> list[dict[str, Any]]:
    """The rows of ``run(*runs[name])`` for each name in ``runs``, into ``path`` and its ``.md``.

    ``path`` holds ``{"settings", "rows"}`` sealed with a checksum, written
    after each run. With ``resume``, the runs of an interrupted comparison
    of the same ``settings`` (robot and code included) are kept, checked
    whole before any run (``check(rows, where)``); without, an earlier
    comparison's files are removed first. ``run_of(row)``: the name of the run of ``row``.
    """
    say = progress if progress is not None else (lambda _line: None)
    if resume and path.exists():
        rows = _kept_rows(path, settings, check)
    else:
        rows = []
        for stale in (path, path.with_suffix(".md")):
            stale.unlink(missing_ok=True)
    done = {run_of(row) for row in rows}
    for name, args in runs.items():
        if name in done:
            say(f"{name}: kept from {path}")
            continue
        rows += run(*args)
        io.atomic_write_json(path, io.sealed({"settings": settings, "rows": rows}))
    io.atomic_write_text(path.with_suffix(".md"), table(rows))
    return rows


def _kept_rows(path: Path, settings: dict[str, Any], check: Callable) -> list[dict[str, Any]]:
    """The rows of a saved comparison of ``settings`` at ``path``, else say why none are kept."""
    advice = "allowed: the same settings, or a fresh --out"
    damaged = "remove it, or use a fresh --out"
    try:
        saved = json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=io.json_object_once)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        reason = " ".join(str(err).split())
        raise ValueError(f"--resume: {path} cannot be read ({reason}); {damaged}") from None
    there = saved.get("settings") if isinstance(saved, dict) else None
    if not isinstance(there, dict):
        raise ValueError(f"--resume: {path} holds no comparison settings; {advice}")
    if there != settings:
        diff = "; ".join(_differences(there, settings))
        raise ValueError(f"--resume: {path} is of another comparison ({diff}); {advice}")
    if "rows" not in saved:
        raise ValueError(f"--resume: {path} holds no rows; {damaged}")
    try:  # values changed since they were written are not kept
        return check(io.unsealed(saved, str(path))["rows"], str(path))
    except ValueError as err:
        raise ValueError(f"--resume: {err}; {damaged}") from None


def _differences(saved: dict[str, Any], now: dict[str, Any], at: str = "") -> list[str]:
    """What differs between two comparisons' settings, each as ``key = … there, … now``."""
    out = []
    for key in dict.fromkeys([*now, *saved]):
        name, there, here = f"{at}{key}", saved.get(key), now.get(key)
        if key not in saved or key not in now:
            out.append(f"{name} only {'now' if key in now else 'there'}")
        elif name == "robot" and there != here:
            out.append(f"robot: {_robot_text(there)} there, {_robot_text(here)} now")
        elif isinstance(there, dict) and isinstance(here, dict):
            out += _differences(there, here, f"{name}.")
        elif there != here:
            out.append(f"{name} = {there!r:.40} there, {here!r:.40} now")
    return out


def _robot_text(values: Any) -> str:
    """A saved comparison's robot in words."""
    try:
        return describe_robot(robot_from_values(values, "robot"))
    except ValueError:
        return "a damaged robot entry"
