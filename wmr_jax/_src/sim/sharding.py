"""Spread a batch of runs over devices, and over hosts, with JAX sharding.

The batch entry points take ``jax.Array`` inputs sharded along their batch
axis and return results sharded alike, each device simulating its own rows:

>>> batch = shard(refs)                      # over all devices
>>> final = final_poses(batch.array)[: batch.n]

``shard`` pads the batch axis with copies of the last row to a multiple of
the device count; ``[: batch.n]`` or ``unpad`` drops them. Several hosts:
docs/scale.md.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.checks import check_int

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
    """Split the CPU into ``count`` JAX devices; return the local count.

    Takes effect only before JAX has started; no effect on accelerators.

    Args:
        count: devices to make; default twice the number of cores this
            process may use.
    """
    if count is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cores = os.cpu_count() or 1
        count = 2 * cores
    # Each device holds threads and buffers: far beyond the cores it only slows the start.
    count = check_int("count", count, 1, MAX_CPU_DEVICES)
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except (RuntimeError, AttributeError):  # JAX is up already, or has no such option
        pass
    return len(jax.local_devices())


def checked_devices(devices: Sequence[Any]) -> list[Any]:
    """Return ``devices`` as a list; ``ValueError`` for none, a non-device or a repeat."""
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
        batch: an ``(N, ...)`` array (or nested list of numbers), or a
            pytree of arrays of one leading length ``N``.
        devices: in order; default ``jax.devices()`` (every device of every
            process). With several processes, every process passes the same ``batch``.

    Returns:
        ``ShardedBatch(array, n)``, ``array`` padded to ``ceil(N / D) · D`` rows.

    Raises:
        ValueError: if the leaves do not share one leading length ``N ≥ 1``.
    """
    devices = checked_devices(jax.devices() if devices is None else devices)
    mesh = jax.sharding.Mesh(np.asarray(devices), (BATCH_AXIS,))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(BATCH_AXIS))
    count = len(devices)
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
    """Read a list as rows of one batch (numbers), or as a pytree of batches (arrays)."""
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
