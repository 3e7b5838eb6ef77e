"""One exception family for the package.

Every message says what went wrong, what was expected and what to try; where a file is involved
the message starts with the file (and line). The CLI prints ``str(err)`` on one line and exits
with ``err.exit_code``.
"""
from __future__ import annotations

from pathlib import Path


class HandeyeError(Exception):
    """Base of all handeye errors. ``str()`` is a single line meant for a user."""

    exit_code = 2

    def __init__(self, what: str, *, path: str | Path | None = None, line: int | None = None,
                 expected: str | None = None, received: str | None = None, hint: str | None = None):
        self.what = what
        self.path = None if path is None else str(path)
        self.line = line
        self.expected = expected
        self.received = received
        self.hint = hint
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path + (f":{self.line}" if self.line is not None else "") + ": "
        parts = [where + self.what]
        if self.expected is not None:
            parts.append(f"expected {self.expected}")
        if self.received is not None:
            parts.append(f"got {self.received}")
        msg = "; ".join(parts)
        if self.hint:
            msg += f" -> {self.hint}"
        return " ".join(msg.split())  # always one line


class InputError(HandeyeError):
    """A session, config or pose file is missing, unreadable or inconsistent."""


class ConfigError(InputError):
    """A configuration value is impossible or of the wrong type."""


class DetectionError(HandeyeError):
    """The calibration target could not be found in enough views."""

    exit_code = 3


class DegenerateMotionError(HandeyeError):
    """The robot motion does not constrain the hand-eye transform."""

    exit_code = 4


class CalibrationError(HandeyeError):
    """A solver failed or produced an unusable result."""

    exit_code = 5


class HardwareError(HandeyeError):
    """A camera or robot could not be reached or answered wrongly."""

    exit_code = 6
