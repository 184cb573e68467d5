"""Final poses and docs/model.md §6 metrics for millions of poses, in bounded memory.

The metrics are streamed through the time loop (no trajectory is stored); the
poses run in chunks of one size spread over the local devices, so one compiled
program serves every chunk. With ``out=DIR`` finished chunks are kept
(``sweep_files.ChunkStore``) and a resumed sweep reuses them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model.controllers import SHIM_SUNG, Controller
from wmr_jax._src.model.controllers.base import require_pytree
from wmr_jax._src.model.params import Robot, validate_robot
from wmr_jax._src.sim import loops, metrics
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.sharding import checked_devices
from wmr_jax._src.studies import sweep_files as files

DEFAULT_CHUNK_SIZE = 131_072


SWEEP_FIELDS = (
    "final_x",
    "final_y",
    "final_theta",
    "arrival_time",
    "success",
    "path_length",
    "peak_wheel_speed",
    "zigzags",
)
"""Keys of the dict ``sweep`` returns, each ``(N,)``: the final pose (cm, cm, rad
unwrapped) and the docs/model.md §6 metrics (``arrival_time`` s, ``inf`` if not
arrived; ``success``; ``path_length`` cm; ``peak_wheel_speed`` cm/s; ``zigzags``).
"""


def _sweep_one(ref, params, init, robot, dt, options: loops.Options):
    """The final pose and the streamed metrics of one run (single pose)."""
    gains, thresholds = params

    def fold(acc, pose, out):
        return metrics.stream_update(acc, pose.stacked(), ref, out, thresholds, frame=pose.frame())

    acc = metrics.stream_start(init.dtype)
    final, acc, _ = loops.scan_closed_loop(ref, gains, init, robot, dt, options, fold=fold, acc=acc)
    result = metrics.stream_result(acc, dt)
    return {
        "final_x": final[0],
        "final_y": final[1],
        "final_theta": final[2],
        **{name: result[name] for name in SWEEP_FIELDS[3:]},
    }


_sweep_jit = loops.EntryJit(loops.batched(_sweep_one), static_argnames=("options",))


@dataclasses.dataclass(frozen=True)
class _Job:
    """A checked sweep: its inputs ``(refs, gains, init, robot)``, options and chunks.

    ``mask`` is ``inputs``' tree of bools: which leaves have one row per run.
    """

    inputs: tuple[Any, Any, Any, Any]
    mask: tuple[Any, Any, Any, Any]
    n: int
    dt: float
    options: loops.Options
    thresholds: metrics.Thresholds
    dtype: np.dtype
    chunk: int
    devices: tuple[Any, ...]

    @property
    def chunks(self) -> int:
        return math.ceil(self.n / self.chunk)


def _per_run_or_shared(tree: Any, n: int, name: str) -> Any:
    """Leaves with one value per run stay, a batch axis of size 1 is dropped, others refused."""

    def leaf_of(path, leaf):
        field = f"{name}{jax.tree_util.keystr(path, simple=True, separator='.')}"
        if checks.array_kind(leaf) not in "iuf":  # named whole, not as the one-row sample
            raise ValueError(
                f"{field} = {checks.described(leaf)} is not allowed; allowed: finite numbers"
            )
        if np.ndim(leaf) == 0 or np.shape(leaf)[0] == n:
            return leaf
        if np.shape(leaf)[0] == 1:
            return leaf[0]
        raise ValueError(
            f"{field} has {np.shape(leaf)[0]} values; allowed: one, or one per reference ({n})"
        )

    return jax.tree_util.tree_map_with_path(leaf_of, tree)


def _batched_leaves(tree: Any, n: int) -> Any:
    return jax.tree.map(lambda leaf: np.ndim(leaf) >= 1 and np.shape(leaf)[0] == n, tree)


def _take(tree: Any, mask: Any, lo: int, hi: int, pad: int) -> Any:
    """Slice the batched leaves of ``tree`` to rows ``lo:hi``, padded by repeating the last."""

    def cut(leaf, batched):
        if not batched:
            return leaf
        part = np.asarray(leaf[lo:hi])
        if pad:
            part = np.concatenate([part, np.repeat(part[-1:], pad, axis=0)])
        return part

    return jax.tree.map(cut, tree, mask)


def _check(refs, gains, init, robot, dt, options, thresholds, chunk_size, devices) -> _Job:
    """Check every input (on a one-pose sample of the batch) and plan the chunks."""
    if isinstance(refs, (list, tuple)):  # lists work as arrays (a memmap stays as it is)
        refs = checks.real_array("refs", refs, "rows of real numbers [x cm, y cm, θ rad]")
    # N from the shape alone: a memmap stays on disk.
    shape = np.shape(refs) if getattr(refs, "shape", None) is None else refs.shape
    if len(shape) != 2 or shape[1] != 3 or shape[0] < 1:
        raise ValueError(
            f"refs has shape {tuple(shape)}; allowed: (N, 3) with N >= 1 [x cm, y cm, theta rad]"
        )
    n = int(shape[0])
    chunk_size = checks.check_int("chunk_size", chunk_size)
    devices = tuple(checked_devices(jax.local_devices() if devices is None else devices))
    gains = options.controller.default_params() if gains is None else gains
    require_pytree(f"controller {options.controller.name!r}", gains)
    robot = Robot() if robot is None else robot
    if not isinstance(init, jax.Array):
        init = checks.real_array("init", init, "real numbers [x cm, y cm, θ rad], (3,) or (N, 3)")
    if n == 1:  # one reference shared by every run of batched parameters
        runs = checks.common_batch_size({"gains": gains, "robot": robot}, {"init": init})
        refs, n = (np.repeat(np.asarray(refs[:1]), runs, axis=0), runs) if runs > 1 else (refs, 1)
    if n > 1:
        gains = _per_run_or_shared(gains, n, "gains.")
        robot = _per_run_or_shared(robot, n, "robot.")
    if np.ndim(init) == 2 and np.shape(init)[0] == 1:
        init = init[0]  # one start shared by every run
    batched_init = np.ndim(init) == 2
    if batched_init and np.shape(init)[0] != n:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,), (1, 3) or ({n}, 3)")
    inputs = (refs, gains, init, robot)
    mask = (True, _batched_leaves(gains, n), batched_init, _batched_leaves(robot, n))
    _, gains_1, init_1, robot_1 = _take(inputs, mask, 0, 1, 0)
    refs_1 = np.asarray(refs[:1], dtype=float)
    simulation.prepare(refs_1, gains_1, init_1, robot_1, dt, options, batch=None)
    return _Job(
        inputs=inputs,
        mask=mask,
        n=n,
        dt=float(dt),
        options=loops.for_robot(options, robot, dt),
        thresholds=thresholds,
        dtype=np.dtype(checks.float_dtype()),
        chunk=math.ceil(min(chunk_size, n) / len(devices)) * len(devices),
        devices=devices,
    )


@dataclasses.dataclass(frozen=True)
class _Chunk:
    """Chunk ``i``: rows ``lo:hi`` of the job's inputs, padded by ``pad`` copies of the last."""

    i: int
    lo: int
    hi: int
    pad: int
    inputs: tuple[Any, Any, Any, Any]


