"""Throughput of the simulator: ``wmr-jax bench``, in robot-steps per second.

One robot-step is one robot simulated over one control period. For each batch
size the command times

* ``final_poses`` with the ideal velocity loop, and with the non-ideal one;
  with several local devices also the ideal one on a batch spread over all of
  them (``wmr_jax.sharding.shard``); the command splits the CPU into two
  devices per core first (``--cpu-devices``), which is faster on the CPU;
* ``batch_rollout`` (whole trajectories), ideal loop;
* the gradient of a batched loss with respect to the gains: the mean squared
  final-pose error through ``final_poses``, and ``wmr_jax.tuning``'s loss when
  that module is present; each against its own forward evaluation;

and, in the same run, two baselines of the ideal loop:

* the package's scalar NumPy reference (``wmr_jax.reference``), one pose at a
  time in a Python loop: a few poses are timed and the rate is per robot-step;
* ``numpy_final_poses``, the law and the exact arc of SPEC §2–4 written for
  NumPy arrays the way a user would without JAX: vectorised over the batch,
  one Python iteration per control period, angles and ``atan2``.

Each time is the median of ``--repeats`` calls after a first call, whose extra
time is reported apart as the compile time (tracing and XLA compilation).
Cases compared with each other (``final_poses`` and the baselines, a loss and
its gradient) are timed in alternation, so that they share the machine's load;
each timed JAX call follows an untimed one, so that it measures the steady
state of a loop of calls rather than the wake-up of XLA's threads.
The device, JAX version and the machine's load during the run are recorded,
since a shared machine makes every timing noisy: compare ratios taken in the
same run rather than absolute rates across runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import resource
import statistics
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = [
    "BenchConfig",
    "configure_parser",
    "format_table",
    "numpy_final_poses",
    "run_benchmark",
    "run_cli",
]

DEFAULT_SIZES = (1_000, 10_000, 100_000)
DEFAULT_STEPS = 100
DEFAULT_REPEATS = 5
DEFAULT_REFERENCE_POSES = 20
DTYPES = ("float32", "float64")
# The smooth law used for the gradient of the tuning loss, as tuning anneals it.
TUNING_TEMPERATURE = 0.05


# ---------------------------------------------------------------- NumPy baseline


def numpy_final_poses(
    refs: Any,
    gains: Any = None,
    *,
    init: Sequence[float] = (0.0, 0.0, 0.0),
    dt: float = 0.033,
    steps: int = 150,
) -> np.ndarray:
    """Return the final poses of the ideal closed loop, vectorised with NumPy (SPEC §2–4).

    The baseline a user would write without JAX: the law with angles and
    ``atan2`` as SPEC §3 states it, the exact arc of SPEC §4, arrays over the
    batch and one Python iteration per control period. The arithmetic is in
    the dtype of ``refs`` (float32 or float64).

    Args:
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        gains: ``wmr_jax.Gains`` with scalar fields; default ``Gains()``.
        init: ``(3,)`` initial pose shared by every run.
        dt: control period, s.
        steps: number of control periods.

    Returns:
        ``(N, 3)`` final poses, dtype of ``refs``.
    """
    from wmr_jax.params import Gains

    refs = np.asarray(refs)
    if refs.dtype not in (np.float32, np.float64):
        refs = refs.astype(np.float64)
    dtype = refs.dtype.type
    g = Gains() if gains is None else gains
    kr, k_theta, phi_m = dtype(g.kr), dtype(g.k_theta), dtype(g.phi_m)
    r_m, r_a, r_e, alpha = dtype(g.r_m), dtype(g.r_a), dtype(g.r_e), dtype(g.alpha)
    pi, half_pi, h = dtype(math.pi), dtype(math.pi / 2), dtype(dt)
    x_r, y_r, th_r = refs[:, 0], refs[:, 1], refs[:, 2]
    n = refs.shape[0]
    x = np.full(n, init[0], dtype)
    y = np.full(n, init[1], dtype)
    th = np.full(n, init[2], dtype)
    one, zero = dtype(1), dtype(0)

    def fold(a):
        return np.where(a > half_pi, a - pi, np.where(a < -half_pi, a + pi, a))

    def sgn(a):
        return np.where(a > 0, one, -one)

    for _ in range(steps):
        # Error coordinates (Eq. 3, 4).
        cos_c, sin_c = np.cos(th), np.sin(th)
        dx, dy = x_r - x, y_r - y
        e_x = cos_c * dx + sin_c * dy
        e_y = cos_c * dy - sin_c * dx
        r = np.hypot(e_x, e_y)
        phi = np.arctan2(e_y, e_x)  # atan2(0, 0) = 0: SPEC's choice at r_e = 0
        theta_e = np.mod(th_r - th + pi, 2 * pi) - pi
        # The law (Eq. 6–8), regions tested in SPEC §3 order.
        r_bar = np.minimum(r * (half_pi / r_m), half_pi)
        abs_phi = np.abs(phi)
        d = np.where(abs_phi <= phi_m, one, np.where(abs_phi > pi - phi_m, -one, zero))
        phi_bar = fold(phi)
        sin_phi_bar, cos_phi_bar = np.sin(phi_bar), np.cos(phi_bar)
        sin_theta_bar = np.sin(fold(theta_e))
        eps_1 = dtype(0.5) - alpha * sgn(sin_theta_bar) * sgn(sin_theta_bar + sin_phi_bar)
        eps = np.where(r <= r_e, zero, np.where(d == 0, one, np.where(r < r_a, eps_1, one)))
        v = kr * d * np.sin(r_bar) * cos_phi_bar
        omega = k_theta * (eps * sin_phi_bar + (one - eps) * sin_theta_bar)
        # Exact arc over dt (SPEC §4), sinc by its series near 0.
        half = dtype(0.5) * omega * h
        small = np.abs(half) < 1e-3
        sinc = np.where(
            small,
            one - half * half / dtype(6),
            np.sin(half) / np.where(small, one, half),
        )
        chord = v * h * sinc
        heading = th + half
        x = x + chord * np.cos(heading)
        y = y + chord * np.sin(heading)
        th = th + omega * h
    return np.stack([x, y, th], axis=-1)


# ---------------------------------------------------------------- timing


def _cpu_busy_seconds() -> float | None:
    """Return the CPU seconds all processes have used (Linux), or ``None``."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    # user, nice, system, irq, softirq, steal
    busy = fields[0] + fields[1] + fields[2] + sum(fields[5:8])
    return busy / os.sysconf("SC_CLK_TCK")


