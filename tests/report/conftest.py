"""Helpers of the report tests (fixtures: the tests run with --import-mode=importlib)."""

from __future__ import annotations

import re

import pytest


def joined_lines(md: str) -> list[tuple[str, str]]:
    """Adjacent lines of ``md`` that Markdown runs into one paragraph (or into a list item's or quote's text).

    Outside code blocks: a prose line (not a table row, heading, quote, list item, indented continuation or
    HTML) after a non-empty line other than a table row, heading, HTML, rule or hard break (two spaces).
    """
    pairs, fence = [], False
    lines = md.splitlines()
    for a, b in zip(lines, lines[1:], strict=False):
        if a.startswith("```"):
            fence = not fence
        if fence or b.startswith("```") or not (a.strip() and b.strip()) or a.endswith("  "):
            continue
        if not re.match(r"[|#><]|[-*+] |\d+\. |\s", b) and not re.match(r"[|#<]|---$", a):
            pairs.append((a, b))
    return pairs


@pytest.fixture(name="joined_lines")
def joined_lines_fixture():
    """:func:`joined_lines`, for the tests of the Markdown reports."""
    return joined_lines
