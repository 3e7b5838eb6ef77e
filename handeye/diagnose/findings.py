"""The findings framework: the :class:`Finding` record, severities, and the guarded stage runner.

Every check of the diagnostics runs as a named stage through :class:`Stages`. A stage that raises is
recorded as ``crashed`` with its exception (``diagnostics["stages"]`` and ``["stage_errors"]``); it is
never turned into a finding or into "nothing found", so a clean-session test or benchmark sees the
crash. A stage that does not apply (no hand-eye result, images not read) is ``skipped`` with why.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

from ..output import plain

log = logging.getLogger(__name__)

SEVERITIES = ("fail", "warn", "info")
STAGE_STATUSES = ("ok", "crashed", "skipped")


@dataclass(frozen=True)
class Finding:
    code: str  # stable machine name, e.g. "translation_units"
    severity: str  # fail | warn | info
    title: str  # one line a person understands
    evidence: str  # the numbers that show it
    action: str  # what to do
    view_ids: tuple = ()
    details: dict = field(default_factory=dict)  # machine-readable numbers behind the evidence

    def __post_init__(self):
        if self.severity not in SEVERITIES:
            raise ValueError(f"severity must be one of {SEVERITIES}, got {self.severity!r}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["view_ids"] = [str(v) for v in self.view_ids]
        return plain(d, nan_to_none=True)


def worst_first(findings: Sequence[Finding]) -> list[Finding]:
    order = {s: k for k, s in enumerate(SEVERITIES)}
    return sorted(findings, key=lambda f: order[f.severity])


def ids_text(ids: Sequence[str], limit: int = 12) -> str:
    """View ids as a short list for a title ("1, 2, 3 and 4 more")."""
    ids = [str(v) for v in ids]
    return ", ".join(ids[:limit]) + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


class Stages:
    """Runs the diagnostics' stages, each guarded, and records how each ended.

    ``run(name, fn, ...)`` returns ``fn``'s value, or ``default`` when it raised (status ``crashed``,
    the exception kept for the output); ``skip(name, why)`` records a stage that did not apply.
    """

    def __init__(self) -> None:
        self.status: dict[str, str] = {}
        self.errors: dict[str, str] = {}
        self.skipped: dict[str, str] = {}

    def run(self, name: str, fn: Callable, *args, default=None, **kw):
        try:
            out = fn(*args, **kw)
        except Exception as e:  # noqa: BLE001 - a crashed stage is recorded and reported, never hidden
            # one line for the user; the traceback for developers (handeye --verbose / --debug)
            log.warning("diagnostics stage %r crashed (%s: %s); its checks did not run", name, type(e).__name__, e)
            log.debug("traceback of the crashed diagnostics stage %r", name, exc_info=True)
            self.status[name] = "crashed"
            self.errors[name] = f"{type(e).__name__}: {e}"
            return default
        self.status.setdefault(name, "ok")
        return out

    def skip(self, name: str, why: str) -> None:
        self.status[name] = "skipped"
        self.skipped[name] = why

    @property
    def crashed(self) -> list[str]:
        return [k for k, v in self.status.items() if v == "crashed"]

    def to_dict(self) -> dict:
        """The stages' outcomes as a JSON-ready dict.

        ``{"stages": {name: ok|crashed|skipped}, "stage_errors": {name: "Type: message"},
        "stages_skipped": {name: why}, "crashed_stages": count}``.
        """
        return {
            "stages": dict(self.status),
            "stage_errors": dict(self.errors),
            "stages_skipped": dict(self.skipped),
            "crashed_stages": len(self.crashed),
        }


#: code -> a few words naming the root cause, for the start of the report's banner; a finding code not
#: here (e.g. board_moved) is named by its own title, which says it already
ROOT_CAUSE_LABELS = {
    "mode_swapped": "Mode swapped",
    "poses_inverted": "Robot poses inverted",
    "translation_units": "Robot translations in the wrong unit",
    "angle_units": "Robot angles in the wrong unit",
    "euler_order": "Wrong Euler angle order",
    "rotation_kind": "Wrong kind of rotation",
    "quaternion_order": "Wrong quaternion order",
    "pairs_shuffled": "Pairs shuffled",
    "poses_do_not_fit": "Robot poses do not fit the target's poses",  # seen in the images or by a tracker
    "mode_undecided": "Mounting mode not decided",
}

#: the label of a pairs_shuffled finding that is a shift from one image on (a capture that lost its image or pose)
PAIRS_OUT_OF_STEP = "Pairs out of step"


def is_out_of_step(f: dict) -> bool:
    """A pairs_shuffled finding that is a shift from one image on (its own fix: the order was not lost)."""
    return f.get("code") == "pairs_shuffled" and bool((f.get("details") or {}).get("partial_shift"))
