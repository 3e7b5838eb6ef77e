"""One exception family for the package, with structured fields.

Every error says what went wrong, where (file, line), what was expected and received, and what to
try. ``str(err)`` is one line for a person, ``err.code`` a stable machine name and ``err.to_dict()``
the record result.json stores under ``"error"``. This module is the one source of the exit codes:
each class's ``exit_code``, :func:`verdict_exit_code` for a run with a matrix, and :data:`EXIT_CODES`,
the table ``handeye --help`` and the README show. :data:`PIPELINE_CODES` lists the pipeline's codes.

See docs/cli.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


class HandeyeError(Exception):
    """Base of all handeye errors. ``str()`` is a single line meant for a user."""

    exit_code = 2
    code = "error"

    def __init__(
        self,
        what: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        expected: str | None = None,
        received: str | None = None,
        hint: str | None = None,
        code: str | None = None,
    ):
        self.what = what
        self.path = None if path is None else str(path)
        self.line = line
        self.expected = expected
        self.received = received
        self.hint = hint
        if code is not None:
            self.code = code  # instance attribute: the class default stays as it is
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

    def at(self, path: str | Path, line: int | None = None) -> "HandeyeError":
        """The same error located in ``path`` (a new exception of the same class and code)."""
        return type(self)(
            self.what,
            path=path,
            line=line if line is not None else self.line,
            expected=self.expected,
            received=self.received,
            hint=self.hint,
            code=self.code,
        )

    def to_dict(self) -> dict[str, Any]:
        """The structured record (JSON-ready).

        Code, what, file, line, expected, got, fix, exit_code, plus ``type`` (the class name) and
        ``message`` (``str(self)``).
        """
        return {
            "code": self.code,
            "type": type(self).__name__,
            "what": self.what,
            "file": self.path,
            "line": self.line,
            "expected": self.expected,
            "got": self.received,
            "fix": self.hint,
            "exit_code": self.exit_code,
            "message": str(self),
        }


class InputError(HandeyeError):
    """A session, config or pose file is missing, unreadable or inconsistent."""

    code = "input_error"


class ConfigError(InputError):
    """A configuration value is impossible or of the wrong type."""

    code = "config_error"


class OutputError(InputError):
    """An output folder or file cannot be used.

    It is a file, lies under a file, is not writable, is in use by another run, or the disk refused the
    write. Checked before the work starts where it can be.
    """

    code = "output_unusable"


class DetectionError(HandeyeError):
    """The calibration target could not be found in enough views."""

    exit_code = 3
    code = "detection_failed"


class DegenerateMotionError(HandeyeError):
    """The robot motion does not constrain the hand-eye transform."""

    exit_code = 4
    code = "degenerate_motion"


class CalibrationError(HandeyeError):
    """A solver failed or produced an unusable result."""

    exit_code = 5
    code = "calibration_failed"


class SessionRefused(HandeyeError):
    """The data contradict themselves so that no result can be trusted.

    The data contradict themselves so that no result can be trusted (images and poses shuffled or
    shifted, a stated mounting mode the data contradict): no matrix is given, the findings say why.

    Raised (or set as a run's error) by the stage that decides it, or by the workflow for a diagnostics
    finding that refuses the run (see :mod:`handeye.workflow`); ``code`` names the reason more precisely
    when the raise site knows it (e.g. the finding's code).
    """

    exit_code = 8
    code = "session_refused"


class QAFailed(HandeyeError):
    """A matrix was computed, but the verdict is FAIL.

    A QA check or a diagnostics finding says it is not fit for use. result.json and the reports are
    written; the CLI exits with this class's code.
    """

    exit_code = 7
    code = "qa_failed"


class HardwareError(HandeyeError):
    """A camera or robot could not be reached or answered wrongly."""

    exit_code = 6
    code = "hardware_error"


#: codes the calibration pipeline raises (beyond the class defaults), for advice keyed on them
PIPELINE_CODES = {
    "target_not_found": "the target was found in fewer than 3 images",
    "too_few_views": "fewer than 3 views with a detected target and a robot pose",
    "motion_small_rotation": "the robot barely rotates between views",
    "motion_one_axis": "all relative rotations are about one axis",
    "intrinsics_size_mismatch": "the given intrinsics are for another image size",
    "unknown_method": "the closed-form method name is not known",
    "closed_form_failed": "the chosen closed-form solver failed",
    "refinement_failed": "the joint refinement failed",
    "camera_calibration_failed": "calibrateCamera returned an unusable camera",
    "pnp_failed": "a view's board pose could not be solved",
    "mode_swapped": "the stated mounting mode contradicts the data (the other mode fits clearly better)",
    "pairs_shifted": "images and robot poses are out of step by a constant shift (refused; see --shift-poses)",
    "pairs_shuffled": "images carry other views' robot poses (refused)",
}


#: what each value of result.json's ``verdict`` means; PASS and WARN exit 0, FAIL with
#: :class:`QAFailed`'s code, REFUSED with :class:`SessionRefused`'s
VERDICTS = {
    "PASS": "every QA check passes and the diagnostics found nothing to warn about",
    "WARN": "the result is usable; a QA check or a finding warns (the CLI prints each with its fix)",
    "FAIL": "a matrix was computed but a QA check or a finding says it is not fit for use",
    "REFUSED": "a finding makes any result untrustworthy; no matrix is given",
}

#: exit code of ``handeye`` after Ctrl-C (128 + SIGINT, as shells report it)
INTERRUPTED_EXIT_CODE = 130

#: exit code of ``handeye`` when the reader of its output went away (128 + SIGPIPE, as ``handeye ... | head``
#: gives a shell)
OUTPUT_CLOSED_EXIT_CODE = 141

#: exit code of ``handeye verify`` / ``handeye compare`` when the calibration changed beyond its uncertainty
DRIFTED_EXIT_CODE = 9

#: exit codes of ``handeye`` (code, meaning), the table ``--help`` and the README show
EXIT_CODES = (
    (0, "PASS or WARN: the result is written (warnings and their fixes are printed)"),
    (1, "an unexpected internal error (a bug: please report it with the traceback of --debug)"),
    (
        InputError.exit_code,
        "unusable input: a session, pose, config or QA file, a command-line option, or an "
        "output folder that cannot be written or is in use",
    ),
    (DetectionError.exit_code, "the target was not found in enough views (or not with the stated size)"),
    (DegenerateMotionError.exit_code, "the robot motion does not determine the hand-eye transform"),
    (CalibrationError.exit_code, "a solver failed"),
    (HardwareError.exit_code, "a camera or robot could not be reached or answered wrongly (collect)"),
    (QAFailed.exit_code, "FAIL: a matrix was computed but QA or a finding fails it; result and reports written"),
    (SessionRefused.exit_code, "REFUSED: a finding makes the result untrustworthy; no matrix, the finding says why"),
    (DRIFTED_EXIT_CODE, "DRIFTED (verify, compare): the calibration changed beyond its uncertainty"),
    (INTERRUPTED_EXIT_CODE, "interrupted (Ctrl-C)"),
    (OUTPUT_CLOSED_EXIT_CODE, "the reader of the printed output went away (e.g. the output piped into head)"),
)


def verdict_exit_code(verdict: str | None) -> int:
    """The exit code of a finished run from its verdict (PASS | WARN | FAIL | REFUSED)."""
    return {"FAIL": QAFailed.exit_code, "REFUSED": SessionRefused.exit_code}.get(str(verdict or "").upper(), 0)


def exit_codes_text(indent: str = "  ") -> str:
    """:data:`EXIT_CODES` as lines for a ``--help`` epilog."""
    return "exit codes:\n" + "\n".join(f"{indent}{code:>3}  {meaning}" for code, meaning in EXIT_CODES)


def clip(text: object, limit: int = 120) -> str:
    """``text`` on one line, at most ``limit`` characters, cut between words and marked ``...`` when cut.

    For a quoted exception or value inside a message: a plain slice (``text[:80]``) cut words in half and,
    inside the message's parentheses, read as a finished text (``(|x| )``, ``(e.)``). A message of
    handeye's own (a failure reason, a hint) is quoted whole, not clipped.
    """
    one = " ".join(str(text).split())
    if len(one) <= limit:
        return one
    cut = one[: max(limit - 3, 1)]
    head, _, _ = cut.rpartition(" ")
    return (head if len(head) >= limit // 2 else cut).rstrip(" ,;:") + "..."
