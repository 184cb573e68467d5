"""Test configuration: float64 for reference comparisons.

JAX's default float32 path is exercised by tests that wrap themselves in
``jax.enable_x64(False)`` (e.g. ``test_rollout.py::test_float32_default_path_*``).
"""

import atexit
import functools
import gc
import os
import shutil
import sys
from pathlib import Path

# The suite is mostly XLA compilation (each test compiles its own shapes and
# options once). XLA's backend optimisation level 0 compiles the same programs
# about twice as fast; they compute the same values (the tests compare them
# with the NumPy reference, and tests/test_readme.py with probes recorded by
# the commands at the default level), if more slowly, which the suite's small
# runs do not feel. The commands and the benchmark keep XLA's default.
# Likewise XLA:CPU's older loop emitters compile these programs about a
# quarter faster than its fusion emitters; their float32 results may differ
# in the last bit, so tests comparing runs across processes bit for bit hand
# these flags on (tests/test_sharding.py).
for _flag in ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false"):
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _flag).strip()

# JAX's persistent compilation cache, kept in the checkout (ignored by git):
# tests that build the same program again (a new closure, another file, the
# other worker, a subprocess) load it instead of compiling it, and a second
# run of the suite compiles almost nothing. Its key is the compiled program
# itself (with the XLA flags and JAX's version), so a changed law or a
# mutant (mutmut) compiles afresh. Set WMR_JAX_TEST_CACHE=0 to run without it.
_CACHE = Path(__file__).resolve().parent.parent / ".xla-cache"
_CACHE_LIMIT = 2 << 30  # bytes; above this the whole cache is dropped at the next start
if os.environ.get("WMR_JAX_TEST_CACHE", "1") != "0":
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

# Python's cyclic garbage collector: a worker comes to hold millions of
# long-lived objects (JAX's traces, lowered and compiled programs), and with
# CPython's default thresholds a full collection over all of them ran every
# few seconds, some 5 % of the suite's CPU time. Collect more rarely; the
# objects alive once the tests are collected (modules, JAX itself) are moved
# out of the collector's way (``pytest_collection_finish``).
gc.set_threshold(50_000, 20, 20)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wmr_jax as w

jax.config.update("jax_enable_x64", True)
# JAX writes the Python call stack of every operation into the programs it
# lowers, as source locations for XLA's error messages and profiles; building
# them costs some 8 % of the CPU time of a test that traces a robust tuning
# step. The suite reads neither, and the compilation cache's key leaves them out.
jax.config.update("jax_include_full_tracebacks_in_locations", False)
jax.config.update("jax_traceback_in_locations_limit", 0)

# pyproject.toml's filterwarnings names wmr_jax.WheelSpeedWarning, so pytest
# imports wmr_jax, and JAX with it, before this file runs: JAX has read its
# settings from the environment already, and the cache set there above would
# reach only the subprocesses. Set it on JAX's config as well.
if os.environ.get("WMR_JAX_TEST_CACHE", "1") != "0":
    jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


@pytest.fixture
def paper_refs() -> np.ndarray:
    """The seven references of Fig. 7, ``(7, 3)`` in cm, cm, rad."""
    return w.paper_refs()


@pytest.fixture
def estimator_registry():
    """The estimators' registry, left as the test found it (every module reads the one dict)."""
    from wmr_jax._src.sim.sensing import estimators

    kept = dict(estimators.ESTIMATORS)
    yield estimators.ESTIMATORS
    estimators.ESTIMATORS.clear()
    estimators.ESTIMATORS.update(kept)


# Every draw of n ≤ _POOL poses is the first n rows of one draw of _POOL (JAX's
# threefry draws element by element), so the tests share one compiled sampler
# instead of compiling one per n.
_POOL = 1024


@functools.cache
def _pool(seed: int, r_min: float, r_max: float) -> np.ndarray:
    with jax.enable_x64(True):  # float64 even when first asked inside a float32 test
        pool = w.sample_poses(seed, _POOL, r_min=r_min, r_max=r_max, dtype=np.float64)
        pool = np.asarray(pool, dtype=np.float64)
    pool.setflags(write=False)
    return pool


def random_refs(seed: int, n: int, r_min: float = 5.0, r_max: float = 80.0) -> np.ndarray:
    """``n`` references of the evaluation set (``docs/model.md §6``), as float64 NumPy.

    Equal to ``w.sample_poses(seed, n, r_min=r_min, r_max=r_max, dtype=np.float64)``.
    """
    if n > _POOL:
        return np.asarray(w.sample_poses(seed, n, r_min=r_min, r_max=r_max, dtype=np.float64))
    return _pool(seed, float(r_min), float(r_max))[:n].copy()


@functools.partial(jax.jit, static_argnames=("dt",))
def _run_metrics(traj, refs, dt):
    refs = jnp.asarray(refs)
    return {
        "arrival": w.arrival_time(traj, refs, dt=dt),
        "zigzag": w.studies.zigzag_count(traj),
        "path": w.studies.path_length(traj),
        # Whether each sample (the pose after each period) is arrived.
        "arrived": w.studies.arrived(traj.poses[..., 1:, :], refs[..., None, :]),
    }


def run_metrics(traj, refs, dt=0.033) -> dict:
    """Arrival times, zigzag counts, path lengths and arrived samples of recorded runs (§6).

    The public metrics, compiled as one program. Called directly they run op
    by op and compile every operation again for each new shape, several times
    the cost of this; ``test_metrics.py`` and ``test_fuzz.py`` call them so.
    For the tests that only need their values.
    """
    return {name: np.asarray(value) for name, value in _run_metrics(traj, refs, dt).items()}


def assert_metrics_of_runs(m, traj, refs, dt=0.033) -> dict:
    """Assert that streamed metrics ``m`` are those of the recorded runs ``traj``.

    Arrival times and zigzag counts are decided by the same comparisons on
    poses that agree to rounding (the streamed metrics read the heading's
    cosine and sine as the loop carries them, the recorded ones recompute them
    from θ, about 1e-14 apart), so they agree exactly unless a pose lies
    within that of a tolerance, which none of the tests' poses does; path
    lengths and peak wheel speeds are sums and maxima, equal to rounding.
    Returns ``run_metrics`` of ``traj``.
    """
    want = run_metrics(traj, refs, dt)
    np.testing.assert_array_equal(m.arrival, want["arrival"])
    np.testing.assert_array_equal(m.zigzag, want["zigzag"])
    np.testing.assert_allclose(m.path, want["path"], rtol=1e-12)
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(-1, -2))
    np.testing.assert_allclose(m.peak_wheel, peak, rtol=1e-12)
    return want


# ---------------------------------------------------------------- test order
#
# The suite runs one worker per core with ``--dist loadfile --no-loadscope-reorder``:
# each file goes whole to one worker (its compiled programs are reused within
# it), in the order below. Handing out the longest files first keeps both
# workers busy to the end, where a long file handed out last would leave one
# idle. CPU seconds per file (its process's and its subprocesses'), summed
# from the record of a whole run of a fresh clone (``WMR_JAX_TEST_CPU``,
# below; two workers, the compilation cache empty at the start): on a shared
# machine CPU time ranks the files where wall time would rank the load. A
# file not listed counts as one second.
FILE_SECONDS = {
    "test_tuning_robust.py": 30,
    "test_export.py": 19,
    "test_sensing.py": 18,
    "test_identify.py": 16,
    "test_bench.py": 13,
    "test_edges.py": 12,
    "test_tuning.py": 11,
    "test_robustness.py": 10,
    "test_law_derivative.py": 9,
    "test_custom_estimator.py": 8,
    "test_tuning_edges.py": 8,
    "test_maps.py": 7,
    "test_sweep.py": 7,
    "test_usability.py": 7,
    "test_user_view.py": 7,
    "test_velocity_loop.py": 7,
    "test_fuzz_inputs.py": 6,
    "test_schedule.py": 6,
    "test_cma.py": 5,
    "test_controllers.py": 5,
    "test_fuzz.py": 5,
    "test_metrics.py": 5,
    "test_reference.py": 5,
    "test_robot_followups.py": 5,
    "test_sharding.py": 5,
    "test_tuning_train.py": 5,
    "test_cli.py": 4,
    "test_readme.py": 4,
    "test_robots.py": 4,
    "test_rollout.py": 4,
    "test_shim_sung.py": 4,
    "test_tuning_budget.py": 4,
    "test_docs_current.py": 3,
    "test_meaning_estimators.py": 3,
    "test_meaning_law.py": 3,
    "test_tuning_best.py": 3,
    "test_velocity_loop_paths.py": 3,
    "test_waypoints.py": 3,
    "test_animation.py": 2,
    "test_centred.py": 2,
    "test_dynamics.py": 2,
    "test_evaluate.py": 2,
    "test_meaning_disturbances.py": 2,
    "test_report_edges.py": 2,
    "test_accel_limits.py": 1,
    "test_load_tuned.py": 1,
    "test_meaning_metrics.py": 1,
    "test_params.py": 1,
    "test_robot_commands.py": 1,
    "test_robot_studies.py": 1,
    "test_surfaces.py": 1,
    "test_boundaries.py": 1,
    "test_io.py": 1,
    "test_meaning_io.py": 1,
    "test_meaning_parametrisation.py": 1,
    "test_meaning_robots.py": 1,
    "test_optimal.py": 1,
    "test_poses.py": 1,
    "test_provenance.py": 1,
    "test_reproduction.py": 1,
}


@pytest.fixture(scope="session", autouse=True)
def _jax_started():
    """Start JAX's CPU backend before a test process runs its first test.

    The commands split the CPU into several JAX devices when JAX has not
    started yet (``use_cpu_devices``): without this, whichever test ran a
    command first would decide how many devices every later test in its
    process sees. tests/test_sharding.py splits the CPU in subprocesses.
    """
    jax.devices()


