"""The non-ideal velocity loop: wheel-speed control of the Eq. 5 dynamics (SPEC §4)."""

from __future__ import annotations

DEFAULT_SUBSTEPS = 10


def advance(state, command, robot, dt, *, substeps, wheel_limit):
    raise NotImplementedError("the non-ideal velocity loop is being written")
