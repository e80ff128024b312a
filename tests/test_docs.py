"""Every document the code or the docs name exists, and every cited section of docs/math.md.

Scanned: the Python files of app/, estimation/, bench/, tests/ and scripts/, the Markdown
files of docs/ and README.md. A reference is any name ending in ``.md`` (``docs/x.md``,
``x.md``, ``../x.md``). It resolves when it names an existing file, with the exact case, in
the repository: relative to the repository root, to the referring file's folder or to docs/.
A citation ``math.md section N`` (or ``sections N-M``) needs a heading ``N.`` in docs/math.md.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MATH = ROOT / "docs" / "math.md"
PY_FOLDERS = ("app", "estimation", "bench", "tests", "scripts")
THIS = Path(__file__).resolve()  # names documents as patterns and examples, not as references

# Documents outside the repository on purpose: the C-MAPSS data set's own description,
# shipped with the data beside the repository (tests/support/paths.py, CMAPSS).
EXTERNAL = {"SOURCE.md"}
# Names the code used before the project had its own documents: MATH.md is docs/math.md,
# UPLOAD.md is docs/upload-format.md.
OLD_NAMES = {"MATH.md", "UPLOAD.md"}

REFERENCE = re.compile(r"(?<![\w.-])((?:\.{1,2}/)*[\w./-]*?[\w-]+\.md)(?![\w])")
SECTION = re.compile(r"math\.md`?[\s#*]+sections?[\s#*]+(\d+(?:\s*(?:-|–|,|and|to)\s*\d+)*)")
HEADING = re.compile(r"^#{1,6}\s+(\d+)\.\s", re.MULTILINE)


def scanned_files() -> Iterator[Path]:
    for folder in PY_FOLDERS:
        base = ROOT / folder
        if base.is_dir():
            yield from (p for p in sorted(base.rglob("*.py")) if p.resolve() != THIS)
    yield from sorted((ROOT / "docs").rglob("*.md"))
    yield ROOT / "README.md"


def references() -> list[tuple[Path, int, str]]:
    """(file, line, reference) for every document named in the scanned files."""
    found = []
    for path in scanned_files():
        text = path.read_text(encoding="utf-8")
        for match in REFERENCE.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            found.append((path, line, match.group(1)))
    return found


def _exists_exactly(path: Path) -> bool:
    """A file of exactly this name (a case-insensitive file system would find MATH.md too)."""
    return path.is_file() and path.name in os.listdir(path.parent)


def resolves(source: Path, ref: str) -> bool:
    if Path(ref).name in EXTERNAL:
        return True
    if ref.startswith(("./", "../")):
        candidates = [source.parent / ref]
    else:
        candidates = [ROOT / ref, source.parent / ref, ROOT / "docs" / ref]
    for candidate in candidates:
        resolved = candidate.resolve()
        if resolved.is_relative_to(ROOT) and _exists_exactly(resolved):
            return True
    return False


def _where(source: Path, line: int, ref: str) -> str:
    return f"{source.relative_to(ROOT)}:{line}: {ref}"


def test_documents_named_in_code_and_docs_exist() -> None:
    refs = references()
    assert any(ref == "docs/upload-format.md" for _s, _l, ref in refs), "the scan finds nothing"
    missing = [
        _where(source, line, ref)
        for source, line, ref in refs
        if Path(ref).name not in OLD_NAMES and not resolves(source, ref)
    ]
    assert not missing, "documents named but not in the repository:\n" + "\n".join(missing)


def test_old_document_names_are_gone() -> None:
    old = [
        _where(source, line, ref)
        for source, line, ref in references()
        if Path(ref).name in OLD_NAMES and not resolves(source, ref)
    ]
    assert not old, "cite docs/math.md and docs/upload-format.md instead of:\n" + "\n".join(old)


def expand(spec: str) -> list[int]:
    """Section numbers of a citation: 2-5 gives 2, 3, 4, 5; "2, 4" and "2 and 4" give 2, 4."""
    out: list[int] = []
    for part in re.split(r"\s*(?:,|and)\s*", re.sub(r"\s*(?:–|to)\s*", "-", spec)):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def cited_sections() -> list[tuple[Path, int, int]]:
    """(file, line, section) for every ``math.md section N`` citation; ranges expanded."""
    cited = []
    for path in scanned_files():
        text = path.read_text(encoding="utf-8")
        for match in SECTION.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            cited.extend((path, line, n) for n in expand(match.group(1)))
    return cited


def test_math_sections_are_numbered_as_cited() -> None:
    numbers = [int(n) for n in HEADING.findall(MATH.read_text(encoding="utf-8"))]
    assert numbers[:8] == list(range(1, 9)), "docs/math.md keeps sections 1-8 in this order"
    assert numbers == list(range(1, len(numbers) + 1)), "sections are numbered 1, 2, 3, ..."
    missing = [
        f"{source.relative_to(ROOT)}:{line}: section {n}"
        for source, line, n in cited_sections()
        if n not in numbers
    ]
    assert not missing, "docs/math.md has no such section:\n" + "\n".join(missing)


@pytest.mark.parametrize(
    ("text", "sections"),
    [
        ("(docs/math.md section 3)", [3]),
        ("docs/math.md sections 2-3):", [2, 3]),
        ("`math.md` sections 2-5 (seeds", [2, 3, 4, 5]),
        ("docs/math.md section 4, last paragraph", [4]),
        ("math.md\n    # section 8", [8]),
    ],
)
def test_section_citations_are_read(text: str, sections: list[int]) -> None:
    assert [n for m in SECTION.finditer(text) for n in expand(m.group(1))] == sections
