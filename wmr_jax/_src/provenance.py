"""Which code computed a result: the package version and a digest of its source.

Caches record ``code_version()`` and are reused only by the same code. The digest
leaves out ``cli/`` and ``report/``, which compute nothing that is cached.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
from pathlib import Path

_SOURCE = Path(__file__).resolve().parent
_NOT_COMPUTING = ("cli", "report")


@functools.cache
def code_version() -> str:
    """``"<package version>+<16 hex digits of the computing source>"``."""
    try:
        version = importlib.metadata.version("wmr_jax")
    except importlib.metadata.PackageNotFoundError:  # a source tree, not installed
        version = "source"
    digest = hashlib.sha256()
    for path in sorted(_SOURCE.rglob("*.py")):
        relative = path.relative_to(_SOURCE)
        if relative.parts[0] in _NOT_COMPUTING:
            continue
        digest.update(relative.as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return f"{version}+{digest.hexdigest()[:16]}"
