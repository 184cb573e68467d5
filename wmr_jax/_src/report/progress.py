"""Progress bars on a terminal; elsewhere plain lines, one every ``PLAIN_INTERVAL_S`` at most."""

from __future__ import annotations

import re
import sys
from typing import Any

PLAIN_INTERVAL_S = 10.0
# A status without the bar: "tune (ideal): 40/400 [00:12<01:48, T=0.05, loss=0.61s]".
_PLAIN_FORMAT = "{desc}: {n_fmt}/{total_fmt} [{elapsed}<{remaining}{postfix}]"
_ESCAPES = re.compile(r"\x1b\[[0-9;]*[A-Za-z]|\r")


def on_terminal(stream: Any = None) -> bool:
    """Whether progress written to ``stream`` (default stderr) is seen on a terminal or notebook."""
    stream = sys.stderr if stream is None else stream
    if "ipykernel" in sys.modules:  # a notebook draws its own widget
        return True
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or closed
        return False


class _Lines:
    """A stream for ``tqdm`` that turns each redraw into one plain line (none before it moves)."""

    def __init__(self, stream: Any, desc: str) -> None:
        self._stream = stream
        self._unmoved = f"{desc}: 0/"

    def write(self, text: str) -> None:
        line = _ESCAPES.sub("", text).strip()
        if line and not line.startswith(self._unmoved):
            self._stream.write(line + "\n")

    def flush(self) -> None:
        self._stream.flush()


def bar(**kwargs: Any) -> Any:
    """A ``tqdm.auto.tqdm(**kwargs)`` on a terminal; plain lines, no escapes, elsewhere."""
    import tqdm.auto

    stream = kwargs.pop("file", None) or sys.stderr
    if on_terminal(stream):
        return tqdm.auto.tqdm(file=stream, **kwargs)
    kwargs.pop("dynamic_ncols", None)
    plain = {"bar_format": _PLAIN_FORMAT, "mininterval": PLAIN_INTERVAL_S}
    lines = _Lines(stream, kwargs.get("desc") or "")
    return tqdm.auto.tqdm(file=lines, **{**kwargs, **plain})
