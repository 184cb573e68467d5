"""Final poses and SPEC §6 metrics for millions of poses, in bounded memory.

``sweep(refs, gains, ...)`` runs the closed loop for every reference pose and
returns, per pose, the final pose and the metrics of SPEC §6: arrival time,
success, path length, peak wheel speed and zig-zag count. The metrics are
streamed through the time loop (``simulation.scan_closed_loop`` with a fold),
so no trajectory is ever stored, and the poses are processed in chunks of a
fixed size, so device memory does not grow with ``N`` and one compiled program
serves every chunk. Each chunk is spread over all local devices.

With ``out=DIR`` every finished chunk is written to ``DIR`` atomically as soon
as it is done, with a fingerprint of the settings and of its reference poses;
a later call with the same arguments and ``resume=True`` (the default) loads
the finished chunks instead of recomputing them, so an interrupted sweep loses
nothing it had finished. Host memory holds the inputs and the results (about
30 bytes per pose in float32) and little else; ``refs`` may be a NumPy memmap.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import metrics, simulation
from wmr_jax.controllers import SHIM_SUNG, Controller
from wmr_jax.io import atomic_write_json
from wmr_jax.params import Robot

__all__ = ["DEFAULT_CHUNK_SIZE", "FIELDS", "sweep"]

DEFAULT_CHUNK_SIZE = 131_072

FIELDS = (
    "final_x",
    "final_y",
    "final_theta",
    "arrival_time",
    "success",
    "path_length",
    "peak_wheel_speed",
    "zigzags",
)
"""Keys of the dict ``sweep`` returns, each an ``(N,)`` array:

* ``final_x``, ``final_y`` (cm), ``final_theta`` (rad, not wrapped): the pose
  after the last period;
* ``arrival_time``: s, ``inf`` where the robot is not arrived at the end
  (SPEC §6, as ``metrics.arrival_time``);
* ``success``: bool, ``arrival_time`` is finite;
* ``path_length``: cm, as ``metrics.path_length``;
* ``peak_wheel_speed``: cm/s, the largest ``|v_L|``, ``|v_R|`` over the run;
* ``zigzags``: int32, as ``metrics.zigzag_count``.
"""

_MANIFEST = "sweep.json"
_RESULTS = "results.npz"


class Thresholds(NamedTuple):
    """The metrics' tolerances (traced, so changing them does not recompile)."""

    tol_r: jax.Array
    tol_theta: jax.Array
    v_dead_band: jax.Array
    omega_dead_band: jax.Array


class _Streamed(NamedTuple):
    """What each run accumulates over its periods instead of its trajectory."""

    step: jax.Array  # index of the period just finished
    settled_from: jax.Array  # first sample of the final run of arrived samples
    path: jax.Array
    peak: jax.Array
    last_v: jax.Array  # last non-zero sign of v beyond its dead band
    last_omega: jax.Array
    zigzags: jax.Array


def _sign(x: jax.Array, dead_band: jax.Array) -> jax.Array:
    return jnp.where(x > dead_band, 1, jnp.where(x < -dead_band, -1, 0)).astype(jnp.int32)


