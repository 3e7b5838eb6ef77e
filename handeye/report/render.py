"""Render the report context (:mod:`handeye.report.context`) to HTML and Markdown.

The HTML is one self-contained file (figures and thumbnails inlined as data URIs); the Markdown has
its figures and thumbnails as files in ``report_files/``. Templates ship in ``handeye/templates``.
"""

from __future__ import annotations

import base64
import functools
import math
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import quote

import jinja2

from .. import __version__
from .folder import THUMBNAILS_DIR
from .formatting import num

FILES_DIR = "report_files"
#: revision of the escaping compiled into the templates (a new value invalidates cached bytecode)
_ESCAPING_REVISION = "md-escape-1"


def _bytecode_cache() -> jinja2.BytecodeCache | None:
    """Compiled templates kept between runs.

    Compiled templates kept between runs (keyed on the template source, like ``__pycache__``):
    compiling them costs more than the rest of the rendering. None when no cache folder is writable.
    """
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    # the compiled code depends on the environment's finalize (Markdown escaping), which the cache's key
    # (the template source) does not see: the folder name carries its revision
    folder = Path(base) / "handeye" / f"templates-{__version__}-{_ESCAPING_REVISION}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return jinja2.FileSystemBytecodeCache(str(folder)) if os.access(folder, os.W_OK) else None


_MD_TAG = re.compile(r"<(?=[A-Za-z/!?])")  # what starts raw HTML (a tag, comment, declaration) or an autolink
_MD_LINK = re.compile(r"\]\s*([(\[])")  # ](url) and ][ref]: the second half of a link or image


class MdMarkup(str):
    """Markdown the template wrote itself.

    Markdown the template wrote itself (a macro's image or link whose values were escaped one by one, a
    ``<br>`` between flags): printed as it is (the ``md_markup`` filter).
    """


def md_text(x: Any) -> Any:
    """Text safe in Markdown rendered to HTML (python-markdown, GitHub): no raw HTML can start.

    Text safe in Markdown rendered to HTML (python-markdown, GitHub): no raw HTML can start (``<``
    before a letter, ``/``, ``!`` or ``?`` becomes ``&lt;``) and no link or image can form (``](`` and
    ``][`` are broken with a backslash); ``8 < 10`` and ``[mm]`` stay as written. Every value a
    Markdown template prints passes through it (the environment's ``finalize``), except the template's
    own markup (:class:`MdMarkup`).
    """
    if x is None or isinstance(x, (bool, int, float, MdMarkup)):
        return x
    s = str(x)
    if "<" in s:
        s = _MD_TAG.sub("&lt;", s)
    if "]" in s:
        s = _MD_LINK.sub(lambda m: "]\\" + m.group(1), s)
    return s


@functools.lru_cache(maxsize=2)
def _env(*, html: bool) -> jinja2.Environment:
    root = resources.files("handeye").joinpath("templates")
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(root)),
        autoescape=html,
        undefined=jinja2.StrictUndefined,
        bytecode_cache=_bytecode_cache(),
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        finalize=None if html else md_text,
    )
    env.filters["num"] = num
    env.filters["pct"] = pct
    env.filters["sgn"] = lambda x, d=3: num(x, d, signed=True)
    env.filters["mdcell"] = mdcell
    env.filters["md_fence"] = md_fence
    env.filters["md_markup"] = MdMarkup
    env.filters["status_label"] = lambda s: {
        "pass": "PASS",
        "warn": "WARN",
        "fail": "FAIL",
        "info": "INFO",
        "untrusted": "UNTRUSTED",
    }.get(s, s)
    env.globals["version"] = __version__
    return env


def pct(x, digits: int = 0) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "—"
    return "—" if not math.isfinite(v) else f"{100 * v:.{digits}f} %"


def md_fence(x) -> str:
    """The backtick fence of a code block holding ``x``.

    Longer than any run of backticks in ``x``, so no line of it can close the block early.
    """
    longest = max((len(m.group()) for m in re.finditer(r"`+", str(x))), default=0)
    return "`" * max(3, longest + 1)


def mdcell(x) -> str:
    """Text safe inside a Markdown table cell."""
    return str(x).replace("|", "\\|").replace("\n", " ")


def data_uri(data: bytes, mime: str = "image/png") -> str:
    return f"data:{mime};base64," + base64.b64encode(data).decode("ascii")


