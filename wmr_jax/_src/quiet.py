"""Whether the package gives its warnings about arguments here.

A study checks every run's settings before it draws anything, on a stand-in
run (``sensing.loop.check_settings``); the runs check them again and warn.
The stand-in's warnings are not given: ``warnings.catch_warnings`` would hide
them too, but it also resets Python's record of the warnings already shown,
so that each would then be shown again.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator

_QUIET = contextvars.ContextVar("wmr_jax_quiet", default=False)


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Within it, the package's warnings about arguments are not given."""
    token = _QUIET.set(True)
    try:
        yield
    finally:
        _QUIET.reset(token)


def warns() -> bool:
    """Whether the package's warnings about arguments are given here (outside ``quiet``)."""
    return not _QUIET.get()