def _flips(sign: jax.Array, last: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Return ``(new last sign, 1 if this sample flips the sign else 0)`` (SPEC §6)."""
    flipped = (sign != 0) & (last != 0) & (sign != last)
    return jnp.where(sign != 0, sign, last), flipped.astype(jnp.int32)


def _sweep_one(ref, params, init, robot, dt, options: simulation.Options):
    """Return the final pose and the streamed metrics of one run (single pose)."""
    gains, thresholds = params
    steps = options.steps

    def fold(acc: _Streamed, pose: jax.Array, out: simulation.StepOutput) -> _Streamed:
        ok = metrics.arrived(pose, ref, tol_r=thresholds.tol_r, tol_theta=thresholds.tol_theta)
        # The final run of arrived samples starts at the first arrived sample
        # after the last one that was not (SPEC §6); `steps` marks "not arrived".
        settled_from = jnp.where(ok, jnp.minimum(acc.settled_from, acc.step), steps)
        last_v, flip_v = _flips(_sign(out.v, thresholds.v_dead_band), acc.last_v)
        last_w, flip_w = _flips(_sign(out.omega, thresholds.omega_dead_band), acc.last_omega)
        return _Streamed(
            step=acc.step + 1,
            settled_from=settled_from,
            path=acc.path + out.distance,
            # Two wheels: an elementwise maximum, not a reduction (XLA would
            # run a reduction over a length-2 axis as a slow library call).
            peak=jnp.maximum(
                acc.peak,
                jnp.maximum(jnp.abs(out.wheel_speeds[0]), jnp.abs(out.wheel_speeds[1])),
            ),
            last_v=last_v,
            last_omega=last_w,
            zigzags=acc.zigzags + flip_v + flip_w,
        )

    zero_i = jnp.zeros((), jnp.int32)
    zero_f = jnp.zeros((), init.dtype)
    acc = _Streamed(zero_i, zero_i + steps, zero_f, zero_f, zero_i, zero_i, zero_i)
    final, acc, _ = simulation.scan_closed_loop(
        ref, gains, init, robot, dt, options, fold=fold, acc=acc
    )
    arrival = jnp.where(
        acc.settled_from < steps, (acc.settled_from + 1).astype(dt.dtype) * dt, jnp.inf
    )
    return {
        "final_x": final[0],
        "final_y": final[1],
        "final_theta": final[2],
        "arrival_time": arrival,
        "success": acc.settled_from < steps,
        "path_length": acc.path,
        "peak_wheel_speed": acc.peak,
        "zigzags": acc.zigzags,
    }


_sweep_jit = simulation.EntryJit(simulation.batched(_sweep_one), static_argnames=("options",))


# ---------------------------------------------------------------- inputs


@dataclasses.dataclass(frozen=True)
class _Plan:
    """How a sweep is cut into chunks and placed on devices."""

    n: int
    chunk: int
    devices: tuple[Any, ...]

    @property
    def chunks(self) -> int:
        return math.ceil(self.n / self.chunk)

    def bounds(self, i: int) -> tuple[int, int]:
        return i * self.chunk, min(self.n, (i + 1) * self.chunk)


def _check_refs(refs: Any) -> int:
    shape = getattr(refs, "shape", None)
    if shape is None:
        refs = np.asarray(refs)
        shape = refs.shape
    if len(shape) != 2 or shape[1] != 3 or shape[0] < 1:
        raise ValueError(
            f"refs has shape {tuple(shape)}; allowed: (N, 3) with N >= 1 [x cm, y cm, theta rad]"
        )
    return int(shape[0])


def _check_positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= 1")
    return int(value)


def _check_number(
    name: str, value: Any, *, low: float, high: float = math.inf, closed: bool = False
) -> float:
    """Return ``value`` as a float in ``(low, high)`` (``[low, high)`` if ``closed``)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    above = number >= low if closed else number > low
    if not (above and number < high):
        sign = ">=" if closed else ">"
        allowed = f"{name} {sign} {low}" + (f" and < {high:.6g}" if math.isfinite(high) else "")
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: {allowed}")
    return number


def _batched_leaves(tree: Any, n: int) -> Any:
    """Map each leaf to True if it carries the batch axis ``(n, ...)``."""
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


def _fingerprint(settings: dict[str, Any]) -> str:
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def _tree_description(tree: Any) -> dict[str, Any]:
    """Scalars by value, batched leaves by shape and digest (for the fingerprint)."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        arr = np.asarray(leaf)
        key = jax.tree_util.keystr(path) or "."
        out[key] = (
            float(arr) if arr.ndim == 0 else {"shape": list(arr.shape), "digest": _digest(arr)}
        )
    return out


# ---------------------------------------------------------------- chunk files


def _chunk_path(out: Path, i: int) -> Path:
    return out / f"chunk_{i:06d}.npz"


def _save_npz(path: Path, **arrays: Any) -> None:
    """Write an ``.npz`` through a temporary file and an atomic rename.

    Streamed to disk rather than built in memory: the final results of a
    10⁷-pose sweep are hundreds of megabytes.
    """
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _save_chunk(path: Path, fingerprint: str, refs_digest: str, values: dict) -> None:
    _save_npz(path, fingerprint=fingerprint, refs_digest=refs_digest, **values)


def _load_chunk(path: Path, fingerprint: str, refs_digest: str, size: int) -> dict | None:
    """Return the chunk's results if the file is there and was made with these inputs."""
    try:
        with np.load(path) as data:
            if str(data["fingerprint"]) != fingerprint or str(data["refs_digest"]) != refs_digest:
                return None
            values = {name: data[name] for name in FIELDS}
    except (OSError, KeyError, ValueError):
        return None
    if any(v.shape != (size,) for v in values.values()):
        return None
    return values


# ---------------------------------------------------------------- the sweep


def sweep(
    refs: Any,
    gains: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = simulation.DEFAULT_DT,
    steps: int = simulation.DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Controller | str = SHIM_SUNG,
    temperature: float | None = None,
    substeps: int = simulation.DEFAULT_SUBSTEPS,
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
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``: a NumPy
            array, a memmap (read a chunk at a time) or a ``jax.Array``.
        gains: the controller's parameters (default: its defaults); leaves
            scalar, or ``(N,)`` for one value per pose.
        init: ``(3,)`` initial pose, or ``(N, 3)``.
        dt: control period, s.
        steps: control periods per run (static).
        robot: robot parameters (leaves scalar or ``(N,)``); default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (SPEC §4).
        controller: a ``Controller`` or its name; default Shim–Sung.
        temperature: ``None`` for the hard law, else its smooth relaxation.
        substeps: inner steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` or ``"scale"`` (non-ideal loop).
        tol_r: arrival distance tolerance, cm (SPEC §6).
        tol_theta: arrival heading tolerance, rad, ``< π/2``.
        v_dead_band: speeds with ``|v| ≤`` this (cm/s) carry no sign (zig-zags).
        omega_dead_band: turn rates with ``|ω| ≤`` this (rad/s) carry no sign.
        chunk_size: poses per chunk, rounded up to a multiple of the number
            of devices; the last chunk is padded to the same size.
        devices: devices each chunk is spread over; default all local ones.
        out: folder for the per-chunk files (written atomically as each chunk
            finishes), the settings (``sweep.json``) and, at the end, all
            results (``results.npz``); ``None`` keeps everything in memory.
        resume: with ``out``, load the chunks already finished with the same
            settings and reference poses instead of recomputing them.
        progress: show a tqdm progress bar over the chunks.
        on_chunk: called as ``on_chunk(done, total)`` after every chunk.

    Returns:
        A dict of ``(N,)`` NumPy arrays keyed by ``FIELDS``.

    Raises:
        ValueError: naming the argument, its value and what is allowed,
            before anything is traced.
    """
    n = _check_refs(refs)
    options = simulation.make_options(
        steps=steps,
        velocity=velocity,
        controller=controller,
        temperature=temperature,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )
    chunk_size = _check_positive_int("chunk_size", chunk_size)
    thresholds = Thresholds(
        tol_r=_check_number("tol_r", tol_r, low=0.0),
        tol_theta=_check_number("tol_theta", tol_theta, low=0.0, high=math.pi / 2),
        v_dead_band=_check_number("v_dead_band", v_dead_band, low=0.0, closed=True),
        omega_dead_band=_check_number("omega_dead_band", omega_dead_band, low=0.0, closed=True),
    )
    devices = tuple(jax.local_devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices = () is not allowed; allowed: at least one device")
    chunk = math.ceil(min(chunk_size, n) / len(devices)) * len(devices)
    plan = _Plan(n=n, chunk=chunk, devices=devices)

    # Check gains, robot, dt and init on a one-pose sample of the batch first:
    # every message then names the bad field before any chunk is traced.
    control = options.controller
    gains = control.default_params() if gains is None else gains
    robot = Robot() if robot is None else robot
    init_arr = np.asarray(init, dtype=float) if not isinstance(init, jax.Array) else init
    batched_init = np.ndim(init_arr) == 2
    if batched_init and np.shape(init_arr)[0] != n:
        raise ValueError(f"init has shape {np.shape(init_arr)}; allowed: (3,) or ({n}, 3)")
    gains_mask = _batched_leaves(gains, n)
    robot_mask = _batched_leaves(robot, n)
    simulation.prepare(
        np.asarray(refs[:1], dtype=float),
        _take(gains, gains_mask, 0, 1, 0),
        init_arr[:1] if batched_init else init_arr,
        _take(robot, robot_mask, 0, 1, 0),
        dt,
        options,
        batch=None,
    )
    dtype = np.dtype(simulation.float_dtype())

    settings = {
        "n": n,
        "chunk": chunk,
        "dtype": dtype.name,
        "options": {
            "steps": options.steps,
            "velocity": options.velocity,
            "controller": options.controller.name,
            "temperature": options.temperature,
            "substeps": options.substeps,
            "wheel_limit": options.wheel_limit,
        },
        "dt": float(dt),
        "gains": _tree_description(gains),
        "robot": _tree_description(robot),
        "init": _tree_description(init_arr) if not batched_init else "per pose",
        "thresholds": [float(t) for t in thresholds],
    }
    fingerprint = _fingerprint(settings)
    folder = None if out is None else Path(out)
    if folder is not None:
        if folder.exists() and not folder.is_dir():
            raise ValueError(f"out = {str(folder)!r} is not allowed; allowed: a folder")
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_json(folder / _MANIFEST, {"fingerprint": fingerprint, **settings})

    mesh = jax.sharding.Mesh(np.asarray(devices), ("batch",))
    spread = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    shared = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())

    def place(tree: Any, mask: Any) -> Any:
        return jax.tree.map(
            lambda leaf, batched: jax.device_put(
                np.asarray(leaf, dtype), spread if batched else shared
            ),
            tree,
            mask,
        )

    results = {
        name: np.empty(
            n, dtype=bool if name == "success" else np.int32 if name == "zigzags" else dtype
        )
        for name in FIELDS
    }

    def chunk_inputs(i: int):
        lo, hi = plan.bounds(i)
        pad = plan.chunk - (hi - lo)
        chunk_refs = _take(refs, True, lo, hi, pad)
        chunk_init = _take(init_arr, True, lo, hi, pad) if batched_init else init_arr
        per_pose = [chunk_refs, chunk_init if batched_init else np.zeros(0)]
        for tree, mask in ((gains, gains_mask), (robot, robot_mask)):
            per_pose += jax.tree.leaves(_take(tree, mask, lo, hi, pad))
        return lo, hi, pad, chunk_refs, chunk_init, _digest(*per_pose)

    def launch(i: int, chunk_refs, chunk_init, lo: int, hi: int, pad: int):
        params = (_take(gains, gains_mask, lo, hi, pad), thresholds)
        params_mask = (gains_mask, Thresholds(False, False, False, False))
        return _sweep_jit(
            place(chunk_refs, True),
            place(params, params_mask),
            place(chunk_init, batched_init),
            place(_take(robot, robot_mask, lo, hi, pad), robot_mask),
            jax.device_put(np.asarray(dt, dtype), shared),
            options=options,
        )

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=plan.chunks, unit="chunk", desc=f"sweep {n} poses")

    def finish(i: int, lo: int, hi: int, digest: str, values: dict) -> None:
        host = {name: np.asarray(values[name])[: hi - lo] for name in FIELDS}
        for name in FIELDS:
            results[name][lo:hi] = host[name]
        if folder is not None:
            _save_chunk(_chunk_path(folder, i), fingerprint, digest, host)
        if bar is not None:
            bar.update(1)
        if on_chunk is not None:
            on_chunk(i + 1, plan.chunks)

    # One chunk in flight while the previous one is copied back and saved:
    # JAX dispatches asynchronously, so the host work overlaps the next chunk.
    pending = None
    try:
        for i in range(plan.chunks):
            lo, hi, pad, chunk_refs, chunk_init, digest = chunk_inputs(i)
            if folder is not None and resume:
                loaded = _load_chunk(_chunk_path(folder, i), fingerprint, digest, hi - lo)
                if loaded is not None:
                    for name in FIELDS:
                        results[name][lo:hi] = loaded[name]
                    if bar is not None:
                        bar.update(1)
                    if on_chunk is not None:
                        on_chunk(i + 1, plan.chunks)
                    continue
            bad = ~np.isfinite(chunk_refs[: hi - lo]).all(axis=1)
            if bad.any():
                row = lo + int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"refs[{row}] = {np.asarray(refs[row]).tolist()} is not finite; "
                    "allowed: finite numbers"
                )
            launched = (i, lo, hi, digest, launch(i, chunk_refs, chunk_init, lo, hi, pad))
            if pending is not None:
                finish(*pending)
            pending = launched
        if pending is not None:
            finish(*pending)
            pending = None
    finally:
        if bar is not None:
            bar.close()
    if folder is not None:
        _save_npz(folder / _RESULTS, **results)
    return results
