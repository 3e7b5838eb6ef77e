"""The README and docs pages: links that resolve, a README that starts on one screen, short module docstrings."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: files the README links that another change adds; checked here once they are part of the tree
PENDING: set[str] = set()
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {_slug(m) for m in re.findall(r"^#{1,6} (.+)$", text, flags=re.M)}


def _links(page: Path):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for target in LINK.findall(text):
        if not re.match(r"[a-z]+:", target):
            yield target


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(page):
    for target in _links(page):
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if dest.relative_to(ROOT).as_posix() in PENDING:
            continue
        assert dest.exists(), f"{page.name}: {target} does not exist"
        if anchor and dest.suffix == ".md":
            assert anchor in _anchors(dest), f"{page.name}: {target} names no heading of {dest.name}"


def test_the_readme_starts_on_one_screen():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) < 180
    first = "\n".join(lines[:40])
    blocks = re.findall(r"```bash\n(.*?)```", first, flags=re.S)
    assert "pip install . && handeye demo\n" in blocks  # install and run the main job
    assert "bash scripts/test.sh\n" in blocks  # install and pass the tests


def _module_docstrings():
    for folder in ("handeye", "factors", "configs"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if not any(p.is_symlink() for p in path.relative_to(ROOT).parents if p != Path(".")):
                yield path.relative_to(ROOT).as_posix(), ast.get_docstring(ast.parse(path.read_text()), clean=False)


def test_module_docstrings_are_short_with_a_one_line_summary():
    found = dict(_module_docstrings())
    assert len(found) > 100
    for name, doc in found.items():
        assert doc, f"{name} has no module docstring"
        lines = doc.strip("\n").splitlines()
        assert len(lines) <= 15, f"{name}: module docstring of {len(lines)} lines; move the details to docs/"
        assert lines[0].rstrip().endswith("."), f"{name}: the summary line ends with a period"
        assert len(lines) == 1 or not lines[1].strip(), f"{name}: a blank line follows the summary"