def _own_cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@dataclasses.dataclass
class Timing:
    """Timing of one benchmark case.

    Attributes:
        run_s: median wall time of one call, s.
        compile_s: extra time of the first call (trace and compile), s.
        runs_s: every timed call, s.
        others_cpu: CPU other processes used while the case was timed, in
            cores (0 on an idle machine; Linux only, else ``None``).
    """

    run_s: float
    compile_s: float | None
    runs_s: list[float]
    others_cpu: float | None


def _wait_for_idle(limit_s: float, *, threshold: float = 0.1, window_s: float = 0.3) -> None:
    """Wait up to ``limit_s`` until other processes use under ``threshold`` cores."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        busy0, own0 = _cpu_busy_seconds(), _own_cpu_seconds()
        if busy0 is None:
            return
        time.sleep(window_s)
        busy1, own1 = _cpu_busy_seconds(), _own_cpu_seconds()
        if max(0.0, (busy1 - busy0) - (own1 - own0)) / window_s < threshold:
            return


def _time_group(
    calls: dict[str, tuple[Callable[[], Any], bool]], repeats: int, *, wait_idle: float = 0.0
) -> dict:
    """Time several calls, interleaved, so that they see the same machine load.

    Args:
        calls: ``name -> (call, compiled)``; a ``compiled`` call gets a first,
            untimed call whose extra time is reported as its compile time.
        repeats: timed calls of each.
        wait_idle: before each round of calls, wait up to this many seconds
            for the machine to be idle (0: do not wait).

    Returns:
        ``name -> Timing``.
    """
    import jax

    first: dict[str, float | None] = {}
    for name, (call, compiled) in calls.items():
        first[name] = None
        if compiled:
            start = time.perf_counter()
            jax.block_until_ready(call())
            first[name] = time.perf_counter() - start
    runs: dict[str, list[float]] = {name: [] for name in calls}
    # CPU time of other processes while each case ran, summed over its calls:
    # /proc/stat counts in 10 ms ticks, too coarse for one short call.
    others: dict[str, list[float]] = {name: [0.0, 0.0] for name in calls}
    for _ in range(repeats):
        if wait_idle > 0:
            _wait_for_idle(wait_idle)
        for name, (call, compiled) in calls.items():
            if compiled:
                # Steady state, as in a loop of calls: right after another
                # case (NumPy's half second, say) XLA's worker threads are
                # asleep, and waking them costs a JAX call up to 30 %.
                jax.block_until_ready(call())
            busy0, own0, start = _cpu_busy_seconds(), _own_cpu_seconds(), time.perf_counter()
            jax.block_until_ready(call())
            wall = time.perf_counter() - start
            busy1, own1 = _cpu_busy_seconds(), _own_cpu_seconds()
            runs[name].append(wall)
            if busy0 is not None and busy1 is not None:
                others[name][0] += max(0.0, (busy1 - busy0) - (own1 - own0))
                others[name][1] += wall
    cores = os.cpu_count() or 1
    timings = {}
    for name in calls:
        run = statistics.median(runs[name])
        compile_s = None if first[name] is None else max(0.0, first[name] - run)
        cpu, wall = others[name]
        share = min(cores, cpu / wall) if wall > 0 and _cpu_busy_seconds() is not None else None
        timings[name] = Timing(run, compile_s, runs[name], share)
    return timings


# ---------------------------------------------------------------- the benchmark


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """What ``run_benchmark`` measures.

    Attributes:
        sizes: batch sizes N.
        steps: control periods per run.
        repeats: timed calls per case (the median is reported).
        dtype: ``"float32"`` or ``"float64"``.
        reference_poses: poses the scalar reference is timed on.
        cases: which cases to run, from ``CASES``.
        seed: seed of the reference poses (SPEC §6 distribution).
        wait_idle: before each round of timed calls, wait up to this many
            seconds for other processes to leave the CPU (shared machines).
    """

    sizes: tuple[int, ...] = DEFAULT_SIZES
    steps: int = DEFAULT_STEPS
    repeats: int = DEFAULT_REPEATS
    dtype: str = "float32"
    reference_poses: int = DEFAULT_REFERENCE_POSES
    cases: tuple[str, ...] = ()
    seed: int = 0
    wait_idle: float = 0.0


CASES = (
    "final_poses",
    "final_poses_sharded",
    "final_poses_nonideal",
    "batch_rollout",
    "grad_final_pose_loss",
    "grad_tuning_loss",
    "numpy_batch",
    "scalar_reference",
)


def _check_config(config: BenchConfig) -> BenchConfig:
    """Validate ``config`` (before any tracing); return it with ``cases`` filled in."""
    if not config.sizes or any(
        isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1 for n in config.sizes
    ):
        raise ValueError(f"sizes = {config.sizes!r} is not allowed; allowed: integers >= 1")
    for name in ("steps", "repeats", "reference_poses"):
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= 1")
    if not (isinstance(config.wait_idle, (int, float)) and 0 <= config.wait_idle < math.inf):
        raise ValueError(
            f"wait_idle = {config.wait_idle!r} is not allowed; allowed: a number >= 0 s"
        )
    if config.dtype not in DTYPES:
        raise ValueError(f"dtype = {config.dtype!r} is not allowed; allowed: {DTYPES}")
    unknown = [c for c in config.cases if c not in CASES]
    if unknown:
        raise ValueError(f"cases = {unknown!r} are not known; allowed: {CASES}")
    return dataclasses.replace(config, cases=tuple(config.cases) or CASES)


def _sample_refs(n: int, seed: int, dtype: Any) -> np.ndarray:
    """References of SPEC §6: 5–80 cm away in any bearing, any heading."""
    rng = np.random.default_rng(seed)
    dist = rng.uniform(5.0, 80.0, n)
    bearing = rng.uniform(-math.pi, math.pi, n)
    heading = rng.uniform(-math.pi, math.pi, n)
    refs = np.stack([dist * np.cos(bearing), dist * np.sin(bearing), heading], axis=-1)
    return refs.astype(dtype)


def _environment() -> dict[str, Any]:
    import jax
    import jaxlib

    devices = jax.devices()
    cpu_model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu_model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "backend": jax.default_backend(),
        "device": str(devices[0].device_kind),
        "devices": len(devices),
        "cpu": cpu_model,
        "cpu_cores": os.cpu_count(),
        "x64": bool(jax.config.jax_enable_x64),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def _row(case: str, n: int | None, steps: int, timing: Timing | None, **extra: Any) -> dict:
    row: dict[str, Any] = {"case": case, "n": n, "steps": steps}
    if timing is not None:
        count = (n or 0) * steps
        row.update(
            run_s=timing.run_s,
            compile_s=timing.compile_s,
            robot_steps_per_s=count / timing.run_s if timing.run_s > 0 else None,
            runs_s=timing.runs_s,
            others_cpu=timing.others_cpu,
        )
    row.update(extra)
    return row


def _final_pose_loss(final_poses: Callable, steps: int) -> Callable:
    """Mean squared final-pose error as a function of ``(gains, refs)``."""
    import jax.numpy as jnp

    def loss(gains, refs):
        final = final_poses(refs, gains, steps=steps)
        err = final - refs
        return jnp.mean(err[:, 0] ** 2 + err[:, 1] ** 2 + (1.0 - jnp.cos(err[:, 2])))

    return loss


def run_benchmark(config: BenchConfig, *, log: Callable[[str], None] | None = None) -> dict:
    """Run the benchmark and return its results as a JSON-ready dict.

    Args:
        config: what to measure.
        log: called with one line per finished case (progress).

    Returns:
        ``{"environment": ..., "config": ..., "rows": [...], "ratios": {...}}``;
        each row has ``case``, ``n``, ``steps``, ``run_s``, ``compile_s``,
        ``robot_steps_per_s``, ``others_cpu`` (or ``skipped`` with a reason).

    Raises:
        ValueError: for a bad ``config``.
    """
    config = _check_config(config)
    import jax

    if config.dtype == "float64" and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    if config.dtype == "float32" and jax.config.jax_enable_x64:
        raise ValueError(
            "dtype = 'float32' is not allowed while jax_enable_x64 is on; "
            "allowed: 'float64', or turn jax_enable_x64 off"
        )
    from wmr_jax.params import Gains

    say = log or (lambda line: None)
    dtype = np.float32 if config.dtype == "float32" else np.float64
    gains = Gains()
    rows: list[dict] = []

    def add(row: dict) -> None:
        rows.append(row)
        rate = row.get("robot_steps_per_s")
        text = row.get("skipped") or (f"{rate:.3e} robot-steps/s" if rate else "")
        say(f"{row['case']:<22} N={row['n']!s:<8} {text}")

    with warnings.catch_warnings():
        # The paper's gains trip the wheel-speed warning on every call.
        warnings.simplefilter("ignore")
        for n in config.sizes:
            scalar = "scalar_reference" in config.cases and n == max(config.sizes)
            for row in _bench_size(config, n, gains, dtype, scalar=scalar):
                add(row)
    return {
        "environment": _environment(),
        "config": dataclasses.asdict(config),
        "rows": rows,
        "ratios": _ratios(rows),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _bench_size(config: BenchConfig, n: int, gains: Any, dtype: Any, *, scalar: bool) -> list:
    """Return the rows of every case at batch size ``n``."""
    import jax
    import jax.numpy as jnp

    from wmr_jax import reference, simulation

    steps, repeats, cases = config.steps, config.repeats, config.cases
    refs_np = _sample_refs(n, config.seed + n, dtype)
    refs = jnp.asarray(refs_np)
    rows = []

    # final_poses against both baselines, interleaved: their ratio is what counts.
    group: dict[str, tuple[Callable[[], Any], bool]] = {}
    if "final_poses" in cases:
        group["final_poses"] = (lambda: simulation.final_poses(refs, gains, steps=steps), True)
    if "numpy_batch" in cases:
        group["numpy_batch"] = (lambda: numpy_final_poses(refs_np, gains, steps=steps), False)
    k = config.reference_poses
    scalar_refs = _sample_refs(k, config.seed, np.float64)
    if scalar:

        def scalar_runs():
            for ref in scalar_refs:
                reference.reference_rollout(ref, gains, steps=steps)

        group["scalar_reference"] = (scalar_runs, False)
    devices = jax.local_devices()
    if "final_poses_sharded" in cases and len(devices) > 1:
        from wmr_jax.sharding import shard

        spread = shard(refs_np, devices)
        group["final_poses_sharded"] = (
            lambda: simulation.final_poses(spread.array, gains, steps=steps),
            True,
        )
    timings = _time_group(group, repeats, wait_idle=config.wait_idle) if group else {}
    if "final_poses" in timings:
        rows.append(_row("final_poses", n, steps, timings["final_poses"], velocity="ideal"))
    if "final_poses_sharded" in timings:
        rows.append(
            _row(
                "final_poses_sharded",
                n,
                steps,
                timings["final_poses_sharded"],
                devices=len(devices),
            )
        )

    if "final_poses_nonideal" in cases:
        try:
            t = _time_group(
                {
                    "nonideal": (
                        lambda: simulation.final_poses(
                            refs, gains, steps=steps, velocity="nonideal"
                        ),
                        True,
                    )
                },
                repeats,
                wait_idle=config.wait_idle,
            )["nonideal"]
            rows.append(_row("final_poses_nonideal", n, steps, t, velocity="nonideal"))
        except NotImplementedError as err:
            rows.append(_row("final_poses_nonideal", n, steps, None, skipped=f"skipped: {err}"))
    if "batch_rollout" in cases:
        t = _time_group(
            {"rollout": (lambda: simulation.batch_rollout(refs, gains, steps=steps), True)},
            repeats,
            wait_idle=config.wait_idle,
        )["rollout"]
        rows.append(_row("batch_rollout", n, steps, t, velocity="ideal"))
    if "grad_final_pose_loss" in cases:
        loss = _final_pose_loss(simulation.final_poses, steps)
        forward = simulation.jit_top_level(loss)
        gradient = simulation.jit_top_level(jax.value_and_grad(loss))
        t = _time_group(
            {
                "forward": (lambda: forward(gains, refs), True),
                "gradient": (lambda: gradient(gains, refs), True),
            },
            repeats,
            wait_idle=config.wait_idle,
        )
        rows.append(_row("final_pose_loss", n, steps, t["forward"], of="mean squared error"))
        rows.append(
            _row(
                "grad_final_pose_loss",
                n,
                steps,
                t["gradient"],
                grad_over_forward=t["gradient"].run_s / t["forward"].run_s,
            )
        )
    if "grad_tuning_loss" in cases:
        rows += _tuning_rows(refs, gains, n, steps, repeats, config.wait_idle)
    if "numpy_batch" in timings:
        rows.append(_row("numpy_batch", n, steps, timings["numpy_batch"], dtype=config.dtype))
    if "scalar_reference" in timings:
        rows.append(
            _row(
                "scalar_reference",
                k,
                steps,
                timings["scalar_reference"],
                note="float64, one pose at a time",
            )
        )
    return rows


def _tuning_rows(refs: Any, gains: Any, n: int, steps: int, repeats: int, wait_idle: float) -> list:
    """Time ``wmr_jax.tuning.tuning_loss`` and its gradient, or record why not."""
    import jax

    from wmr_jax import simulation

    try:
        from wmr_jax import tuning

        horizon = steps * simulation.DEFAULT_DT

        def loss(g, r):
            return tuning.tuning_loss(g, r, temperature=TUNING_TEMPERATURE, horizon=horizon)

        forward = simulation.jit_top_level(loss)
        gradient = simulation.jit_top_level(jax.value_and_grad(loss))
        t = _time_group(
            {
                "forward": (lambda: forward(gains, refs), True),
                "gradient": (lambda: gradient(gains, refs), True),
            },
            repeats,
            wait_idle=wait_idle,
        )
    except (ImportError, AttributeError, TypeError, NotImplementedError) as err:
        return [_row("grad_tuning_loss", n, steps, None, skipped=f"skipped: {err}")]
    return [
        _row("tuning_loss", n, steps, t["forward"], temperature=TUNING_TEMPERATURE),
        _row(
            "grad_tuning_loss",
            n,
            steps,
            t["gradient"],
            grad_over_forward=t["gradient"].run_s / t["forward"].run_s,
        ),
    ]


def _ratios(rows: list[dict]) -> dict[str, Any]:
    """Speed-ups of ``final_poses`` over the baselines, per batch size."""

    def rate(case: str, n: int | None = None) -> float | None:
        for row in rows:
            if row["case"] == case and (n is None or row["n"] == n):
                return row.get("robot_steps_per_s")
        return None

    scalar = rate("scalar_reference")
    out: dict[str, Any] = {}
    sizes = sorted({row["n"] for row in rows if row["case"] != "scalar_reference"})
    for n in sizes:
        entry: dict[str, Any] = {}
        jax_rate = rate("final_poses", n)
        spread_rate = rate("final_poses_sharded", n)
        numpy_rate = rate("numpy_batch", n)
        for name, value in (("", jax_rate), ("sharded_", spread_rate)):
            if value and numpy_rate:
                entry[f"{name}vs_numpy_batch"] = value / numpy_rate
            if value and scalar:
                entry[f"{name}vs_scalar_reference"] = value / scalar
        for case in ("grad_final_pose_loss", "grad_tuning_loss"):
            for r in rows:
                if r["case"] == case and r["n"] == n and "grad_over_forward" in r:
                    entry[f"{case}_over_forward"] = r["grad_over_forward"]
        if entry:
            out[f"N={n}"] = entry
    return out


# ---------------------------------------------------------------- report


def _fmt(value: float | None, spec: str, unit: str = "") -> str:
    return "—" if value is None else format(value, spec) + unit


def format_table(result: dict) -> str:
    """Return the benchmark as a Markdown table with the environment above it."""
    env = result["environment"]
    lines = [
        f"device: {env['device']} ({env['backend']}, {env['devices']} device(s), "
        f"{env['cpu_cores']} cores: {env['cpu']})",
        f"jax {env['jax']}, jaxlib {env['jaxlib']}, numpy {env['numpy']}, "
        f"dtype {result['config']['dtype']}, {result['config']['steps']} steps, "
        f"median of {result['config']['repeats']}",
        "",
        "| case | N | robot-steps/s | run s | compile s | others' CPU |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for row in result["rows"]:
        if "skipped" in row:
            lines.append(f"| {row['case']} | {row['n']} | {row['skipped']} | | | |")
            continue
        lines.append(
            f"| {row['case']} | {row['n']} | {_fmt(row.get('robot_steps_per_s'), '.3e')} | "
            f"{_fmt(row.get('run_s'), '.4f')} | {_fmt(row.get('compile_s'), '.2f')} | "
            f"{_fmt(row.get('others_cpu'), '.2f')} |"
        )
    ratios = result.get("ratios") or {}
    if ratios:
        lines += [
            "",
            "| N | final_poses / NumPy batch | final_poses / scalar reference "
            "| sharded / NumPy batch | sharded / scalar reference "
            "| grad / forward (final-pose loss) | grad / forward (tuning loss) |",
            "|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for key, entry in ratios.items():
            lines.append(
                f"| {key[2:]} | {_fmt(entry.get('vs_numpy_batch'), '.1f', '×')} | "
                f"{_fmt(entry.get('vs_scalar_reference'), '.0f', '×')} | "
                f"{_fmt(entry.get('sharded_vs_numpy_batch'), '.1f', '×')} | "
                f"{_fmt(entry.get('sharded_vs_scalar_reference'), '.0f', '×')} | "
                f"{_fmt(entry.get('grad_final_pose_loss_over_forward'), '.2f')} | "
                f"{_fmt(entry.get('grad_tuning_loss_over_forward'), '.2f')} |"
            )
    busy = [r["others_cpu"] for r in result["rows"] if r.get("others_cpu") is not None]
    if busy and max(busy) > 0.2:
        lines += [
            "",
            f"note: other processes used up to {max(busy):.1f} CPU cores during the run; "
            "absolute rates are lower than on an idle machine.",
        ]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- command line


def _positive_int(text: str) -> int:
    try:
        value = int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not allowed; allowed: an integer >= 1")
    return value


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax bench`` to ``parser``."""
    parser.add_argument(
        "--sizes",
        nargs="+",
        type=_positive_int,
        default=list(DEFAULT_SIZES),
        metavar="N",
        help="batch sizes (default 1000 10000 100000)",
    )
    parser.add_argument(
        "--steps", type=_positive_int, default=DEFAULT_STEPS, help="control periods (100)"
    )
    parser.add_argument(
        "--repeats", type=_positive_int, default=DEFAULT_REPEATS, help="timed calls per case (5)"
    )
    parser.add_argument("--dtype", choices=DTYPES, default="float32", help="float32 (default)")
    parser.add_argument(
        "--reference-poses",
        type=_positive_int,
        default=DEFAULT_REFERENCE_POSES,
        metavar="K",
        help="poses the scalar NumPy reference is timed on (20)",
    )
    parser.add_argument(
        "--cases",
        nargs="+",
        choices=CASES,
        default=None,
        metavar="CASE",
        help="only these cases: " + ", ".join(CASES),
    )
    parser.add_argument(
        "--cpu-devices",
        type=_positive_int,
        default=None,
        metavar="K",
        help="split the CPU into K JAX devices for the sharded case (default: two per "
        "core; 1 to keep one). Only before JAX starts; see wmr_jax.sharding.use_cpu_devices",
    )
    parser.add_argument(
        "--wait-idle",
        type=float,
        default=0.0,
        metavar="S",
        help="on a shared machine: before each round of timed calls, wait up to S s "
        "for other processes to leave the CPU (default 0: do not wait)",
    )
    parser.add_argument("--json", metavar="FILE", help="also write the results here (atomically)")


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax bench`` with parsed ``args``; print the table; return 0.

    Raises:
        ValueError: one line naming a bad flag value and what is allowed.
    """
    from wmr_jax.io import atomic_write_json
    from wmr_jax.sharding import use_cpu_devices

    use_cpu_devices(args.cpu_devices)
    config = BenchConfig(
        sizes=tuple(args.sizes),
        steps=args.steps,
        repeats=args.repeats,
        dtype=args.dtype,
        reference_poses=args.reference_poses,
        cases=tuple(args.cases or ()),
        wait_idle=args.wait_idle,
    )
    result = run_benchmark(config, log=lambda line: print(line, file=sys.stderr, flush=True))
    print(format_table(result), end="")
    if args.json:
        atomic_write_json(args.json, result)
        print(f"results: {args.json}")
    return 0
