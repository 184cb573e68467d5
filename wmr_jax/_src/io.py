"""Output files: atomic writes (no half-written file), checksummed arrays and records."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

_ERRNO = re.compile(r"\[Errno (\d+)\] ([^:]*)(: .*)?$")


def os_reason(text: Any) -> str:
    """An ``OSError``'s text in plain words (``there is no such file``), without the path."""
    text = " ".join(str(text).split())
    found = _ERRNO.search(text)
    if found is None:
        return text
    reason = {"2": "there is no such file", "21": "it is a folder"}.get(found[1])
    return text[: found.start()] + (reason or found[2][:1].lower() + found[2][1:])


def _write_atomically(path: str | os.PathLike, write: Callable[[Any], None]) -> Path:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it over ``path``."""
    if not isinstance(path, (str, os.PathLike)) or str(path) in ("", "."):
        raise ValueError(f"path = {path!r} is not allowed; allowed: a file path")
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path = {str(path)!r} is a folder; allowed: a file path")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp creates the file private (0600); give it the usual permissions.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def json_object_once(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``'s ``object_pairs_hook`` that refuses a key given twice."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} is given twice")
        out[key] = value
    return out


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValueError(
            f"data is a {type(data).__name__}; allowed: bytes (atomic_write_text writes a str)"
        )
    return _write_atomically(path, lambda f: f.write(data))


def atomic_write_npz(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write arrays as an ``.npz`` atomically, streamed to disk (not built in memory)."""
    return _write_atomically(path, lambda f: np.savez(f, **arrays))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically (bytes go to ``atomic_write_bytes``)."""
    if not isinstance(text, str):
        raise ValueError(f"text = {text!r:.80} is not allowed; allowed: a str")
    return atomic_write_bytes(path, text.encode("utf-8"))


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, float) and not (obj == obj and abs(obj) != float("inf")):
        return "nan" if obj != obj else ("inf" if obj > 0 else "-inf")
    if isinstance(obj, dict):
        out = {str(k): _jsonable(v) for k, v in obj.items()}
        if len(out) < len(obj):  # {1: a, "1": b} would keep only b
            keys = sorted(map(repr, obj))
            raise ValueError(f"keys {', '.join(keys)} collide as JSON names (str of each)")
        return out
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "tolist"):
        return _jsonable(obj.tolist())
    return obj


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as indented JSON atomically; ``inf`` and NaN become "inf" and "nan"."""
    return atomic_write_text(path, json_text(obj, "obj", indent=2, sort_keys=False) + "\n")


def json_text(obj: Any, name: str, **kwargs: Any) -> str:
    """``obj`` as JSON text, or a ``ValueError`` naming ``name`` and the value JSON cannot store."""
    try:
        return json.dumps(_jsonable(obj), allow_nan=False, **kwargs)
    except RecursionError:
        raise ValueError(
            f"{name} is not allowed: it contains itself, or nests too deeply for JSON; "
            "allowed: numbers, strings, bools, None, lists and dicts of them (JSON)"
        ) from None
    except (TypeError, ValueError) as err:
        raise ValueError(
            f"{name} = {obj!r:.200} is not allowed ({err}); allowed: numbers, strings, "
            "bools, None, lists and dicts of them (JSON)"
        ) from None


def save_figure(fig: Any, path: str | os.PathLike, **kwargs: Any) -> Path:
    """Render a matplotlib figure to ``path`` atomically, in the format its suffix names."""
    canvas = getattr(fig, "canvas", None)
    if not hasattr(canvas, "get_supported_filetypes"):
        raise ValueError(f"fig is a {type(fig).__name__}; allowed: a matplotlib Figure")
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        raise ValueError(f"path = {path!r} is not allowed; allowed: a file name (str or Path)")
    supported = canvas.get_supported_filetypes()
    fmt = Path(path).suffix.lstrip(".").lower()
    if fmt not in supported:
        raise ValueError(
            f"path = {os.fspath(path)!r} is not allowed; allowed: a path ending in "
            + ", ".join(f".{name}" for name in sorted(supported))
        )
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, **kwargs)
    return atomic_write_bytes(path, buffer.getvalue())


# ---------------------------------------------------------------- checked array files


class DamagedFileError(ValueError):
    """A results file that cannot be trusted: unreadable, truncated or altered."""


_META = "__meta__"
_CHECKSUM = "__sha256__"


def _checksum(arrays: dict[str, np.ndarray], meta_text: str) -> str:
    digest = hashlib.sha256(meta_text.encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()


def _checked_arrays(arrays: Any) -> dict[str, np.ndarray]:
    """``arrays`` as NumPy arrays that ``np.load(allow_pickle=False)`` reads back, or raise."""
    if not isinstance(arrays, Mapping):
        raise ValueError(
            f"arrays = {arrays!r:.80} is not allowed; allowed: a mapping of names to arrays"
        )
    out = {}
    for name, value in arrays.items():
        if not isinstance(name, str) or name in (_META, _CHECKSUM):
            raise ValueError(
                f"arrays name = {name!r} is not allowed; allowed: a str other than "
                f"{_META!r} and {_CHECKSUM!r}"
            )
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError):
            arr = np.asarray(None)  # ragged lists: named below, as an object array
        if arr.dtype.kind not in "biufcUSMm":
            raise ValueError(
                f"arrays[{name!r}] = {value!r:.80} is not allowed; allowed: an array of "
                "numbers, bools or strings (not objects: None, dicts, ragged lists)"
            )
        out[name] = arr
    return out