def _chunk_inputs(job: _Job, i: int) -> _Chunk:
    lo, hi = i * job.chunk, min(job.n, (i + 1) * job.chunk)
    pad = job.chunk - (hi - lo)
    return _Chunk(i, lo, hi, pad, _take(job.inputs, job.mask, lo, hi, pad))


def _chunk_digest(job: _Job, chunk: _Chunk) -> str:
    """The digest of everything per pose in a chunk (what a stored chunk is matched by)."""
    refs, gains, init, robot = chunk.inputs
    per_pose = [refs, init if job.mask[2] else np.zeros(0)]
    return files.digest(*per_pose, *jax.tree.leaves(gains), *jax.tree.leaves(robot))


def _check_chunk(job: _Job, chunk: _Chunk) -> None:
    """Check every row of a chunk as ``final_poses`` checks a batch (rows of the whole batch)."""
    size = chunk.hi - chunk.lo
    refs, gains, init, robot = chunk.inputs
    _, gains_mask, batched_init, robot_mask = job.mask
    try:
        checks.as_poses("refs", np.asarray(refs[:size]), batch=True, check_only=True)
        if batched_init:
            checks.as_poses("init", np.asarray(init[:size]), batch=True, check_only=True)
    except ValueError as err:  # "refs[3] = ..." of the chunk is row lo + 3 of the batch
        row = r"^(refs|init)\[(\d+)\]"
        text = re.sub(row, lambda m: f"{m[1]}[{chunk.lo + int(m[2])}]", str(err))
        raise ValueError(text) from None
    try:
        if any(jax.tree.leaves(gains_mask)):
            job.options.controller.validate(_take(gains, gains_mask, 0, size, 0))
        if any(jax.tree.leaves(robot_mask)):
            validate_robot(_take(robot, robot_mask, 0, size, 0))
    except ValueError as err:
        raise ValueError(f"{err} (among runs {chunk.lo} to {chunk.hi - 1})") from None


def _launcher(job: _Job) -> Callable[[_Chunk], Any]:
    """``launch(chunk)``: place a chunk on the devices and dispatch it (asynchronously)."""
    mesh = jax.sharding.Mesh(np.asarray(job.devices), ("batch",))
    spread = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    shared = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())

    def put(leaf: Any, batched: bool = False) -> jax.Array:
        return jax.device_put(np.asarray(leaf, job.dtype), spread if batched else shared)

    thresholds = jax.tree.map(put, job.thresholds)

    def launch(chunk: _Chunk) -> Any:
        refs, gains, init, robot = jax.tree.map(put, chunk.inputs, job.mask)
        dt = put(job.dt)
        return _sweep_jit(refs, (gains, thresholds), init, robot, dt, options=job.options)

    return launch


def _run_chunks(
    job: _Job,
    results: dict[str, np.ndarray],
    store: files.ChunkStore | None,
    resume: bool,
    done: Callable[[int], None],
) -> None:
    """Fill ``results`` chunk by chunk, loading finished ones if ``resume``."""
    launch = _launcher(job)

    def keep(chunk: _Chunk, digest: str | None, values: dict[str, Any], *, computed: bool) -> None:
        host = {name: np.asarray(values[name])[: chunk.hi - chunk.lo] for name in SWEEP_FIELDS}
        if computed:  # as final_poses does, raise if a run left the floating-point range
            finite = np.all([np.isfinite(host[name]) for name in SWEEP_FIELDS[:3]], axis=0)
            checks.require_finite_runs(finite, job.dtype, first=chunk.lo)
        for name in SWEEP_FIELDS:
            results[name][chunk.lo : chunk.hi] = host[name]
        if computed and store is not None:
            store.save(chunk.i, digest, host)
        done(chunk.i)

    pending = None
    for i in range(job.chunks):
        chunk = _chunk_inputs(job, i)
        digest = None if store is None else _chunk_digest(job, chunk)
        loaded = store.load(i, digest, chunk.hi - chunk.lo, job) if store and resume else None
        if loaded is not None:
            keep(chunk, digest, loaded, computed=False)
            continue
        _check_chunk(job, chunk)
        launched = (chunk, digest, launch(chunk))
        if pending is not None:
            keep(*pending, computed=True)
        pending = launched
    if pending is not None:
        keep(*pending, computed=True)


