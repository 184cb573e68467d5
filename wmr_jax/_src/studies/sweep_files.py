"""The folder of a resumable sweep: its settings' fingerprint and one checked file per chunk.

A chunk is reused only when the fingerprint of the sweep's settings and the
digest of its own inputs match and its values are plausible.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from wmr_jax._src import io
from wmr_jax._src.provenance import code_version

if TYPE_CHECKING:
    from wmr_jax._src.studies.sweep import _Job

_MANIFEST = "sweep.json"
_RESULTS = "results.npz"


class OtherSettingsWarning(UserWarning):
    """A sweep's folder holds chunks of other settings: they are not used, and are replaced."""


def digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def tree_description(tree: Any) -> dict[str, Any]:
    """Scalars by value, batched leaves by shape and digest, static fields by ``repr``."""
    out: dict[str, Any] = {"type": type(tree).__name__}
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        arr = np.asarray(leaf)
        key = jax.tree_util.keystr(path) or "."
        out[key] = (
            float(arr) if arr.ndim == 0 else {"shape": list(arr.shape), "digest": digest(arr)}
        )
    if dataclasses.is_dataclass(tree):
        for field in dataclasses.fields(tree):
            if field.metadata.get("static"):
                out[f"static {field.name}"] = repr(getattr(tree, field.name))
    return out


def settings(job: _Job) -> dict[str, Any]:
    """Everything but the reference poses that decides a chunk's results."""
    chosen = ("steps", "velocity", "controller", "temperature", "substeps", "wheel_limit")
    options = {name: getattr(job.options, name) for name in chosen}
    _, gains, init, robot = job.inputs
    return {
        "n": job.n,
        "chunk": job.chunk,
        "dtype": job.dtype.name,
        "options": {**options, "controller": job.options.controller.name},
        "dt": job.dt,
        "gains": tree_description(gains),
        "robot": tree_description(robot),
        "init": "per pose" if np.ndim(init) == 2 else tree_description(init),
        "thresholds": [float(t) for t in job.thresholds],
        # A change of the code that computes (the law, a loop, a metric) must
        # not reuse old chunks, even under one version number.
        "version": code_version(),
    }


def fingerprint(settings: dict[str, Any]) -> str:
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# The metadata of every chunk file: the sweep's fingerprint and its poses' digest.
_CHUNK_META = ("fingerprint", "refs_digest")


def _metadata_fault(meta: Any) -> str | None:
    """What is wrong with a chunk's metadata, in a few words, or ``None`` if nothing is."""
    if not isinstance(meta, dict):
        return f"that is no JSON object ({json.dumps(meta)[:40]})"
    missing = [key for key in _CHUNK_META if not isinstance(meta.get(key), str)]
    return f"without a text {' or '.join(missing)}" if missing else None


class ChunkStore:
    """The folder of a resumable sweep: its settings, one checked file per chunk, the results."""

    def __init__(self, folder: Path, settings: dict[str, Any], fields: tuple[str, ...]):
        if folder.exists() and not folder.is_dir():
            raise ValueError(f"out = {str(folder)!r} is not allowed; allowed: a folder")
        folder.mkdir(parents=True, exist_ok=True)
        io.remove_stale_temporaries(folder)  # left by a sweep killed mid-write
        self.folder = folder
        self.fields = fields
        self.fingerprint = fingerprint(settings)
        self._warn_if_other(settings)
        io.atomic_write_json(folder / _MANIFEST, {"fingerprint": self.fingerprint, **settings})

    def _warn_if_other(self, settings: dict[str, Any]) -> None:
        """Say so when the folder's chunks are of other settings: none of them will be used."""
        try:
            before = json.loads((self.folder / _MANIFEST).read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            return
        chunks = len(list(self.folder.glob("chunk_*.npz")))
        if not isinstance(before, dict) or before.get("fingerprint") == self.fingerprint:
            return
        if chunks:
            now = json.loads(json.dumps(settings, default=str))
            changed = [k for k in settings if before.get(k) != now[k]]
            shown = ", ".join(
                f"{k} {before.get(k)!r} -> {settings[k]!r}"
                if k in ("n", "chunk", "dtype", "dt")
                else k
                for k in changed
            )
            warnings.warn(
                f"{self.folder} holds {chunks} chunk file(s) of a sweep with other settings "
                f"({shown or 'its fingerprint'}): none of them is used (a resume needs the "
                "same settings, chunk size and number of devices included)",
                OtherSettingsWarning,
                stacklevel=4,
            )

    def path(self, i: int) -> Path:
        return self.folder / f"chunk_{i:06d}.npz"

    def load(self, i: int, digest: str, size: int, job: _Job) -> dict[str, np.ndarray] | None:
        """Chunk ``i``'s results if its file is intact and was made from these inputs.

        A damaged or altered file is not used, with a one-line warning.
        """
        try:
            values, meta = io.load_arrays(self.path(i))
        except FileNotFoundError:
            return None
        except io.DamagedFileError as err:
            warnings.warn(f"{' '.join(str(err).split())}; recomputing that chunk", stacklevel=4)
            return None
        fault = _metadata_fault(meta)
        if fault is not None:  # a valid checksum over metadata this sweep never writes
            warnings.warn(
                f"{self.path(i)} has metadata {fault}; allowed: an object with "
                f"{' and '.join(_CHUNK_META)}; recomputing it",
                stacklevel=4,
            )
            return None
        if meta["fingerprint"] != self.fingerprint or meta["refs_digest"] != digest:
            return None
        if set(values) != set(self.fields) or any(v.shape != (size,) for v in values.values()):
            warnings.warn(f"{self.path(i)} has unexpected contents; recomputing it", stacklevel=4)
            return None
        why = implausible(job, values)
        if why is not None:
            # Written with a valid checksum but not by this sweep's arithmetic.
            warnings.warn(f"{self.path(i)} holds {why}; recomputing it", stacklevel=4)
            return None
        return values

    def save(self, i: int, digest: str, values: dict[str, np.ndarray]) -> None:
        meta = {"fingerprint": self.fingerprint, "refs_digest": digest}
        io.save_arrays(self.path(i), values, meta)

    def save_results(self, results: dict[str, np.ndarray]) -> None:
        io.save_arrays(self.folder / _RESULTS, results, {"fingerprint": self.fingerprint})


def implausible(job: _Job, values: dict[str, np.ndarray]) -> str | None:
    """Why a chunk read back cannot be this sweep's result, or ``None`` if it can be."""
    pose = np.stack([values[name] for name in ("final_x", "final_y", "final_theta")], axis=1)
    if not np.isfinite(pose).all():
        return "a final pose that is not finite"
    arrival, dt = values["arrival_time"], float(job.dt)
    finite = np.isfinite(arrival)
    periods = arrival[finite] / dt
    # (k + 1) dt in the compute dtype: float32 rounds it by ~1e-7 relative.
    whole = np.abs(periods - np.round(periods)) <= 1e-3 + 1e-5 * periods
    in_horizon = (periods >= 1 - 1e-3) & (periods <= job.options.steps + 1e-3)
    if np.isnan(arrival).any() or np.isneginf(arrival).any() or not (whole & in_horizon).all():
        return "an arrival time that is no whole number of periods within the horizon"
    if not np.array_equal(values["success"].astype(bool), finite):
        return "success flags that disagree with its arrival times"
    for name in ("path_length", "peak_wheel_speed", "zigzags"):
        value = values[name]
        if not (np.isfinite(value) & (value >= 0)).all():
            return f"a {name} that is negative or not finite"
    return None
