"""The README is a landing page and docs/ the reference: every page listed, every link and anchor resolves.

Markdown is read with markdown-it-py (CommonMark, as GitHub renders it, with its
tables), not with regular expressions: a ``#`` line in a code block is no
heading, a link in a table cell is a link. Anchors follow GitHub's rule for
headings: the heading's text in lower case, every character but letters,
digits, ``_``, ``-`` and spaces dropped, spaces as ``-``, and ``-1``, ``-2``
... on a repeated one.
"""

from __future__ import annotations

import argparse
import re
import shlex
from functools import cache
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from markdown_it import MarkdownIt
from markdown_it.token import Token

from compd.cli import COMMANDS, build_parser

ROOT = Path(__file__).parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
INDEX = DOCS / "README.md"
PAGES = sorted(path for path in DOCS.glob("*.md") if path != INDEX)
EVERY_PAGE = [README, INDEX, *PAGES]


def _ids(paths: list[Path]) -> list[str]:
    return [str(path.relative_to(ROOT)) for path in paths]


@cache
def tokens(path: Path) -> list[Token]:
    """``path`` parsed as GitHub parses Markdown (CommonMark with tables and strikethrough)."""
    parser = MarkdownIt("commonmark").enable(["table", "strikethrough"])
    return parser.parse(path.read_text())


def heading_text(inline: Token) -> str:
    """A heading's text as GitHub slugs it: its words and code, without the markup."""
    return "".join(
        child.content
        for child in inline.children or []
        if child.type in ("text", "code_inline", "html_inline")
    )


def slug(text: str) -> str:
    """GitHub's anchor of a heading whose text is ``text`` (before a repeat's ``-N``)."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


@cache
def headings(path: Path) -> list[tuple[int, str, str]]:
    """Each heading of ``path``: its level, its text and its anchor, repeats numbered as GitHub does."""
    found: list[tuple[int, str, str]] = []
    seen: dict[str, int] = {}
    stream = tokens(path)
    for index, token in enumerate(stream):
        if token.type == "heading_open":
            text = heading_text(stream[index + 1])
            base = slug(text)
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.append((int(token.tag[1]), text, base if count == 0 else f"{base}-{count}"))
    return found


def links(path: Path) -> list[str]:
    """Every link and image target in ``path``, as written."""
    targets = []
    for token in tokens(path):
        for child in token.children or []:
            if child.type == "link_open":
                targets.append(str(child.attrs["href"]))
            elif child.type == "image":
                targets.append(str(child.attrs["src"]))
    return targets


def local_links(path: Path) -> list[tuple[Path, str]]:
    """The links of ``path`` into this repository: the file each names and its anchor ("" for none)."""
    found = []
    for target in links(path):
        parts = urlsplit(target)
        if parts.scheme or parts.netloc:
            continue  # a web address: not this repository's to check
        file = (path.parent / unquote(parts.path)).resolve() if parts.path else path
        found.append((file, unquote(parts.fragment)))
    return found


def sh_commands(path: Path) -> list[list[str]]:
    """The ``compd`` command lines in ``path``'s ```sh blocks, as words (comments left out)."""
    lines = []
    for token in tokens(path):
        if token.type == "fence" and token.info.strip() == "sh":
            text = token.content.replace("\\\n", " ")
            for line in text.splitlines():
                words = shlex.split(line, comments=True)
                command: list[str] = []
                for word in [*words, "&&"]:
                    if word in ("&&", "||", ";", "|"):
                        if command[:1] == ["compd"]:
                            lines.append(command)
                        command = []
                    else:
                        command.append(word)
    return lines


def test_the_readme_is_a_landing_page_under_300_lines() -> None:
    """The README stays short: what compd is, the quick start, the loop in brief, where to read on."""
    count = len(README.read_text().splitlines())
    assert count < 300, f"README.md has {count} lines: move reference text into docs/"


def test_the_readme_links_to_every_docs_page() -> None:
    """Every page in docs/, and the index, is one click from the README."""
    linked = {file for file, _ in local_links(README)}
    missing = [path.name for path in [INDEX, *PAGES] if path.resolve() not in linked]
    assert not missing, f"README.md links to none of docs/{missing}: add them to 'Where to read on'"


