"""Spread a batch of runs over devices, and over hosts, with JAX sharding.

The batch entry points (``batch_rollout``, ``final_poses``) take
``jax.Array`` inputs sharded along their batch axis and return results
sharded the same way: each device simulates its own rows, with no
communication until the results are gathered. ``shard`` places a batch so:

>>> batch = shard(refs)                      # over all devices
>>> final = final_poses(batch.array)         # sharded (N_padded, 3)
>>> final = final[: batch.n]                 # drop the padding rows

The batch axis must divide evenly among the devices, so ``shard`` pads it
with copies of the last row up to a multiple of the device count; the padded
rows are ordinary runs whose results are simply dropped (``[: batch.n]``, or
``unpad``). Several arrays (reference poses, per-pose gains, initial poses)
can be sharded together as one pytree, so that they are padded alike.

On the CPU, one process sees one device unless told otherwise:
``use_cpu_devices(K)`` (or ``XLA_FLAGS=--xla_force_host_platform_device_count=K``),
before JAX starts, splits it into ``K`` devices, which is also faster (see
``use_cpu_devices``). Across hosts, start every process with
``jax.distributed.initialize(...)`` (see ``multihost_recipe``); ``jax.devices()``
then lists every device of every host, and ``shard`` with the default devices
builds one global array from the same host data given to every process.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.checks import check_int

__all__ = [
    "ShardedBatch",
    "batch_sharding",
    "checked_devices",
    "multihost_recipe",
    "shard",
    "unpad",
    "use_cpu_devices",
]

BATCH_AXIS = "batch"


class ShardedBatch(NamedTuple):
    """A batch placed across devices.

    Attributes:
        array: the sharded ``jax.Array`` (or pytree of them), leading axis
            padded to ``n_padded``, a multiple of the device count.
        n: the true batch size; ``result[:n]`` drops the padding.
    """

    array: Any
    n: int

    @property
    def n_padded(self) -> int:
        """Length of the leading axis after padding."""
        return int(jax.tree.leaves(self.array)[0].shape[0])


MAX_CPU_DEVICES = 1024


def use_cpu_devices(count: int | None = None) -> int:
    """Split the CPU into ``count`` JAX devices; return the number of local devices.

    XLA runs the kernels of one program one after another, so on the CPU one
    device leaves cores idle; a batch sharded over several CPU devices runs
    one stream of kernels per device, which the cores then share
    (``wmr-jax bench`` measures the gain). This only takes effect before JAX
    has started (no JAX computation yet in this process); later it changes
    nothing. It has no effect on accelerator backends.

    Args:
        count: devices to make; default twice the number of cores this
            process may use.

    Returns:
        ``len(jax.local_devices())`` after the call.
    """
    if count is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cores = os.cpu_count() or 1
        count = 2 * cores
    # Each device holds threads and buffers of its own: far beyond the cores it
    # only slows the start (100,000 of them did not start in minutes).
    count = check_int("count", count, 1, MAX_CPU_DEVICES)
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except (RuntimeError, AttributeError):  # JAX is up already, or has no such option
        pass
    return len(jax.local_devices())


def batch_sharding(devices: Sequence[Any] | None = None) -> jax.sharding.NamedSharding:
    """Return the sharding that splits an array's leading axis over ``devices``.

    Args:
        devices: devices in order; default ``jax.devices()`` (every device of
            every process).
    """
    devices = checked_devices(jax.devices() if devices is None else devices)
    mesh = jax.sharding.Mesh(np.asarray(devices), (BATCH_AXIS,))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(BATCH_AXIS))


def checked_devices(devices: Sequence[Any]) -> list[Any]:
    """Return ``devices`` as a list after checking each is a JAX device, once.

    Raises:
        ValueError: for none, something else than a device, or a repeat.
    """
    if isinstance(devices, (str, bytes, jax.Device)) or not hasattr(devices, "__iter__"):
        raise ValueError(
            f"devices = {devices!r} is not allowed; allowed: a sequence of JAX devices "
            "(jax.devices(), jax.local_devices())"
        )
    devices = list(devices)
    if not devices:
        raise ValueError("devices = [] is not allowed; allowed: at least one device")
    for device in devices:
        if not isinstance(device, jax.Device):
            raise ValueError(
                f"devices holds {device!r}; allowed: JAX devices "
                "(jax.devices(), jax.local_devices())"
            )
    if len(set(devices)) != len(devices):
        raise ValueError("devices names a device twice; allowed: each device once")
    return devices


def shard(batch: Any, devices: Sequence[Any] | None = None) -> ShardedBatch:
    """Place a batch across ``devices``, padding its leading axis to a multiple of their count.

    Args:
        batch: an ``(N, ...)`` array (e.g. reference poses ``(N, 3)``; a
            nested list of numbers reads as one), or a pytree of arrays that
            all have the same leading length ``N`` (a list of 1-D arrays is
            ambiguous, rows or batches, and refused).
        devices: default ``jax.devices()``. With several processes
            (``jax.distributed``), every process passes the same ``batch`` and
            places the rows that belong to its own devices.

    Returns:
        ``ShardedBatch(array, n)``: ``array`` has leading length
        ``n_padded = ceil(N / D) · D`` for ``D`` devices, its extra rows
        copies of row ``N − 1``; results computed from it are sharded alike,
        and ``result[:n]`` (or ``unpad(result, n)``) drops the padding.

    Raises:
        ValueError: if the leaves do not share one leading length ``N ≥ 1``.
    """
    sharding = batch_sharding(devices)
    count = len(sharding.mesh.devices.flat)
    if isinstance(batch, list):
        batch = _rows("batch", batch)
    leaves = jax.tree.leaves(batch)
    if not leaves:
        raise ValueError("batch is empty; allowed: an array or a pytree of arrays")
    lengths = {np.shape(leaf)[0] if np.ndim(leaf) >= 1 else None for leaf in leaves}
    if len(lengths) != 1 or None in lengths or 0 in lengths:
        raise ValueError(
            f"batch leaves have leading lengths {sorted(map(str, lengths))}; "
            "allowed: one common length N >= 1"
        )
    n = int(lengths.pop())
    padded = -(-n // count) * count

    def place(leaf: Any) -> jax.Array:
        host = np.asarray(leaf)
        if host.dtype.kind not in "biufc":
            raise ValueError(f"batch holds {host.dtype} values; allowed: numbers")
        if host.dtype.kind == "f" and not isinstance(leaf, jax.Array):
            checks.require("batch", host, np.isfinite(host), "finite numbers")
            checks.require_representable("batch", host, tiny_ok=True)
        if padded > n:
            host = np.concatenate([host, np.repeat(host[-1:], padded - n, axis=0)])
        if isinstance(leaf, jax.Array):
            host = host.astype(leaf.dtype)
        elif np.issubdtype(host.dtype, np.floating):
            host = host.astype(jax.numpy.result_type(float))
        return jax.device_put(host, sharding)

    return ShardedBatch(jax.tree.map(place, batch), n)


def _rows(name: str, batch: list) -> Any:
    """Read a list as rows of one batch (numbers), or as a pytree of batches (arrays).

    A list of one-dimensional arrays alone is both: ``[pose, pose]`` reads as
    two rows, or as two batches of 3. It is refused rather than guessed.
    """
    arrays = [isinstance(row, (np.ndarray, jax.Array)) for row in batch]
    if any(arrays):
        if all(arrays) and all(np.ndim(row) == 1 for row in batch):
            raise ValueError(
                f"{name} is a list of {len(batch)} one-dimensional arrays: rows of one batch, "
                f"or {len(batch)} batches? allowed: np.stack(rows) for one batch, or a tuple "
                "or dict of batches"
            )
        return batch  # a pytree of batches
    try:
        return np.asarray(batch)
    except ValueError:
        raise ValueError(
            f"{name} is a list of rows of different lengths; allowed: rows of one shape"
        ) from None


def unpad(result: Any, n: int) -> Any:
    """Return ``result`` (an array or pytree) without the rows ``shard`` added: ``[:n]``.

    Raises:
        ValueError: unless ``1 <= n <=`` the leading length of every leaf.
    """
    leaves = jax.tree.leaves(result)
    if not leaves or any(np.ndim(leaf) == 0 for leaf in leaves):
        raise ValueError(
            f"result = {result!r:.80} is not allowed; allowed: arrays (or a pytree of them) "
            "with a leading batch axis, as shard's batch gave"
        )
    shortest = min(np.shape(leaf)[0] for leaf in leaves)
    if shortest == 0:
        raise ValueError("result has no rows (a leading length of 0); allowed: shard's output")
    n = check_int("n", n, 1, shortest)
    return jax.tree.map(lambda leaf: leaf[:n], result)


def multihost_recipe() -> str:
    """Return the steps to run a batch over several hosts (also in the module docs)."""
    return """\
Multi-host runs (one process per host, or per accelerator):
1. Start the same script on every host with the same arguments, and in it,
   before any other JAX call:
       jax.distributed.initialize(coordinator_address="HOST0:PORT",
                                  num_processes=P, process_id=i)
   (on CPU hosts also: jax.config.update("jax_cpu_collectives_implementation",
   "gloo"); on SLURM, Cloud TPU or Kubernetes initialize() needs no arguments).
2. Build the same reference poses on every host (same seed or file) and call
   batch = wmr_jax.shard(refs): jax.devices() now lists the devices of
   every host, and each process places only the rows of its own devices.
3. Call wmr_jax.final_poses(batch.array, ...) (or batch_rollout) on every host:
   each device simulates its rows, with no communication between hosts.
4. Gather what you need: jax.experimental.multihost_utils.process_allgather(
   result)[:batch.n] on every host, or each process writes its own shards
   (result.addressable_shards) to shared storage.
"""
