"""Nothing POSIX-only in the library or the command line (``pipeline/``, installed as
``treesim``), unless behind a guard with a fallback: they must import and run on Windows.

Reads every import of every module (function-local ones included) and every use of
``os``, ``signal``, ``select`` and ``subprocess`` names that Windows lacks, with ``ast``;
nothing is imported. A use is accepted when it sits

* under ``if sys.platform != "win32":`` / ``if os.name == "posix":`` (or in the ``else``
  of the Windows test), or ``if hasattr(module, "name"):``, or the same as ``x if ... else
  y``;
* in the ``try`` body of a ``try``/``except`` that catches its failure (``ImportError``
  for an import, ``AttributeError`` for an attribute) with a handler that does something:
  a handler of only ``pass`` / ``return`` / ``yield`` / ``...`` is a silent no-op (the old
  batch lock ran without a lock that way) and is not a fallback.

Windows itself is not tested here (the project's CI is Linux): this holds the line the
docs draw, that the library and the CLI do not depend on a POSIX-only module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "pipeline"

#: Standard-library modules that exist only on POSIX systems (the docs' "Availability:
#: Unix"), by their top-level name.
POSIX_MODULES = frozenset(
    {
        "fcntl",
        "termios",
        "tty",
        "pty",
        "pwd",
        "grp",
        "spwd",
        "crypt",
        "nis",
        "resource",
        "posix",
        "syslog",
        "readline",
        "curses",
        "pipes",
        "ossaudiodev",
        "_posixsubprocess",
        "_posixshmem",
    }
)

#: Names of cross-platform modules that Windows lacks.
POSIX_ATTRIBUTES = {
    "os": frozenset(
        {
            "fork",
            "forkpty",
            "register_at_fork",
            "killpg",
            "getpgid",
            "setpgid",
            "getpgrp",
            "setpgrp",
            "setsid",
            "getsid",
            "getuid",
            "geteuid",
            "getgid",
            "getegid",
            "setuid",
            "seteuid",
            "setgid",
            "setegid",
            "getgroups",
            "setgroups",
            "initgroups",
            "getresuid",
            "getresgid",
            "setresuid",
            "setresgid",
            "chown",
            "fchown",
            "lchown",
            "chroot",
            "mkfifo",
            "mknod",
            "nice",
            "getpriority",
            "setpriority",
            "sched_getaffinity",
            "sched_setaffinity",
            "getloadavg",
            "sync",
            "wait3",
            "wait4",
            "waitid",
            "WNOHANG",
            "WUNTRACED",
            "pipe2",
            "sysconf",
            "confstr",
            "pathconf",
            "fpathconf",
            "statvfs",
            "fstatvfs",
            "uname",
            "ttyname",
            "openpty",
            "ctermid",
            "posix_spawn",
            "posix_spawnp",
            "O_NOFOLLOW",
            "O_CLOEXEC",
            "O_NONBLOCK",
            "O_DIRECTORY",
        }
    ),
    "signal": frozenset(
        {
            "SIGKILL",
            "SIGHUP",
            "SIGQUIT",
            "SIGUSR1",
            "SIGUSR2",
            "SIGALRM",
            "SIGCHLD",
            "SIGCLD",
            "SIGPIPE",
            "SIGSTOP",
            "SIGCONT",
            "SIGTSTP",
            "SIGTTIN",
            "SIGTTOU",
            "SIGWINCH",
            "SIGBUS",
            "SIGTRAP",
            "SIGXCPU",
            "SIGXFSZ",
            "SIGPROF",
            "SIGVTALRM",
            "SIGSYS",
            "SIGIO",
            "SIGIOT",
            "SIGPOLL",
            "SIGURG",
            "SIGPWR",
            "SIGRTMIN",
            "SIGRTMAX",
            "alarm",
            "pause",
            "setitimer",
            "getitimer",
            "siginterrupt",
            "pthread_kill",
            "pthread_sigmask",
            "sigwait",
            "sigwaitinfo",
            "sigtimedwait",
            "sigpending",
            "SIG_BLOCK",
            "SIG_UNBLOCK",
            "SIG_SETMASK",
            "ITIMER_REAL",
            "ITIMER_VIRTUAL",
            "ITIMER_PROF",
        }
    ),
    "select": frozenset({"poll", "epoll", "kqueue", "devpoll"}),
}

#: Keyword arguments of ``subprocess`` that Windows rejects or silently ignores.
POSIX_KEYWORDS = frozenset(
    {"preexec_fn", "start_new_session", "process_group", "pass_fds", "user", "group"}
)
#: The ``subprocess`` functions that take them.
SUBPROCESS_CALLS = frozenset({"Popen", "run", "call", "check_call", "check_output"})
#: Start methods of ``multiprocessing`` that Windows lacks.
POSIX_START_METHODS = frozenset({"fork", "forkserver"})


# -- the guards --------------------------------------------------------------------------


def _platform_of(test: ast.expr) -> str | None:
    """``"posix"`` if ``test`` holds only on POSIX, ``"windows"`` if only on Windows."""
    if isinstance(test, ast.UnaryOp) and isinstance(test.op, ast.Not):
        inner = _platform_of(test.operand)
        return {"posix": "windows", "windows": "posix"}.get(inner or "")
    if isinstance(test, ast.BoolOp) and isinstance(test.op, ast.And):
        kinds = {_platform_of(v) for v in test.values} - {None}
        return kinds.pop() if len(kinds) == 1 else None
    if isinstance(test, ast.Compare) and len(test.ops) == 1:
        left, op, right = test.left, test.ops[0], test.comparators[0]
        what = ast.unparse(left)
        if not isinstance(right, ast.Constant) or not isinstance(right.value, str):
            return None
        value = right.value
        if what == "sys.platform" and value in ("win32", "cygwin"):
            windows = True
        elif what == "sys.platform" and value in ("linux", "darwin"):
            windows = False
        elif what == "os.name" and value == "nt":
            windows = True
        elif what == "os.name" and value == "posix":
            windows = False
        else:
            return None
        if isinstance(op, ast.Eq):
            return "windows" if windows else "posix"
        if isinstance(op, ast.NotEq):
            return "posix" if windows else None
        return None
    if (
        isinstance(test, ast.Call)
        and ast.unparse(test.func) == "sys.platform.startswith"
        and test.args
        and isinstance(test.args[0], ast.Constant)
    ):
        prefix = str(test.args[0].value)
        if prefix.startswith("win"):
            return "windows"
        if prefix.startswith(("linux", "darwin", "freebsd")):
            return "posix"
    return None


def _has_attr_test(test: ast.expr) -> bool:
    """``hasattr(module, "name")`` (alone or in an ``and``)."""
    if isinstance(test, ast.BoolOp) and isinstance(test.op, ast.And):
        return any(_has_attr_test(v) for v in test.values)
    return isinstance(test, ast.Call) and getattr(test.func, "id", "") == "hasattr"


def _silent(handler: ast.ExceptHandler) -> bool:
    """A handler that only passes, returns nothing or yields: no fallback."""
    for stmt in handler.body:
        if isinstance(stmt, ast.Pass):
            continue
        if isinstance(stmt, ast.Return) and stmt.value is None:
            continue
        if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Yield | ast.Constant):
            continue
        return False
    return True


def _catches(handler: ast.ExceptHandler, names: set[str]) -> bool:
    if handler.type is None:
        return True
    types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(ast.unparse(t).rsplit(".", 1)[-1] in names for t in types)


def _guarded(node: ast.AST, parents: dict[ast.AST, ast.AST], failure: set[str]) -> bool:
    """Whether ``node`` runs only where it can (see the module's docstring)."""
    child, parent = node, parents.get(node)
    while parent is not None:
        if isinstance(parent, ast.If | ast.IfExp):
            in_body = child in parent.body if isinstance(parent, ast.If) else child is parent.body
            in_else = (
                child in parent.orelse if isinstance(parent, ast.If) else child is parent.orelse
            )
            platform = _platform_of(parent.test)
            if (platform == "posix" and in_body) or (platform == "windows" and in_else):
                return True
            if in_body and _has_attr_test(parent.test):
                return True
        if isinstance(parent, ast.Try) and child in parent.body:
            if any(_catches(h, failure) and not _silent(h) for h in parent.handlers):
                return True
        child, parent = parent, parents.get(parent)
    return False


# -- the walk -----------------------------------------------------------------------------


def posix_only_uses(source: str) -> list[tuple[int, str]]:
    """``(line, what)`` for every unguarded POSIX-only use in ``source``."""
    tree = ast.parse(source)
    parents = {c: p for p in ast.walk(tree) for c in ast.iter_child_nodes(p)}
    imports = {"ImportError", "ModuleNotFoundError", "Exception", "BaseException"}
    attributes = {"AttributeError", "Exception", "BaseException"}
    found: list[tuple[int, str]] = []

    def check(node: ast.AST, what: str, failure: set[str]) -> None:
        if not _guarded(node, parents, failure):
            found.append((node.lineno, what))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in POSIX_MODULES:
                    check(node, f"import {a.name}", imports)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            top = node.module.split(".")[0]
            if top in POSIX_MODULES:
                check(node, f"from {node.module} import ...", imports)
            for a in node.names:
                if a.name in POSIX_ATTRIBUTES.get(node.module, ()):
                    check(node, f"from {node.module} import {a.name}", imports)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            if node.attr in POSIX_ATTRIBUTES.get(node.value.id, ()):
                check(node, f"{node.value.id}.{node.attr}", attributes)
        elif isinstance(node, ast.Call):
            name = getattr(node.func, "attr", getattr(node.func, "id", ""))
            for k in node.keywords if name in SUBPROCESS_CALLS else ():
                if k.arg in POSIX_KEYWORDS:
                    check(node, f"{ast.unparse(node.func)}({k.arg}=...)", attributes)
            if (
                name in ("get_context", "set_start_method")
                and node.args
                and isinstance(node.args[0], ast.Constant)
                and node.args[0].value in POSIX_START_METHODS
            ):
                check(node, f"{name}({node.args[0].value!r})", attributes)
    return found


def test_the_library_and_the_cli_use_nothing_posix_only_unguarded():
    bad = []
    for path in sorted(PKG.rglob("*.py")):
        for line, what in posix_only_uses(path.read_text(encoding="utf-8")):
            bad.append(f"{path.relative_to(PKG.parent)}:{line}: {what}")
    assert not bad, "POSIX-only, without a guard and a fallback:\n" + "\n".join(bad)


def test_the_walk_reads_every_module():
    modules = list(PKG.rglob("*.py"))
    assert (
        len(modules) > 50 and PKG / "batch.py" in modules and PKG / "cli" / "__init__.py" in modules
    )


# -- the checker itself -------------------------------------------------------------------


@pytest.mark.parametrize(
    "source",
    [
        "import fcntl\n",
        "def f():\n    import resource\n    return resource.getrusage(0)\n",
        "from termios import tcgetattr\n",
        "import os\nos.killpg(1, 9)\n",
        "import signal\nsig = signal.SIGKILL\n",
        "from signal import SIGKILL\n",
        "import subprocess\nsubprocess.Popen(['x'], start_new_session=True)\n",
        "import subprocess\nsubprocess.run(['x'], preexec_fn=print)\n",
        "import multiprocessing\nmultiprocessing.get_context('fork')\n",
        # the old batch lock: no fcntl, no lock, silently
        "def lock():\n    try:\n        import fcntl\n    except ImportError:\n"
        "        yield\n        return\n    yield\n",
        "try:\n    import pwd\nexcept ImportError:\n    pass\n",
        # a guard on the wrong side
        "import sys\nif sys.platform == 'win32':\n    import fcntl\n",
        "import os\ntry:\n    os.getuid()\nexcept ValueError:\n    uid = 0\n",
    ],
)
def test_the_checker_finds_an_unguarded_use(source):
    assert posix_only_uses(source), source


@pytest.mark.parametrize(
    "source",
    [
        "import sys\nif sys.platform != 'win32':\n    import fcntl\n",
        "import sys\nif sys.platform == 'win32':\n    import msvcrt\nelse:\n    import fcntl\n",
        "import os\nif os.name == 'posix':\n    import pwd\n",
        "import sys\nif not sys.platform.startswith('win'):\n    import termios\n",
        "try:\n    import resource\nexcept ImportError:\n    resource = None\n",
        "import os\ntry:\n    n = len(os.sched_getaffinity(0))\nexcept AttributeError:\n"
        "    n = os.cpu_count()\n",
        "import os, signal\nif hasattr(os, 'killpg'):\n    os.killpg(1, signal.SIGTERM)\n",
        "import signal\nsig = signal.SIGKILL if hasattr(signal, 'SIGKILL') else signal.SIGTERM\n",
        "import signal\nsig = getattr(signal, 'SIGKILL', signal.SIGTERM)\n",
        "from importlib import resources\n",
        "import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n",
        "import multiprocessing\nmultiprocessing.get_context('spawn')\n",
        "from importlib.metadata import entry_points\nentry_points(group='treesim')\n",
    ],
)
def test_the_checker_accepts_a_guarded_or_portable_use(source):
    assert posix_only_uses(source) == [], source
