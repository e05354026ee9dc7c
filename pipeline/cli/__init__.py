"""The ``treesim`` command line: one module per command, options from the parameter model.

Every command ends with a one-line error and a non-zero exit on bad input (exit 1 for
treesim's own errors, 2 for bad usage, 130 when interrupted); set ``TREESIM_DEBUG=1``
to see a traceback for unexpected errors.

A new command is a module here with ``register(subparsers)`` and its ``cmd_*`` function,
added to :data:`COMMANDS`; its options that set parameters come from
:mod:`treesim.cli._options` (``param_option``), never typed by hand. Packages above the
library add commands through the ``treesim.commands`` entry point group (a
``register(subparsers)`` callable): the service's ``serve`` and ``worker`` come that way,
so this package never imports web code.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

from ..errors import TreesimError

#: The command modules, in the order ``treesim --help`` lists them, with the line each
#: registers there (a test checks that they agree): ``treesim --help`` and ``treesim
#: COMMAND --help`` import only the modules of what they show.
SUMMARIES = {
    "scan": "scan meshes with a virtual TLS scanner",
    "plot": "forest plots: generate a stand, make a twin of a field plot, scan a plot",
    "model": "tree models: procedural trees, QSM cylinder tables to meshes",
    "reconstruct": "reconstruct a tree mesh from a field point cloud (QSM, Poisson or BPA)",
    "compare": "AVOHD comparison of a cloud with a reference mesh or cloud",
    "report": "plots, report.json and an offline HTML page from a comparison",
    "run": "the whole loop on one tree: reconstruct, scan, compare, report",
    "batch": "run the loop on many trees (resumable; local processes or Dask)",
    "sweep": "run a grid of settings on trees: time, memory, accuracy, Pareto fronts",
    "plan": "plan scan stations for a plot or a tree: fewest stations to a per-tree goal",
    "validate": "check a simulated plot scan against the field scan",
    "demo": "run the whole loop on the bundled sample tree and print the report's path",
}
COMMANDS = tuple(SUMMARIES)

#: Entry point group through which other packages add commands (``register(subparsers)``).
PLUGIN_GROUP = "treesim.commands"

__all__ = ["COMMANDS", "PLUGIN_GROUP", "SUMMARIES", "build_parser", "main"]


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole ``treesim`` parser, every command registered.

    ``only``: register that command alone with its options (``""``: none); the others
    are listed by name and :data:`SUMMARIES` line, without importing their modules.
    Commands from other packages (:data:`PLUGIN_GROUP`) are registered unless ``only``
    names a built-in command: that command's run needs none of them, and looking them
    up reads every installed distribution's metadata (about 20 ms at each start).
    """
    from .._version import __version__
    from ._options import Parser

    p = Parser(prog="treesim", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--version", action="version", version=f"treesim {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in COMMANDS:
        if only is None or name == only:
            importlib.import_module(f"{__name__}.{name}").register(sub)
        else:
            sub.add_parser(name, help=SUMMARIES[name])
    if not only:
        from importlib.metadata import entry_points

        for ep in sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
            ep.load()(sub)
    return p


def _command(argv: Sequence[str] | None) -> str:
    """The built-in command that ``argv`` runs (its first word), or ``""``."""
    words = sys.argv[1:] if argv is None else argv
    first = next((w for w in words if not w.startswith("-")), "")
    return first if first in SUMMARIES else ""


def _watch_interrupts() -> tuple[Callable[[], bool], Callable[[], None]]:
    """Note a Ctrl-C as it happens (it still raises KeyboardInterrupt): some libraries
    catch the KeyboardInterrupt raised inside their callbacks and raise their own error
    instead (lazrs, compressing a LAZ file, says 'Failed to call write'); the command
    must still end as interrupted (130). Installed only over Python's own handler, in
    the main thread. Returns (whether one was seen, put Python's handler back)."""
    seen = [False]

    def on_sigint(signum: int, frame: Any) -> None:
        seen[0] = True
        signal.signal(signal.SIGINT, signal.default_int_handler)
        raise KeyboardInterrupt

    mine = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if mine:
        signal.signal(signal.SIGINT, on_sigint)

    def restore() -> None:
        if mine and signal.getsignal(signal.SIGINT) is on_sigint:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    return (lambda: seen[0]), restore


def _interrupted() -> int:
    """Say that the command was interrupted; its exit status (130, as a shell's)."""
    print("treesim: interrupted", file=sys.stderr)
    return 130


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(only=_command(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    interrupted, restore = _watch_interrupts()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return _interrupted()
    except TreesimError as exc:
        if interrupted():  # a library turned the Ctrl-C into its own error
            return _interrupted()
        print(f"treesim: error: {exc}", file=sys.stderr)
        return 1
    except MemoryError:
        print(
            "treesim: error: out of memory; coarsen the resolution or lower --chunk-rays",
            file=sys.stderr,
        )
        return 1
    except Exception as exc:  # never a traceback for users
        if interrupted():
            return _interrupted()
        if os.environ.get("TREESIM_DEBUG"):
            raise
        print(
            f"treesim: internal error: {type(exc).__name__}: {exc} "
            "(set TREESIM_DEBUG=1 for a traceback and report it)",
            file=sys.stderr,
        )
        return 3
    finally:
        restore()
