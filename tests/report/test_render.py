"""Markdown code blocks hold any text: the fence outgrows the text's backtick runs, and the tidying pass
neither closes a block early nor inserts lines into it."""

from __future__ import annotations

from handeye.report.render import _env, _tidy_markdown, md_fence


def test_the_fence_is_longer_than_any_backtick_run():
    assert md_fence("plain: yes") == "```"
    assert md_fence("a: '```'\nb: '`````'") == "``````"


def test_a_config_holding_a_fence_stays_one_code_block():
    config = "note: |\n```\n| not | a | table |\n<script>alert(1)</script>\n```\nsquare: 0.03"
    src = (
        "## Configuration\n{{ c | md_fence }}yaml\n{{ c }}\n{{ c | md_fence }}\n| a | b |\n|---|---|\n| 1 | 2 |\nend\n"
    )
    md = _tidy_markdown(_env(html=False).from_string(src).render(c=config))
    lines = md.splitlines()
    start, stop = lines.index("````yaml"), lines.index("````")
    # the config inside, line for line (markup escaped as everywhere in the Markdown report), nothing added
    assert lines[start + 1 : stop] == [
        "note: |",
        "```",
        "| not | a | table |",
        "&lt;script>alert(1)&lt;/script>",
        "```",
        "square: 0.03",
    ]
    assert lines[stop + 1 :] == ["| a | b |", "|---|---|", "| 1 | 2 |", "", "end"]
