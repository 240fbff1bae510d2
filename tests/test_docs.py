"""The README and the documentation pages under docs/ (the site itself is built strictly by
scripts/test.sh: `mkdocs build --strict` checks every link and anchor between the pages).

The README is the short front page: it links into docs/, and every such link must reach a page (and
an anchor of it) that exists, since the README on its own is not part of the site's link check."""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README_MAX_LINES = 150  # a newcomer reads it in two minutes; the rest lives in docs/
LINK = re.compile(r"\]\(([^)\s]+)\)")
LESSON_MARK = re.compile(r"<!-- lesson: ([a-z0-9-]+) -->")


def slug(heading: str) -> str:
    """The anchor MkDocs' toc extension gives a heading (its default slugify)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(page: Path) -> set[str]:
    """The anchors of a page's headings (outside code fences)."""
    found: set[str] = set()
    fence = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fence = not fence
        elif not fence and (m := re.match(r"^#{1,6}\s+(.*)$", line)):
            found.add(slug(m.group(1)))
    return found


def readme() -> str:
    return (ROOT / "README.md").read_text(encoding="utf-8")


def test_readme_is_short():
    lines = readme().count("\n")
    assert 30 < lines <= README_MAX_LINES, f"README.md has {lines} lines; move the detail to a page under docs/"


def test_every_readme_link_into_docs_reaches_a_page_and_its_anchor():
    links = [u for u in LINK.findall(readme()) if u.startswith("docs/")]
    assert len(links) >= 15, links  # the lessons, the results and the reference pages
    broken = []
    for url in links:
        path, _, anchor = url.partition("#")
        page = ROOT / path
        if page.suffix != ".md" or not page.is_file():
            broken.append(f"{url}: no page {path}")
        elif anchor and anchor not in anchors(page):
            broken.append(f"{url}: {path} has no heading with anchor #{anchor} (it has {sorted(anchors(page))})")
    assert not broken, "\n".join(broken)


def test_every_readme_picture_exists():
    pictures = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", readme())
    assert pictures, "the README shows no picture"
    missing = [p for p in pictures if not (ROOT / p).is_file()]
    assert not missing, missing


def test_every_lesson_has_a_page_that_renders_its_steps():
    """Each lesson of the Lessons tab has a page under docs/lessons/ whose steps are generated from
    app.live.lessons (the marker the docs hook fills), and no page names a lesson that is gone."""
    from app.live.curriculum import LESSONS

    marked = {}
    for page in (DOCS / "lessons").glob("*.md"):
        for key in LESSON_MARK.findall(page.read_text(encoding="utf-8")):
            marked[key] = page.name
    keys = {lesson.key for lesson in LESSONS}
    assert set(marked) == keys, (sorted(marked), sorted(keys))


def test_the_hook_renders_every_subcommand_and_each_lessons_steps():
    """The CLI reference is the parser's own help: a section per subcommand, each with its usage line;
    a lesson's steps are numbered as many as the lesson has."""
    import importlib.util

    import pytest

    pytest.importorskip("mkdocs", reason="the hook is a MkDocs hook: pip install -e '.[docs]'")
    from app.cli import build_parser
    from app.live.curriculum import LESSONS

    spec = importlib.util.spec_from_file_location("docs_hook", DOCS / "hooks" / "generated.py")
    assert spec and spec.loader
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    text = hook.cli_reference()
    names = list(hook._subcommands(build_parser()))
    assert {"serve", "experiment", "sweep", "check", "bench"} <= set(names), names
    for name in names:
        assert f"## torquelab {name}\n" in text
        assert f"usage: torquelab {name}" in text
    for lesson in LESSONS:
        steps = hook.lesson_steps(lesson.key)
        assert lesson.purpose in steps
        assert len(re.findall(r"^\d+\. \*\*", steps, flags=re.M)) == len(lesson.steps)


def test_the_glossary_defines_every_term_the_readme_sends_a_reader_there_for():
    """The README's documentation list names the terms its glossary explains ("…: Np, headroom, σ,
    W_j/W_f/W_a/W_d, … and the rest"); each is a defined term of docs/glossary.md."""
    named = re.search(r"\[glossary\]\(docs/glossary\.md\):(.*?)and the rest", readme(), flags=re.S)
    assert named, "the README's link to the glossary names no terms"
    terms = [t for part in named.group(1).replace("\n", " ").split(",") for t in part.strip().split("/") if t]
    defined = [
        m.group(1)
        for m in re.finditer(r"^\*\*(.+?)\*\*\n:   ", (DOCS / "glossary.md").read_text(encoding="utf-8"), flags=re.M)
    ]
    missing = [t for t in terms if not any(re.search(rf"(^|[\s,(]){re.escape(t)}($|[\s,)])", d) for d in defined)]
    assert len(terms) >= 10, terms
    assert not missing, f"glossary terms {missing} are not defined (defined: {defined})"


def test_the_readme_links_every_page_of_the_sites_navigation():
    """The README is the way into the documentation on GitHub as on the site: each page mkdocs.yml's
    nav lists (but the site's own home page) has a link from it."""
    nav = re.findall(
        r"^\s*-\s+(?:[^:\n]+:\s+)?([\w/.-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(encoding="utf-8"), re.M
    )
    assert len(nav) >= 15, nav
    linked = {u.partition("#")[0] for u in LINK.findall(readme())}
    missing = [page for page in nav if page != "index.md" and f"docs/{page}" not in linked]
    assert not missing, f"pages without a link from the README: {missing}"