@contextlib.contextmanager
def _progress(job: _Job, bar: bool, on_chunk: Callable[[int, int], None] | None):
    """Yield ``done(i)``, called as chunk ``i`` is done: it moves the bar, calls ``on_chunk``."""
    shown = None
    if bar:
        from wmr_jax._src.report.progress import bar as tqdm

        name = job.options.controller.name
        shown = tqdm(total=job.chunks, unit="chunk", desc=f"{name} sweep, {job.n} poses")

    def done(i: int) -> None:
        if shown is not None:
            shown.update(1)
        if on_chunk is not None:
            on_chunk(i + 1, job.chunks)

    try:
        yield done
    finally:
        if shown is not None:
            shown.close()


def sweep(
    refs: Any,
    gains: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = simulation.DEFAULT_DT,
    steps: int = loops.DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Controller | str = SHIM_SUNG,
    temperature: float | None = None,
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    tol_r: float = metrics.DEFAULT_TOL_R,
    tol_theta: float = metrics.DEFAULT_TOL_THETA,
    v_dead_band: float = 1.0,
    omega_dead_band: float = 0.1,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    devices: Sequence[Any] | None = None,
    out: str | Path | None = None,
    resume: bool = True,
    progress: bool = False,
    on_chunk: Callable[[int, int], None] | None = None,
) -> dict[str, np.ndarray]:
    """Run the closed loop for every reference pose; return final poses and metrics.

    Args:
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``: an array,
            or a memmap (read a chunk at a time).
        gains: the controller's parameters (default: its defaults); leaves
            scalar, or ``(N,)`` for one value per pose (the robot's too).
        init, dt, steps, robot, velocity, controller, temperature, substeps,
            wheel_limit: as ``wmr_jax.final_poses``; ``steps`` per run.
        tol_r: arrival distance tolerance, cm (docs/model.md §6).
        tol_theta: arrival heading tolerance, rad, ``< π/2``.
        v_dead_band: speeds with ``|v| ≤`` this (cm/s) carry no sign (zig-zags).
        omega_dead_band: turn rates with ``|ω| ≤`` this (rad/s) carry no sign.
        chunk_size: poses per chunk, rounded up to a multiple of the number
            of devices; the last chunk is padded to the same size.
        devices: devices each chunk is spread over; default all local ones.
        out: folder for the chunk files, the settings (``sweep.json``) and
            all results (``results.npz``); ``None`` keeps everything in memory.
        resume: with ``out``, load the chunks finished with the same settings
            and poses instead of computing them again.
        progress: show a tqdm progress bar over the chunks.
        on_chunk: called as ``on_chunk(done, total)`` after every chunk.

    Returns:
        A dict of ``(N,)`` NumPy arrays keyed by ``SWEEP_FIELDS``.
    """
    options = simulation.make_options(**simulation._static_options(locals()))
    thresholds = metrics.Thresholds(
        tol_r=checks.check_number("tol_r", tol_r, low=0.0, unit="cm"),
        tol_theta=checks.check_number("tol_theta", tol_theta, high=math.pi / 2, unit="rad"),
        v_dead_band=checks.check_number("v_dead_band", v_dead_band, closed=True, unit="cm/s"),
        omega_dead_band=checks.check_number(
            "omega_dead_band", omega_dead_band, closed=True, unit="rad/s"
        ),
    )
    checks.check_callable("on_chunk", on_chunk)
    checks.check_bool("resume", resume)
    checks.check_bool("progress", progress)
    out = None if out is None else checks.check_folder("out", out)
    checks.require_concrete("sweep", refs, gains, init, robot, dt)  # it runs chunk by chunk
    job = _check(refs, gains, init, robot, dt, options, thresholds, chunk_size, devices)
    store = None if out is None else files.ChunkStore(out, files.settings(job), SWEEP_FIELDS)
    kinds = {"success": bool, "zigzags": np.int32}
    results = {name: np.empty(job.n, dtype=kinds.get(name, job.dtype)) for name in SWEEP_FIELDS}
    with _progress(job, progress, on_chunk) as done:
        _run_chunks(job, results, store, resume, done)
    if store is not None:
        store.save_results(results)
    return results