def test_the_docs_index_lists_every_page() -> None:
    """docs/README.md, the table of contents of the reference, links to each page in docs/."""
    assert PAGES, "docs/ has no pages"
    linked = {file for file, _ in local_links(INDEX)}
    missing = [path.name for path in PAGES if path.resolve() not in linked]
    assert not missing, f"docs/README.md does not list {missing}: add a row for each"


@pytest.mark.parametrize("page", PAGES, ids=_ids(PAGES))
def test_each_docs_page_opens_with_a_table_of_contents(page: Path) -> None:
    """Before its first section, a page links to each of its sections (## and ###), in order."""
    sections = [(text, anchor) for level, text, anchor in headings(page) if level in (2, 3)]
    assert sections, f"{page.name} has no sections (## headings) for a table of contents"
    stream = tokens(page)
    first = next(t.map[0] for t in stream if t.type == "heading_open" and t.tag == "h2" and t.map)
    contents = [
        str(child.attrs["href"])[1:]
        for token in stream
        if token.type == "inline" and token.map and token.map[0] < first
        for child in token.children or []
        if child.type == "link_open" and str(child.attrs["href"]).startswith("#")
    ]
    wanted = [anchor for _, anchor in sections]
    assert contents == wanted, (
        f"{page.name}: the table of contents at its top should link, in order, to {wanted}; "
        f"it links to {contents}"
    )


@pytest.mark.parametrize("page", EVERY_PAGE, ids=_ids(EVERY_PAGE))
def test_every_relative_link_and_anchor_resolves(page: Path) -> None:
    """A link names a file of the repository, and its #anchor a heading of that file."""
    broken = []
    for file, anchor in local_links(page):
        if not file.exists():
            broken.append(f"{file.relative_to(ROOT.resolve())} does not exist")
        elif anchor and file.suffix == ".md":
            anchors = {found for _, _, found in headings(file)}
            if anchor not in anchors:
                broken.append(f"{file.name} has no heading with the anchor #{anchor}")
        elif anchor:
            broken.append(f"#{anchor} points into {file.name}, which has no headings")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


@pytest.mark.parametrize("page", EVERY_PAGE, ids=_ids(EVERY_PAGE))
def test_no_page_cites_an_issue_number(page: Path) -> None:
    """Users' pages say what was meant, not "issue 35": an issue number means nothing to a reader."""
    cited = re.findall(r"\bissues?\s+#?\d+", page.read_text(), re.I)
    assert not cited, f"{page.relative_to(ROOT)} cites {cited}: say what is meant instead"


def _subcommands(name: str) -> set[str]:
    """The sub-commands of ``compd NAME`` (``model load``, ``fleet list``...), empty if it has none."""
    parser = build_parser(COMMANDS[name][0])
    command = next(
        action.choices[name]
        for action in parser._actions
        if isinstance(action, argparse._SubParsersAction)
    )
    return {
        choice
        for action in command._actions
        if isinstance(action, argparse._SubParsersAction)
        for choice in action.choices
    }


@pytest.mark.parametrize("page", EVERY_PAGE, ids=_ids(EVERY_PAGE))
def test_every_command_in_a_sh_block_is_a_real_command(page: Path) -> None:
    """Each ``compd COMMAND [SUBCOMMAND]`` a reader may copy from a ```sh block is one compd has."""
    unknown = []
    for words in sh_commands(page):
        name = words[1] if len(words) > 1 else ""
        if name.startswith("-"):
            continue  # compd --version, compd --help
        if name not in COMMANDS:
            unknown.append(" ".join(words[:2]))
            continue
        subcommand = words[2] if len(words) > 2 and not words[2].startswith("-") else None
        subcommands = _subcommands(name)
        if subcommand is not None and subcommands and subcommand not in subcommands:
            unknown.append(" ".join(words[:3]))
    assert not unknown, (
        f"{page.relative_to(ROOT)} names commands compd does not have: {unknown} "
        f"(compd help lists them)"
    )


def test_the_sh_blocks_are_read() -> None:
    """The command check sees the README's walk-through: it is not vacuous."""
    named = {words[1] for words in sh_commands(README) if len(words) > 1}
    assert {"run", "fit", "compare", "diagnose", "extend", "report", "model"} <= named, named