def save_arrays(path: str | os.PathLike, arrays: dict[str, Any], meta: dict[str, Any]) -> Path:
    """Write arrays and a JSON-able ``meta`` dict as a checksummed ``.npz``, atomically.

    Raises:
        ValueError: before writing, for arrays that are not numbers, bools or
            strings under str names, or a ``meta`` JSON cannot store.
    """
    arrays = _checked_arrays(arrays)
    meta_text = json_text(meta, "meta", sort_keys=True)
    stored = dict(arrays)
    stored[_META] = np.asarray(meta_text)
    stored[_CHECKSUM] = np.asarray(_checksum(arrays, meta_text))
    return atomic_write_npz(path, **stored)


def load_arrays(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a file of ``save_arrays``: ``(arrays, meta)``.

    Raises:
        DamagedFileError: unreadable, truncated, not of ``save_arrays``, or a wrong checksum.
        FileNotFoundError: there is no such file.
    """
    path = Path(path)
    if path.is_dir():
        raise DamagedFileError(f"{path} is a folder; allowed: a file written by save_arrays")
    try:
        with open(path, "rb") as f:
            # NumPy would read anything but a zip archive as a pickle.
            start = f.read(4)
            if not start:
                raise DamagedFileError(f"{path} is damaged (it is empty)")
            if start != b"PK\x03\x04":
                raise DamagedFileError(
                    f"{path} is not a file of save_arrays: it is no .npz archive (another kind "
                    "of file, or one damaged at its start)"
                )
            f.seek(0)
            with np.load(f, allow_pickle=False) as data:
                stored = {name: data[name] for name in data.files}
        meta_text = str(stored.pop(_META))
        checksum = str(stored.pop(_CHECKSUM))
        meta = json.loads(meta_text)
    except (FileNotFoundError, DamagedFileError):
        raise
    except Exception as err:  # zip, zlib, EOF, key and format errors alike
        raise DamagedFileError(f"{path} is damaged ({type(err).__name__}: {err})") from None
    if _checksum(stored, meta_text) != checksum:
        raise DamagedFileError(f"{path} is damaged (its checksum does not match its contents)")
    return stored, meta


# ---------------------------------------------------------------- sealed JSON records

_SEAL = "sha256"


def _record_digest(record: dict[str, Any]) -> str:
    return hashlib.sha256(json_text(record, "record", sort_keys=True).encode()).hexdigest()


def sealed(record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` as it reads back from JSON, with a ``"sha256"`` that ``unsealed`` checks.

    Raises:
        ValueError: not a mapping without ``"sha256"``, or a value JSON cannot store.
    """
    if not isinstance(record, Mapping) or _SEAL in record:
        raise ValueError(
            f"record = {record!r:.80} is not allowed; allowed: a mapping without a {_SEAL!r} key"
        )
    content = json.loads(json_text(dict(record), "record"))
    return {**content, _SEAL: _record_digest(content)}


def unsealed(record: Any, where: str) -> dict[str, Any]:
    """The content of a record ``sealed`` wrote; ``DamagedFileError`` naming ``where`` if edited."""
    if not isinstance(record, dict) or not isinstance(record.get(_SEAL), str):
        raise DamagedFileError(
            f"{where} has no checksum (it was not written by this version of wmr_jax, "
            "or was edited)"
        )
    content = {key: value for key, value in record.items() if key != _SEAL}
    try:
        digest = _record_digest(content)
    except ValueError:  # a value JSON does not round-trip cannot be one sealed() wrote
        digest = None
    if digest != record[_SEAL]:
        raise DamagedFileError(
            f"{where} was changed after it was written (its checksum does not match its contents)"
        )
    return content


# ---------------------------------------------------------------- paths


def writable_path(shown: str, value: Any, *, folder: bool) -> Path:
    """``value`` as a path to write (a folder or a file), tried with a temporary file.

    A refusal introduces the value as ``shown`` (``"out = '/x'"``).
    """
    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else ""
    if not text:  # Path("") is the current folder
        want = "a folder name" if folder else "a file name"
        raise ValueError(f"{shown} is not allowed; allowed: {want}")
    path = Path(text)
    wrong = path.exists() and not path.is_dir() if folder else path.is_dir()
    if wrong:
        want, got = ("a folder", "a file") if folder else ("a file name", "a folder")
        raise ValueError(f"{shown} is not allowed; allowed: {want} (it is {got})")
    existing = next(p for p in (path, *path.parents) if p.exists() or p == Path(p.anchor))
    if existing != path and existing.exists() and not existing.is_dir():
        raise ValueError(f"{shown} is not allowed; {str(existing)!r} is a file, not a folder")
    existing = existing if existing.is_dir() else existing.parent
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        raise ValueError(
            f"{shown} is not allowed; allowed: a place this process can write "
            f"({err.strerror or err})"
        ) from None
    return path


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary files a killed atomic write left in ``folder``; return them."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    stale = [p for p in folder.glob(".*.tmp") if p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale
