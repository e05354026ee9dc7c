"""The manual's generated parts: text between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``.

A benchmark that owns a measured table writes it into a page of the manual (by default
``docs/validation.md``), so the figures a reader sees are the ones a script printed, never
typed in by hand. ``recording`` does the same for a benchmark whose figures are its printout:
what it prints inside the ``with`` block becomes the part, headed by the command, the date
and the machine.
"""

from __future__ import annotations

import contextlib
import io
import os
import platform
import sys
from collections.abc import Iterator
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The page that holds every measured table (the manual's validation page).
VALIDATION = ROOT / "docs" / "validation.md"


def markers(name: str) -> tuple[str, str]:
    """The begin and end markers of the part called ``name``."""
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def replace_between(doc_text: str, name: str, body: str, where: str = "the page") -> str:
    """``doc_text`` with what lies between ``name``'s markers replaced by ``body``."""
    begin, end = markers(name)
    if begin not in doc_text or end not in doc_text:
        raise SystemExit(f"{where} has no {begin} ... {end} markers")
    head, rest = doc_text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{body}\n{end}{tail}"


def write_part(name: str, body: str, page: Path = VALIDATION) -> None:
    """Replace ``name``'s part of ``page`` with ``body``."""
    text = page.read_text(encoding="utf-8")
    page.write_text(replace_between(text, name, body, str(page)), encoding="utf-8")


def machine() -> str:
    """The machine a measurement ran on, as the parts name it."""
    cpu = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip() + ", "
                break
    return (
        f"{cpu}{platform.machine()} with {os.cpu_count()} cores, Python {platform.python_version()}"
    )


class _Tee(io.TextIOBase):
    """Writes to the terminal and keeps a copy."""

    def __init__(self, out: io.TextIOBase) -> None:
        self.out, self.copy = out, io.StringIO()

    def write(self, s: str) -> int:
        self.copy.write(s)
        return self.out.write(s)

    def flush(self) -> None:
        self.out.flush()


@contextlib.contextmanager
def recording(name: str | None, script: str, page: Path = VALIDATION) -> Iterator[None]:
    """Print as usual; with a ``name``, also write the printout into ``page``'s part ``name``.

    The part holds a line saying which command measured it, when and on what, then the
    printout as a text block. Nothing is written when the block raises.
    """
    if name is None:
        yield
        return
    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield
    command = " ".join([f"python benchmarks/{script}", *sys.argv[1:]])
    head = f"`{command}` printed this on {date.today()}, {machine()}:"
    text = "\n".join(line.rstrip() for line in tee.copy.getvalue().rstrip().splitlines())
    write_part(name, f"{head}\n\n```text\n{text}\n```", page)
    print(f"wrote {page.relative_to(ROOT)}'s {name} part")


def from_argv(base: str) -> str | None:
    """Take ``--docs`` out of ``sys.argv``; the part it names, or None without it.

    For a benchmark whose own parser knows no ``--docs``: the part is ``base`` followed by
    the other arguments (``bench_leaves.py --step-deg 0.04 --docs`` writes
    ``bench-leaves-step-deg-0.04``), so that each way of running it has a part of its own.
    """
    if "--docs" not in sys.argv[1:]:
        return None
    sys.argv = [a for a in sys.argv if a != "--docs"]
    slug = "-".join(a.lstrip("-").replace("/", "-") for a in sys.argv[1:])
    return f"{base}-{slug}" if slug else base
