"""Find the Python examples of the manual and the README, and the rule that skips one.

An example is a fenced block opened by a line of three backticks and ``python`` (nothing
else on the line), closed by three backticks at the same indentation. A block opts out
only with ``<!-- skip-example: REASON -->`` on the line directly before its fence; the
reason is required and is shown when the test skips.
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

_FENCE_OPEN = re.compile(r"^(?P<indent>[ \t]*)```python[ \t]*$")
_SKIP = re.compile(r"^[ \t]*<!--\s*skip-example:(?P<reason>.*?)-->[ \t]*$")
#: What an example may not reach: the project's shared data is absent from a user's clone.
FORBIDDEN = (re.compile(r"shared/data|shared\\data"), "the project's shared data")


class ExampleSyntaxError(ValueError):
    """A page's fences cannot be read (an unclosed block, an empty skip reason)."""


@dataclass(frozen=True)
class Example:
    """One fenced Python block of a page.

    Parameters
    ----------
    page : Path
        The Markdown file.
    line : int
        The 1-based line of the opening fence.
    first : int
        The 1-based line of the block's first line of code.
    code : str
        The code, dedented to the fence's indentation.
    skip : str or None
        The reason given by a skip marker on the line before the fence, or None.
    """

    page: Path
    line: int
    first: int
    code: str
    skip: str | None

    @property
    def id(self) -> str:
        """``PAGE:LINE``, the page relative to the repository."""
        return f"{self.page.relative_to(ROOT).as_posix()}:{self.line}"

    def compiled(self):
        """The code compiled under the page's name, padded so its lines are the page's.

        A traceback then names the Markdown file and the line in it, and shows that line.
        """
        padded = "\n" * (self.first - 1) + self.code
        return compile(padded, str(self.page), "exec", dont_inherit=True)


def pages() -> list[Path]:
    """Every Markdown page under ``docs/`` and the README, in a stable order."""
    return sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]


def examples_of(page: Path, text: str | None = None) -> list[Example]:
    """The Python blocks of one page, in order.

    Parameters
    ----------
    page : Path
        The Markdown file (read unless ``text`` is given).
    text : str, optional
        The page's text, for tests of this parser.

    Returns
    -------
    list of Example
        Every ``python`` block, skipped ones included.

    Raises
    ------
    ExampleSyntaxError
        A block is never closed, or a skip marker gives no reason.
    """
    lines = (page.read_text(encoding="utf-8") if text is None else text).splitlines()
    found: list[Example] = []
    i = 0
    in_other_fence: str | None = None
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if in_other_fence is not None:
            # a ```python line inside another fence (a Markdown sample) is not an example
            if stripped == in_other_fence:
                in_other_fence = None
            i += 1
            continue
        m = _FENCE_OPEN.match(line)
        if m is None:
            if stripped.startswith("```"):
                in_other_fence = "```"
            i += 1
            continue
        indent = m.group("indent")
        end = next(
            (j for j in range(i + 1, len(lines)) if lines[j].rstrip() == f"{indent}```"), None
        )
        if end is None:
            raise ExampleSyntaxError(f"{page}:{i + 1}: a python block is never closed")
        skip = None
        if i > 0 and (s := _SKIP.match(lines[i - 1])):
            skip = s.group("reason").strip()
            if not skip:
                raise ExampleSyntaxError(
                    f"{page}:{i}: skip-example needs a reason: <!-- skip-example: why -->"
                )
        body = textwrap.dedent("\n".join(ln[len(indent) :] for ln in lines[i + 1 : end]))
        found.append(Example(page, i + 1, i + 2, body + "\n", skip))
        i = end + 1
    return found


def all_examples() -> list[Example]:
    """Every Python example of the manual and the README."""
    return [ex for page in pages() for ex in examples_of(page)]