def safe_name(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", str(s))


def render_html(ctx: dict) -> str:
    images = {p.key: data_uri(p.png) for p in ctx["plots"]}
    thumbs = {vid: data_uri(jpg, "image/jpeg") for vid, jpg in ctx["thumbs"].items()}
    return _env(html=True).get_template("report.html.j2").render(**ctx, images=images, thumb_src=thumbs)


def render_markdown(ctx: dict, *, thumbnails_beside: bool = False) -> tuple[str, dict[str, bytes]]:
    """Markdown text and the files it links (relative path -> bytes).

    ``thumbnails_beside``: the Markdown is written into the result folder, whose ``thumbnails/`` it
    links instead of copying.
    """
    files: dict[str, bytes] = {}
    images, thumbs = {}, {}
    for p in ctx["plots"]:
        rel = f"{FILES_DIR}/{safe_name(p.key)}.png"
        files[rel] = p.png
        images[p.key] = rel
    for vid, jpg in ctx["thumbs"].items():
        if thumbnails_beside:  # the report sits in the result folder: link its thumbnails, no copies
            thumbs[vid] = f"{THUMBNAILS_DIR}/{quote(str(vid))}.jpg"
        else:
            rel = f"{FILES_DIR}/view_{safe_name(vid)}.jpg"
            files[rel] = jpg
            thumbs[vid] = rel
    text = _env(html=False).get_template("report.md.j2").render(**ctx, images=images, thumb_src=thumbs)
    return _tidy_markdown(text), files


#: a line that starts a block of its own or continues one: a table row, heading, quote, list item, indented
#: continuation or raw HTML (everything else is prose: a paragraph of its own in the templates)
_MD_BLOCK = re.compile(r"[|#><]|[-*+] |\d+\. |\s")


def _runs_on(prev: str, line: str) -> bool:
    """Whether Markdown would join ``line`` to the paragraph, list item or quote ``prev`` ends.

    Every prose line of the templates is a paragraph (template control blocks eat the blank line after
    it); a line ending in two spaces is a hard break, meant to continue.
    """
    if not (prev.strip() and line.strip()) or prev.endswith("  ") or _MD_BLOCK.match(line):
        return False
    if prev.startswith(("- ", "* ", "+ ", ">")) or re.match(r"\d+\. ", prev):
        return True  # a lazy continuation of a list item or quote
    return not _MD_BLOCK.match(prev) and prev.strip() != "---"


def _tidy_markdown(text: str) -> str:
    """Blank lines around every table and between paragraphs, and no runs of blank lines.

    Template control blocks eat the blank lines: a table would join the text before it, and two prose
    lines (or a figure after a sentence) would run together into one paragraph (:func:`_runs_on`).
    """
    out: list[str] = []
    fence = None  # the open code block's fence: only a line of that fence closes it (md_fence)
    after_fence = False
    for line in text.splitlines():
        opening = None if fence is not None else re.match(r"`{3,}", line)
        is_fence = opening is not None or (fence is not None and line.strip() == fence)
        in_code = fence is not None or is_fence
        is_row = not in_code and line.startswith("|")
        prev = out[-1] if out else ""
        if not in_code and not after_fence and line.strip() and prev.strip():
            if is_row != prev.startswith("|") or (not is_row and _runs_on(prev, line)):
                out.append("")
        out.append(line)
        if is_fence:
            fence = opening.group() if opening is not None else None
        after_fence = is_fence
    return re.sub(r"\n{3,}", "\n\n", "\n".join(out)).strip() + "\n"


def write_files(out_dir: Path, html: str | None, md: tuple[str, dict] | None) -> list[Path]:
    from ..output import atomic_write_bytes, atomic_write_text

    written = []
    if md is not None:
        text, files = md
        fdir = out_dir / FILES_DIR
        fdir.mkdir(parents=True, exist_ok=True)
        keep = {Path(rel).name for rel in files}
        for old in [*fdir.glob("*.png"), *fdir.glob("*.jpg")]:  # stale files of an earlier report here
            if old.name not in keep:
                old.unlink()
        for rel, data in files.items():
            atomic_write_bytes(out_dir / rel, data)
    if html is not None:
        written.append(atomic_write_text(out_dir / "report.html", html))
    if md is not None:
        written.append(atomic_write_text(out_dir / "report.md", md[0]))
    return written
