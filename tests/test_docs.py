"""The docs hold together: the flag reference is the configs' own, and every pointer into docs/ resolves.

Pointers in the code take three forms, `docs/page.md` (the page), `docs/page.md#anchor` and
`docs/page.md, "Heading"` (a section by its heading's text, in double or single quotes), possibly
wrapped over comment or docstring lines. Links in the Markdown pages are relative, `[text](page.md#anchor)`;
anchors are GitHub's: the heading lower-cased, punctuation but `-` and `_` dropped, spaces as `-`, and
`-1`, `-2`, ... on repeats.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

from pipeline.targets import markdown_text

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
FLAGS = DOCS / "reference" / "flags.md"

POINTER = re.compile(r"""docs/((?:[\w.-]+/)*[\w.-]+\.md)(?:#([\w-]+)|,\s*(["'])(.+?)\3)?""")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
WRAP = re.compile(r"""["']\s*\n\s*f?["']|\s*\n\s*(?:#+\s*)?""")  # string concatenation, or a line break


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def headings(page: Path) -> list[str]:
    """The text of every heading of a Markdown page, outside code blocks, Markdown markup kept."""
    found, fenced = [], False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (match := re.match(r"#{1,6} (.+)", line)):
            found.append(match.group(1).strip())
    return found


def anchors(page: Path) -> set[str]:
    """Every anchor of a page, repeats numbered as GitHub numbers them."""
    seen: Counter[str] = Counter()
    result = set()
    for heading in headings(page):
        base = slug(heading)
        result.add(f"{base}-{seen[base]}" if seen[base] else base)
        seen[base] += 1
    return result


def pointer_problems(text: str) -> list[str]:
    """Each pointer into docs/ in `text` (source code) that names no page, anchor or heading there."""
    problems = []
    for match in POINTER.finditer(WRAP.sub(" ", text.replace("\\'", "'").replace('\\"', '"'))):
        page, anchor, heading = DOCS / match.group(1), match.group(2), match.group(4)
        if not page.is_file():
            problems.append(f"{match.group(0)}: no such page")
        elif anchor and anchor not in anchors(page):
            problems.append(f"{match.group(0)}: no such anchor")
        elif heading and " ".join(heading.split()) not in {h.replace("`", "") for h in headings(page)}:
            problems.append(f"{match.group(0)}: no such heading")
    return problems


def link_problems(page: Path, text: str | None = None) -> list[str]:
    """Each relative link of a Markdown page (its `text`, or the file's) whose file or anchor does not exist; a link's
    text may wrap over lines."""
    problems, fenced, prose = [], False, []
    for line in (page.read_text(encoding="utf-8") if text is None else text).splitlines():
        if line.startswith("```"):
            fenced = not fenced
        prose.append("" if fenced or line.startswith("```") else line)
    for target in LINK.findall("\n".join(prose)):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            problems.append(f"{page.relative_to(ROOT)}: {target}: no such file")
        elif anchor and (linked.suffix != ".md" or anchor not in anchors(linked)):
            problems.append(f"{page.relative_to(ROOT)}: {target}: no such anchor")
    return problems


DATA = {"datasets", "exports", "outputs"}  # data folders the stages write, which hold no code


def sources() -> list[Path]:
    """The project's Python files, its Makefile and pyproject.toml (not .venv, .git, other hidden folders or data)."""
    here = Path(__file__).resolve()  # its examples point nowhere on purpose
    tops = [top for top in ROOT.iterdir() if not top.name.startswith(".") and top.name not in DATA]
    files = [p for top in tops for p in ([top] if top.is_file() else top.rglob("*.py")) if p.suffix == ".py"]
    project = [p for p in files if p != here and not any(part.startswith(".") for part in p.parts)]
    return [*project, ROOT / "Makefile", ROOT / "pyproject.toml"]


def test_the_flag_reference_is_generated_from_the_configs() -> None:
    """docs/reference/flags.md is `python -m pipeline.targets --markdown`'s output: `make docs` regenerates it."""
    assert FLAGS.read_text(encoding="utf-8") == markdown_text(), "docs/reference/flags.md is stale: run `make docs`"


def test_every_pointer_in_the_code_resolves() -> None:
    """Every `docs/...` pointer in a docstring, comment or help text names a page, and a section of it that exists."""
    problems = [
        f"{path.relative_to(ROOT)}: {found}" for path in sources() for found in pointer_problems(path.read_text())
    ]
    assert not problems, "\n".join(problems)


def test_every_link_in_the_docs_resolves() -> None:
    """Relative links in the READMEs and docs/**/*.md name files that exist, and anchors those pages have."""
    pages = [ROOT / "README.md", ROOT / "datasets" / "README.md", *sorted(DOCS.rglob("*.md"))]
    problems = [problem for page in pages for problem in link_problems(page)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ('see docs/benchmarks.md, "The expert" for the figures', None),
        ("(docs/benchmarks.md, 'Live\n    # view')", None),
        ("docs/benchmarks.md#the-test-suite", None),
        ("docs/concepts/dataset.md", None),
        ('docs/benchmarks.md, "No such section"', "no such heading"),
        ("docs/benchmarks.md#no-such-anchor", "no such anchor"),
        ("docs/no_such_page.md", "no such page"),
    ],
)
def test_a_pointer_is_checked_against_the_page(text: str, problem: str | None) -> None:
    """The checker finds each form, also wrapped over comment lines, and names what is missing."""
    found = pointer_problems(text)
    assert [p.split(": ")[-1] for p in found] == ([problem] if problem else [])


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("[the expert](benchmarks.md#the-expert)", None),
        ("see [the\nexpert](benchmarks.md#the-expert) there", None),
        ("see [the\nexpert](benchmarks.md#no-such-anchor) there", "no such anchor"),
        ("[a page](no_such_page.md)", "no such file"),
        ("```\n[in a code block](no_such_page.md)\n```", None),
    ],
)
def test_a_link_is_checked_also_where_its_text_wraps(text: str, problem: str | None) -> None:
    """Known answers: a link whose text runs over a line break is checked as any other; code blocks are not."""
    page = DOCS / "page.md"  # where it would live: the targets are relative to docs/
    found = link_problems(page, text)
    assert [p.split(": ")[-1] for p in found] == ([problem] if problem else [])


def test_anchors_are_githubs() -> None:
    """Known answers of GitHub's slugs, repeats numbered."""
    assert slug("The pipeline's table") == "the-pipelines-table"
    assert slug("Choosing the noise: DART") == "choosing-the-noise-dart"
    assert slug("`make record` — appending") == "make-record--appending"
    assert {"the-expert", "ray", "the-test-suite"} <= anchors(DOCS / "benchmarks.md")
    assert "measured-seeds-10001019-20-episodes-per-condition" in anchors(DOCS / "log.md")
