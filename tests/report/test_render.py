"""Markdown code blocks hold any text: the fence outgrows the text's backtick runs, and the tidying pass
neither closes a block early nor inserts lines into it; it keeps every prose line of the templates a
paragraph of its own (template control blocks eat the blank lines between them)."""

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


def test_prose_lines_after_a_control_block_stay_paragraphs_of_their_own(joined_lines):
    """report.md ran "**Why the calibration failed:** ..." into "**What to change:**", "Ratio held-out /
    predicted ..." into "Axes: ...", and a sentence into the figure after it: a line ending in a control
    block loses its newline (trim_blocks), and the blank line after it only ends that line."""
    src = (
        "**Why:** {{ why }}{% if code %} [`{{ code }}`]{% endif %}\n\n**What to change:**\n\n"
        "{% for a in actions %}\n- {{ a }}\n{% endfor %}\nAfter the list.\n"
        "{% if r %}Ratio: {{ r }}.\n{% endif %}\n{% if axes %}Axes: {{ axes }}.\n\n{% endif %}\n"
        "Header line  \nsecond line of the header\n> quote  \n> quote\n\n"
        "- **finding**  \n  Evidence: indented\n\n| a |\n|---|\n| 1 |\n"
        "These sigmas.\n{% for p in plots %}\n![{{ p }}](f.png)\n\n{% endfor %}\n```\nkept\ntogether\n```\n"
    )
    ctx = dict(why="few views", code="few", actions=["add views"], r=1.2, axes="x, y", plots=["Fig"])
    raw = _env(html=False).from_string(src).render(**ctx)
    assert ("**Why:** few views [`few`]", "**What to change:**") in joined_lines(raw)  # the defect, untidied
    md = _tidy_markdown(raw)
    assert joined_lines(md) == []
    assert md.splitlines() == [
        "**Why:** few views [`few`]",
        "",
        "**What to change:**",
        "",
        "- add views",
        "",
        "After the list.",
        "",
        "Ratio: 1.2.",
        "",
        "Axes: x, y.",
        "",
        "Header line  ",  # a hard break continues its paragraph
        "second line of the header",
        "> quote  ",
        "> quote",
        "",
        "- **finding**  ",
        "  Evidence: indented",
        "",
        "| a |",
        "|---|",
        "| 1 |",
        "",
        "These sigmas.",
        "",
        "![Fig](f.png)",
        "",
        "```",
        "kept",
        "together",
        "```",
    ]
