"""The README's generated parts: text between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``.

A benchmark that owns a README table writes it here, so the figures a reader sees are the
ones a script printed, never typed in by hand.
"""

from __future__ import annotations

from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def markers(name: str) -> tuple[str, str]:
    """The begin and end markers of the README part called ``name``."""
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def replace_between(doc_text: str, name: str, body: str) -> str:
    """``doc_text`` with what lies between ``name``'s markers replaced by ``body``."""
    begin, end = markers(name)
    if begin not in doc_text or end not in doc_text:
        raise SystemExit(f"README.md has no {begin} ... {end} markers")
    head, rest = doc_text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{body}\n{end}{tail}"


def write_part(name: str, body: str, readme: Path = README) -> None:
    """Replace ``name``'s part of ``readme`` with ``body``."""
    readme.write_text(replace_between(readme.read_text(encoding="utf-8"), name, body), "utf-8")
