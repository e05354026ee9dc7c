"""Every Python example in the manual (``docs/**/*.md``) and the README runs.

One test per block, named ``PAGE:LINE``. The blocks of one page run in order, in one
namespace and one fresh temporary working directory of their own, so a page can build on
what its earlier blocks defined and wrote; a block run alone (``-k``) first runs the blocks
above it. A block opts out only with ``<!-- skip-example: REASON -->`` on the line before
its fence, and the reason is shown. Examples may not reach the network (a connection to
anything but this machine fails) nor the project's shared data (absent from a user's
clone): the bundled sample tree is reachable through the package,
``importlib.resources.files("treesim") / "data" / "coffee_tree"``.
"""

from __future__ import annotations

import ipaddress
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from .examples import FORBIDDEN, Example, all_examples, examples_of

EXAMPLES = all_examples()


@dataclass
class _PageRun:
    """What the blocks of one page have run so far."""

    cwd: Path
    namespace: dict = field(default_factory=lambda: {"__name__": "__docs_example__"})
    done: int = 0  # blocks of the page run so far, in order
    failed: str | None = None  # the id of an earlier block that failed


_RUNS: dict[Path, _PageRun] = {}


class NetworkUsed(RuntimeError):
    """An example tried to reach another machine."""


def _local_only(real_connect):
    def connect(sock, address):
        host = address[0] if isinstance(address, tuple) else None
        if host is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
            try:
                local = ipaddress.ip_address(host).is_loopback
            except ValueError:
                local = host == "localhost"
            if not local:
                raise NetworkUsed(f"a docs example may not use the network (connect to {host})")
        return real_connect(sock, address)

    return connect


def _run(ex: Example, run: _PageRun, monkeypatch: pytest.MonkeyPatch) -> None:
    with monkeypatch.context() as m:
        m.chdir(run.cwd)
        m.setenv("MPLBACKEND", "Agg")
        m.setattr(socket.socket, "connect", _local_only(socket.socket.connect))
        m.setattr(sys, "argv", [ex.id])
        exec(ex.compiled(), run.namespace)


@pytest.mark.slow
@pytest.mark.parametrize("ex", EXAMPLES, ids=[ex.id for ex in EXAMPLES])
def test_example_runs(ex: Example, tmp_path_factory, monkeypatch):
    assert not FORBIDDEN[0].search(ex.code), f"{ex.id} uses {FORBIDDEN[1]}"
    run = _RUNS.get(ex.page)
    if run is None:
        run = _RUNS[ex.page] = _PageRun(tmp_path_factory.mktemp(ex.page.stem))
    blocks = examples_of(ex.page)
    index = next(i for i, b in enumerate(blocks) if b.line == ex.line)
    # the blocks above this one, not run yet (this one was selected alone)
    for before in blocks[run.done : index]:
        if before.skip is None and run.failed is None:
            try:
                _run(before, run, monkeypatch)
            except Exception:
                run.failed = before.id
        run.done += 1
    if run.done > index:
        pytest.fail(f"{ex.id} ran already in this session; run the page's blocks in order")
    run.done = index + 1
    if ex.skip is not None:
        pytest.skip(f"{ex.id}: skip-example: {ex.skip}")
    if run.failed is not None:
        pytest.fail(f"{ex.id} builds on {run.failed}, which failed")
    try:
        _run(ex, run, monkeypatch)
    except BaseException:
        run.failed = ex.id
        raise


def test_examples_are_found():
    # the parser finds blocks (a parser that found none would pass every page)
    text = "\n".join(
        [
            "# page",
            "```python",
            "x = 1",
            "```",
            "```toml",
            "```python",
            "```",
            "<!-- skip-example: needs a scanner in the field -->",
            "```python",
            "raise SystemExit",
            "```",
            "- a list:",
            "",
            "    ```python",
            "    y = x + 1",
            "    ```",
        ]
    )
    found = examples_of(Path("page.md"), text)
    assert [(e.line, e.first, e.code, e.skip) for e in found] == [
        (2, 3, "x = 1\n", None),
        (9, 10, "raise SystemExit\n", "needs a scanner in the field"),
        (14, 15, "y = x + 1\n", None),
    ]


def test_a_skip_needs_a_reason():
    from .examples import ExampleSyntaxError

    with pytest.raises(ExampleSyntaxError, match="needs a reason"):
        examples_of(Path("p.md"), "<!-- skip-example: -->\n```python\nx = 1\n```\n")
    with pytest.raises(ExampleSyntaxError, match="never closed"):
        examples_of(Path("p.md"), "```python\nx = 1\n")


def test_a_traceback_names_the_page_and_line(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("# p\n\n```python\nx = 1\nraise ValueError(x)\n```\n")
    (ex,) = examples_of(page)
    with pytest.raises(ValueError) as info:
        exec(ex.compiled(), {})
    frame = info.traceback[-1]
    assert (Path(str(frame.path)), frame.lineno + 1) == (page, 5)


def test_the_network_is_refused(monkeypatch):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        with monkeypatch.context() as m:
            m.setattr(socket.socket, "connect", _local_only(socket.socket.connect))
            with pytest.raises(NetworkUsed):
                s.connect(("192.0.2.1", 80))  # TEST-NET-1: never reached, refused first
    finally:
        s.close()


def test_the_bundled_sample_is_reachable_through_the_package():
    # what the examples are told to use instead of the shared data
    from importlib.resources import files

    sample = files("treesim") / "data" / "coffee_tree"
    assert (sample / "cloud.txt").is_file()
    assert (sample / "QSM_treeqsm_v2.4.1_cylinders.csv").is_file()