def pytest_configure(config):
    """Drop the compilation cache once it outgrows ``_CACHE_LIMIT`` (main process only).

    In an xdist worker, end the process at exit without JAX's own clean-up.
    """
    if hasattr(config, "workerinput"):
        atexit.register(_exit_now)
        return
    if not _CACHE.is_dir():
        return
    size = sum(f.stat().st_size for f in _CACHE.rglob("*") if f.is_file())
    if size > _CACHE_LIMIT:
        shutil.rmtree(_CACHE, ignore_errors=True)


def _exit_now():
    """End a worker at once, skipping the exit handlers registered before this one.

    JAX's handler (registered when ``jax`` was imported, so it would run after
    this one) frees every program the process compiled, some thousand in a
    worker: over ten seconds, and xdist waits up to ten for each worker to
    end before it kills it. By the time the interpreter exits,
    pytest has finished and xdist has its results; the compilation cache is
    written as programs compile. Only xdist workers do this, so a run in one
    process (``-n 0``, mutation testing) exits as usual.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def pytest_collection_modifyitems(items):
    """Longest files first; within a file, the written order."""
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 1))


def pytest_collection_finish(session):
    """Freeze what is alive now (modules, JAX, the collected tests): no collection rescans it."""
    gc.collect()
    gc.freeze()


def pytest_sessionfinish(session):
    """In an xdist worker, freeze what is alive once its tests have run.

    pytest ends a session with a full garbage collection (to report errors
    raised in finalizers) over every object the worker made, its traced and
    compiled programs included. The worker then ends without freeing
    anything (``_exit_now``), where those finalizers would not run either,
    so the collection is wasted work.
    """
    if hasattr(session.config, "workerinput"):
        gc.freeze()


def pytest_runtest_setup(item):
    """Under mutation testing (``mutmut run``), trace every test's programs afresh.

    A jitted function traced by an earlier test (or in the process mutmut
    forks each mutant from) would run its cached original, so a mutant would
    never be executed, and mutmut could not tell which tests reach which
    function. Outside mutation testing nothing is cleared.
    """
    if "MUTANT_UNDER_TEST" in os.environ:
        jax.clear_caches()


def _map_limit() -> int | None:
    """The kernel's limit on a process's memory mappings (Linux), else ``None``."""
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return None


_MAP_LIMIT = _map_limit()


def _mappings() -> int:
    with open("/proc/self/maps", "rb") as maps:
        return sum(1 for _ in maps)


def pytest_runtest_teardown(item, nextitem):
    """At the end of a file, drop JAX's compiled programs once they near the mapping limit.

    XLA:CPU maps each program it compiles or loads into memory as three
    mappings, and JAX's caches keep every program alive. A run of the whole
    suite in one process (``-n 0``) comes to hold some 22,000 programs,
    beyond Linux's default of 65,530 mappings, where the next compilation
    ends the process with a segmentation fault. Past three quarters of the
    limit the caches are cleared between files (no file adds a quarter);
    later tests trace their programs again and load them from the
    compilation cache. An xdist worker, holding about half the suite's
    programs, stays below.
    """
    if _MAP_LIMIT is None or (nextitem is not None and nextitem.path == item.path):
        return
    if _mappings() > 3 * _MAP_LIMIT // 4:
        jax.clear_caches()
        gc.collect()


# ------------------------------------------------------------ CPU-time record
#
# WMR_JAX_TEST_CPU=FILE appends one line per test to FILE, tab-separated: the
# file, the test, the CPU seconds of its process over its setup, call and
# teardown (XLA's threads included), those of the subprocesses it waited for,
# the wall seconds XLA's backend spent compiling for it, and the xdist worker
# that ran it ("-" without xdist). A loaded machine inflates wall time but
# hardly CPU time, so CPU time ranks the files (FILE_SECONDS), finds the slow
# tests and shows how evenly the workers were loaded.
_CPU_RECORD = os.environ.get("WMR_JAX_TEST_CPU")
_compile_seconds = [0.0]

if _CPU_RECORD:
    import time

    def _on_duration(event, seconds, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            _compile_seconds[0] += seconds

    jax.monitoring.register_event_duration_secs_listener(_on_duration)

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        start = time.process_time(), _children_seconds(), _compile_seconds[0]
        result = yield
        cpu = time.process_time() - start[0]
        children = _children_seconds() - start[1]
        compiled = _compile_seconds[0] - start[2]
        worker = os.environ.get("PYTEST_XDIST_WORKER", "-")
        line = (
            f"{item.path.name}\t{item.name}\t{cpu:.2f}\t{children:.2f}\t{compiled:.2f}\t{worker}\n"
        )
        with open(_CPU_RECORD, "a") as record:
            record.write(line)
        return result

    def _children_seconds():
        times = os.times()
        return times.children_user + times.children_system
