"""Two result folders of the same session, before and after a change: the same numbers, findings and report?

Compares result.json field by field (numbers within ``--rtol``/``--atol``, everything else exactly; run ids,
times, the command line and other provenance that differs between runs are skipped), the findings and
the verdict, and the reports: report.md's section headings and lines, report.html's sections, figures
(count and keys) and tables. Prints each difference and a summary line; exit 1 when anything differs.

A cell's folders (``kind: cell``) are compared with each camera's own calibration in ``solo/<camera>/``; its
findings are the cell's (with the camera they name).

Two runs of the same code differ by about 1e-8 relative (multi-threaded detection and linear algebra); the
summary prints the largest relative difference so that a change can be set against that spread.

    python benchmarks/compare_results.py BEFORE_DIR AFTER_DIR [--rtol 1e-6] [--atol 1e-12]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

#: result.json keys that differ between two runs of the same session by design
VOLATILE = {"seconds", "run_id", "time_utc", "command_line", "generated_utc", "hostname", "pid", "python", "versions"}


WORST = [0.0]  # the largest relative difference of two numbers above atol


def diff(a, b, path: str, *, rtol: float, atol: float, out: list) -> None:
    """Every difference between two JSON values, into ``out`` as 'path: a != b'."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in VOLATILE:
                continue
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'after' if k in b else 'before'}")
            else:
                diff(a[k], b[k], f"{path}/{k}", rtol=rtol, atol=atol, out=out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            diff(x, y, f"{path}[{i}]", rtol=rtol, atol=atol, out=out)
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if math.isnan(a) and math.isnan(b):
            return
        rel = abs(a - b) / max(abs(a), abs(b), 1e-300)
        if abs(a - b) > atol:
            WORST[0] = max(WORST[0], rel)
        if not math.isclose(a, b, rel_tol=rtol, abs_tol=atol):
            out.append(f"{path}: {a!r} != {b!r}")
    elif a != b:
        out.append(f"{path}: {str(a)[:80]!r} != {str(b)[:80]!r}")


def _numbers_masked(line: str) -> str:
    """A report line with its run-dependent parts (times, ids, dates) masked."""
    line = re.sub(r"[0-9a-f]{32}", "<id>", line)
    line = re.sub(r"\d{4}-\d\d-\d\d[T ][\d:.+]+", "<time>", line)
    return re.sub(r"(load|detect|intrinsics|board_poses|closed_form|refine|validate|calibrate|diagnose|write|verdict|"
                  r"report|total) \d+\.\d+ s", r"\1 <t> s", line)  # fmt: skip


def report_diff(before: Path, after: Path, out: list) -> dict:
    """Differences of report.md (lines, masked) and report.html (sections, figures, tables)."""
    counts = {}
    md_a, md_b = (p / "report.md" for p in (before, after))
    if md_a.exists() != md_b.exists():
        out.append("report.md: present in only one folder")
    elif md_a.exists():
        la = [_numbers_masked(x) for x in md_a.read_text().splitlines()]
        lb = [_numbers_masked(x) for x in md_b.read_text().splitlines()]
        skip = ("Report generated", "Run time", "Report command line", "Command line", "Run id")
        la = [x for x in la if not any(s in x for s in skip)]
        lb = [x for x in lb if not any(s in x for s in skip)]
        counts["md sections"] = sum(x.startswith("#") for x in lb)
        if [x for x in la if x.startswith("#")] != [x for x in lb if x.startswith("#")]:
            out.append("report.md: section headings differ")
        for i, (x, y) in enumerate(zip(la, lb, strict=False)):
            if x != y:
                out.append(f"report.md line {i + 1}: {x[:100]!r} != {y[:100]!r}")
        if len(la) != len(lb):
            out.append(f"report.md: {len(la)} lines != {len(lb)}")
    h_a, h_b = (p / "report.html" for p in (before, after))
    if h_a.exists() and h_b.exists():
        ha, hb = h_a.read_text(), h_b.read_text()
        for what, pat in (
            ("sections", r"<h[1-4][^>]*>(.*?)</h[1-4]>"),
            ("figures", r"<figure[^>]*id=\"([^\"]*)\""),
            ("figure captions", r"<figcaption>(.*?)</figcaption>"),
            ("images", r"<img "),
            ("tables", r"<table"),
        ):
            fa, fb = re.findall(pat, ha, re.S), re.findall(pat, hb, re.S)
            counts[f"html {what}"] = len(fb)
            if fa != fb:
                out.append(f"report.html {what}: {len(fa)} before, {len(fb)} after")
    return counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=1e-12)
    a = ap.parse_args(argv)
    ra, rb = (json.loads((p / "result.json").read_text()) for p in (a.before, a.after))
    out: list[str] = []
    diff(ra, rb, "result.json", rtol=a.rtol, atol=a.atol, out=out)
    counts = report_diff(a.before, a.after, out)
    if rb.get("kind") == "cell":  # each camera's own calibration too: solo/<camera>/
        for cam in sorted(set(ra.get("cameras") or {}) | set(rb.get("cameras") or {})):
            sa, sb = (p / "solo" / cam for p in (a.before, a.after))
            if not ((sa / "result.json").is_file() and (sb / "result.json").is_file()):
                out.append(f"solo/{cam}/result.json: present in {'neither' if not sa.exists() else 'one'} folder")
                continue
            rsa, rsb = (json.loads((p / "result.json").read_text()) for p in (sa, sb))
            diff(rsa, rsb, f"solo/{cam}/result.json", rtol=a.rtol, atol=a.atol, out=out)
            sub: list[str] = []
            for k, v in report_diff(sa, sb, sub).items():
                counts[f"solo {k}"] = counts.get(f"solo {k}", 0) + v
            out += [f"solo/{cam}/{x}" for x in sub]
    for line in out[:200]:
        print(line)
    f = [x["code"] for x in (rb.get("diagnostics") or {}).get("findings", [])]
    f += [x["code"] + (f" ({x['camera']})" if x.get("camera") else "") for x in rb.get("findings") or []]
    print(
        f"{len(out)} differences (rtol {a.rtol:g}, atol {a.atol:g}; largest relative difference {WORST[0]:.1e}); "
        f"verdict {ra.get('verdict')} -> {rb.get('verdict')}; findings after: {', '.join(f) or 'none'}; "
        + ", ".join(f"{k} {v}" for k, v in counts.items())
    )
    return 1 if out else 0


if __name__ == "__main__":
    sys.exit(main())
