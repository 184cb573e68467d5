"""How ``wmr-jax bench`` times a case, and what it records of the machine.

A case is timed as the median of repeated calls after a first one; the CPU
time of other processes during each call is recorded beside it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import platform
import resource
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def _others_cpu_seconds() -> float | None:
    """The CPU seconds every process but this one has used (Linux), or ``None``."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    # user, nice, system, irq, softirq, steal
    busy = fields[0] + fields[1] + fields[2] + sum(fields[5:8])
    own = resource.getrusage(resource.RUSAGE_SELF)
    return busy / os.sysconf("SC_CLK_TCK") - (own.ru_utime + own.ru_stime)


@dataclasses.dataclass
class Timing:
    """Timing of one benchmark case.

    Attributes:
        run_s: median wall time of one call, s.
        compile_s: extra time of the first call (trace and compile), s.
        runs_s: every timed call, s.
        others_cpu: CPU other processes used meanwhile, cores (Linux, else ``None``).
        page_faults: minor page faults of this process per timed call: memory
            the call got fresh from the kernel rather than reused (docs/scale.md).
    """

    run_s: float
    compile_s: float | None
    runs_s: list[float]
    others_cpu: float | None
    page_faults: float


def _wait_for_idle(limit_s: float, *, threshold: float = 0.1, window_s: float = 0.3) -> None:
    """Wait up to ``limit_s`` until other processes use under ``threshold`` cores."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        before = _others_cpu_seconds()
        if before is None:
            return
        time.sleep(window_s)
        if max(0.0, _others_cpu_seconds() - before) / window_s < threshold:
            return


def time_group(
    calls: dict[str, tuple[Callable[[], Any], bool]], repeats: int, *, wait_idle: float = 0.0
) -> dict:
    """Time ``calls`` (``name -> (call, compiled)``) interleaved, under the same machine load.

    Each is called ``repeats`` times; a ``compiled`` one first gets an untimed call, whose
    extra time is its compile time. Before each round, wait up to ``wait_idle`` s for an idle
    machine. Returns ``name -> Timing``.
    """
    import jax

    first: dict[str, float | None] = dict.fromkeys(calls)
    for name, (call, compiled) in calls.items():
        if compiled:
            start = time.perf_counter()
            jax.block_until_ready(call())
            first[name] = time.perf_counter() - start
    runs: dict[str, list[float]] = {name: [] for name in calls}
    # CPU time of other processes while each case ran, summed over its calls:
    # /proc/stat counts in 10 ms ticks, too coarse for one short call.
    others: dict[str, list[float]] = {name: [0.0, 0.0] for name in calls}
    faults = dict.fromkeys(calls, 0)
    for _ in range(repeats):
        if wait_idle > 0:
            _wait_for_idle(wait_idle)
        for name, (call, compiled) in calls.items():
            if compiled:
                # Steady state, as in a loop of calls: right after another
                # case XLA's worker threads are asleep, and waking them costs.
                jax.block_until_ready(call())
            faulted = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            before, start = _others_cpu_seconds(), time.perf_counter()
            jax.block_until_ready(call())
            wall = time.perf_counter() - start
            faults[name] += resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faulted
            after = _others_cpu_seconds()
            runs[name].append(wall)
            if before is not None and after is not None:
                others[name][0] += max(0.0, after - before)
                others[name][1] += wall
    cores = os.cpu_count() or 1
    timings = {}
    for name in calls:
        run = statistics.median(runs[name])
        compile_s = None if first[name] is None else max(0.0, first[name] - run)
        cpu, wall = others[name]
        share = min(cores, cpu / wall) if wall > 0 and _others_cpu_seconds() is not None else None
        timings[name] = Timing(run, compile_s, runs[name], share, faults[name] / repeats)
    return timings


def environment() -> dict[str, Any]:
    """The software and machine a benchmark ran on, recorded with its results."""
    import jax
    import jaxlib

    devices = jax.devices()
    cpu_model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("model name"):
                cpu_model = line.split(":", 1)[1].strip()
                break
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
