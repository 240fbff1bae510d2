"""MkDocs hook: the parts of the documentation generated from the code at build time.

- `<!-- cli-reference -->` in a page becomes the `--help` of every `torquelab` subcommand (and of
  each experiment under `torquelab experiment`), rendered from `app.cli.build_parser()`.
- `<!-- lesson: KEY -->` becomes the purpose and the steps of that lesson (`app.live.curriculum.LESSONS`),
  as the Lessons tab shows them.
- In a table row, `\\|` inside a code span is GitHub's way to keep a pipe in a cell; Python-Markdown
  keeps code spans' pipes already and would print the backslash, so the hook drops it.
- The pictures in `static/` (the package's own, written by the browser tests) are served under
  `img/`, so the pages and the README show the same files.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # this checkout's app/, whatever the environment has installed

HELP_WIDTH = "100"  # argparse wraps help to $COLUMNS: fixed, so the page does not depend on the terminal
LESSON_MARK = re.compile(r"<!-- lesson: ([a-z0-9-]+) -->")
CODE_SPAN = re.compile(r"`[^`\n]*`")


def on_files(files: Files, config) -> Files:
    """Serve static/**/*.png as img/**/*.png."""
    static = ROOT / "static"
    for path in sorted(static.rglob("*.png")):
        files.append(File.generated(config, "img/" + path.relative_to(static).as_posix(), abs_src_path=str(path)))
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Fill the generated parts of a page."""
    if "<!-- cli-reference -->" in markdown:
        markdown = markdown.replace("<!-- cli-reference -->", cli_reference())
    markdown = LESSON_MARK.sub(lambda m: lesson_steps(m.group(1)), markdown)
    return "\n".join(_table_pipes(line) for line in markdown.split("\n"))


def _table_pipes(line: str) -> str:
    """A table row's code spans with `\\|` (GitHub's escape) as a plain `|`."""
    if not line.lstrip().startswith("|"):
        return line
    return CODE_SPAN.sub(lambda m: m.group(0).replace("\\|", "|"), line)


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _summaries(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Each subcommand's one-line help, as its parent lists it."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {a.dest: a.help or "" for a in action._choices_actions}
    return {}


def _section(level: str, name: str, summary: str, parser: argparse.ArgumentParser) -> list[str]:
    lead = [summary[:1].upper() + summary[1:].rstrip(".") + ".", ""] if summary else []
    return [f"{level} {name}", "", *lead, "```text", parser.format_help().rstrip(), "```", ""]


def cli_reference() -> str:
    """Every subcommand's help, one section each, nested subcommands as subsections."""
    from app.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_WIDTH
    try:
        root = build_parser()
        out = _section("##", "torquelab", "", root)
        summaries = _summaries(root)
        for name, sub in _subcommands(root).items():
            out += _section("##", f"torquelab {name}", summaries.get(name, ""), sub)
            for inner, parser in _subcommands(sub).items():  # (their one-line help is their parent's list)
                out += _section("###", f"torquelab {name} {inner}", "", parser)
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(out)


def lesson_steps(key: str) -> str:
    """The lesson's purpose and its numbered steps, each with its title and what to do and watch."""
    from app.live.curriculum import LESSONS

    lessons = {lesson.key: lesson for lesson in LESSONS}
    if key not in lessons:
        raise KeyError(f"no lesson {key!r} in app.live.curriculum (there are: {', '.join(lessons)})")
    lesson = lessons[key]
    out = [f"*{lesson.purpose}*", ""]
    for i, step in enumerate(lesson.steps, 1):
        out.append(f"{i}. **{step.title}.** {step.todo}")
    return "\n".join(out) + "\n"
