"""What ``handeye calibrate`` prints after the result block: the verdict and what to fix.

The verdict line, one line for every QA check and diagnostics finding that warns or fails (each with
its fix), and how the mounting mode was chosen when the session did not state it. Everything comes
from result.json (``verdict``, ``verdict_headline``, ``qa``, ``findings``, ``mode_source``,
``mode_evidence``; see :mod:`handeye.results`), so a result folder prints the same lines anywhere.
"""

from __future__ import annotations

_RANK = {"fail": 0, "warn": 1}


def mode_lines(res: dict) -> list[str]:
    """One line saying which mode was used and why, when the data (not the session) decided it."""
    src, mode = res.get("mode_source"), res.get("mode")
    summary = (res.get("mode_evidence") or {}).get("summary")
    why = f": {summary}" if summary else ""
    if src == "detected":
        return [f"mode: {mode}, detected from the data (the session states none){why}"]
    if src == "default" and not summary:  # the run stopped before the data were looked at
        return [f"mode: {mode}, the default (the session states none); state it with --mode if this is wrong"]
    if src == "default":
        return [
            f"mode: {mode}, the default (the session states none and the data do not decide it{why}); "
            f"state it with --mode if this is wrong"
        ]
    return []


def verdict_lines(res: dict) -> list[str]:
    """``verdict: PASS|WARN|FAIL|REFUSED - headline``, then every failing or warning check and finding.

    ``verdict: PASS|WARN|FAIL|REFUSED - headline``, then every failing or warning check and finding,
    worst first, a finding (a cause) before a QA check (an effect) of the same severity:
    ``  FAIL <what> -> fix: <what to do>``.
    """
    verdict = res.get("verdict")
    if verdict is None:  # a result.json written before verdicts were stored
        return []
    head = res.get("verdict_headline") or ""
    if res.get("status") != "ok":  # no matrix: say why, and what to do, from the error
        err = res.get("error") or {}
        if verdict != "REFUSED" or not head:  # a refusal's headline names its root cause, as the report does
            what = str(err.get("what") or res.get("failure_reason") or head).rstrip(".")
            if err.get("what") and err.get("file"):  # the file it is about (a corrupt image, a bad pose line)
                what = f"{err['file']}" + (f":{err['line']}" if err.get("line") is not None else "") + f": {what}"
            head = "no result: " + what
        if err.get("fix"):
            head = head.rstrip(".") + f" -> fix: {err['fix']}"
    lines = ["verdict: " + " ".join(f"{verdict} - {head}".split()) if head else f"verdict: {verdict}"]
    # without a result the QA checks judge nothing: only the findings (the refusal's evidence) follow
    return lines + _item_lines(res, checks=res.get("status") == "ok")


def problem_lines(res: dict) -> list[str]:
    """Every failing or warning QA check and finding of a result with a matrix, worst first, with its fix."""
    return _item_lines(res, checks=True)


def finding_lines(res: dict, *, skip=()) -> list[str]:
    """Every failing or warning finding (not the QA checks), except the codes in ``skip``."""
    return _item_lines(res, checks=False, skip=skip)


def _item_lines(res: dict, *, checks: bool, skip=()) -> list[str]:
    items = []  # (severity, 0 for a finding / 1 for a QA check, text, fix): findings name causes, checks effects
    for c in ((res.get("qa") or {}).get("checks") or []) if checks else []:
        st = str(c.get("status", "")).lower()
        if st in _RANK and c.get("key") != "calibration":  # the failed calibration is the line above
            what = c.get("short") or c.get("title") or c.get("key")
            items.append(
                (st, 1, f"{what} ({c.get('why')})" if c.get("why") and not c.get("short") else what, c.get("action"))
            )
    for f in res.get("findings") or []:
        st = str(f.get("severity", "")).lower()
        if st in _RANK and f.get("code") not in skip:
            items.append((st, 0, f"{f.get('code')}: {str(f.get('title') or '').rstrip('.')}", f.get("action")))
    items.sort(key=lambda it: (_RANK[it[0]], it[1]))  # worst first; a finding (the cause) before a check
    lines = []
    for st, _kind, what, fix in items:
        line = f"{st.upper()} {what}" + (f" -> fix: {_lower1(str(fix).rstrip('.'))}" if fix else "")
        lines.append("  " + " ".join(line.split()))  # always one line
    return lines


def _lower1(s: str) -> str:
    return s[:1].lower() + s[1:]
