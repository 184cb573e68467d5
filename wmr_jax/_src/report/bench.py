"""The benchmark's result as text: a Markdown table with the environment above it."""

from __future__ import annotations

from typing import Any

# Columns of the ratio table: key of the ratio entry -> heading.
_RATIO_COLUMNS = {
    "vs_numpy_batch": "final_poses / NumPy batch",
    "vs_scalar_reference": "final_poses / scalar reference",
    "sharded_vs_numpy_batch": "sharded / NumPy batch",
    "sharded_vs_scalar_reference": "sharded / scalar reference",
    "grad_final_pose_loss_over_forward": "grad / forward (final-pose loss)",
    "grad_tuning_loss_over_forward": "grad / forward (tuning loss)",
    "jvp_tuning_loss_over_forward": "one forward-mode derivative / forward (tuning loss)",
    "grad_robust_loss_over_forward": "grad / forward (robust loss)",
    "jvp_robust_loss_over_forward": "one forward-mode derivative / forward (robust loss)",
    "tuning_loss_over_final_poses": "tuning loss / final_poses (time per robot-step)",
    "nonideal_over_ideal": "non-ideal / ideal final_poses (time per robot-step)",
    "relaxed_over_final_poses": "relaxed / hard-law final_poses (time per robot-step)",
    "tuning_loss_over_relaxed": "tuning loss / relaxed final_poses (time per robot-step)",
}


def _fmt(value: float | None, spec: str, unit: str = "") -> str:
    return "—" if value is None else format(value, spec) + unit


def _ratio(entry: dict[str, float], key: str) -> str:
    """A speed-up as ``12.3×`` (``1234×`` over the scalar reference); a cost as ``2.50``."""
    if key.endswith(("_over_forward", "_over_final_poses", "_over_ideal", "_over_relaxed")):
        return _fmt(entry.get(key), ".2f")
    return _fmt(entry.get(key), ".0f" if key.endswith("scalar_reference") else ".1f", "×")


def _rate_lines(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| case | N | robot-steps/s | run s | compile s | others' CPU |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        if "skipped" in row:
            lines.append(f"| {row['case']} | {row['n']} | {row['skipped']} | | | |")
            continue
        lines.append(
            f"| {row['case']} | {row['n']} | {_fmt(row.get('robot_steps_per_s'), '.3e')} | "
            f"{_fmt(row.get('run_s'), '.4f')} | {_fmt(row.get('compile_s'), '.2f')} | "
            f"{_fmt(row.get('others_cpu'), '.2f')} |"
        )
    return lines


def _ratio_lines(ratios: dict[str, dict[str, float]]) -> list[str]:
    if not ratios:
        return []
    lines = [
        "| N | " + " | ".join(_RATIO_COLUMNS.values()) + " |",
        "|---:|" + "---:|" * len(_RATIO_COLUMNS),
    ]
    for key, entry in ratios.items():
        cells = [_ratio(entry, key) for key in _RATIO_COLUMNS]
        lines.append(f"| {key[2:]} | " + " | ".join(cells) + " |")
    return ["", *lines]


def bench_table(result: dict[str, Any]) -> str:
    """Return a ``run_benchmark`` result as Markdown: environment, rates, then ratios.

    A note follows when other processes used over 0.2 cores while it was timed.
    """
    keys = ("environment", "config", "rows")
    if not isinstance(result, dict) or any(k not in result for k in keys) or not result["rows"]:
        raise ValueError(
            f"result = {result!r:.80} is not allowed; allowed: what run_benchmark returned "
            f"(a dict with {', '.join(keys)}, and one row or more)"
        )
    shown = ("device", "backend", "devices", "cpu_cores", "cpu", "jax", "jaxlib", "numpy")
    for part, needed in (("environment", shown), ("config", ("dtype", "steps", "repeats"))):
        missing = [k for k in needed if k not in result[part]]
        if missing:
            raise ValueError(
                f"result[{part!r}] has no {missing[0]!r}; allowed: what run_benchmark returned"
            )
    for i, row in enumerate(result["rows"]):
        if not all(k in row for k in ("case", "n")):
            raise ValueError(f"result['rows'][{i}] has no 'case' and 'n'; allowed: benchmark rows")
    env, config = result["environment"], result["config"]
    lines = [
        f"device: {env['device']} ({env['backend']}, {env['devices']} device(s), "
        f"{env['cpu_cores']} cores: {env['cpu']})",
        f"jax {env['jax']}, jaxlib {env['jaxlib']}, numpy {env['numpy']}, "
        f"dtype {config['dtype']}, {config['steps']} steps, median of {config['repeats']}",
        "",
        *_rate_lines(result["rows"]),
    ]
    lines += _ratio_lines(result.get("ratios") or {})
    busy = [r["others_cpu"] for r in result["rows"] if r.get("others_cpu") is not None]
    if busy and max(busy) > 0.2:
        lines += [
            "",
            f"note: other processes used up to {max(busy):.1f} CPU cores during the run; "
            "absolute rates are lower than on an idle machine.",
        ]
    return "\n".join(lines) + "\n"
