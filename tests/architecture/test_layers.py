"""The import graph of ``pipeline/`` (installed as ``treesim``): no cycle, and every arrow
points down the layers.

Reads every import of every module (function-local ones included) with ``ast``; nothing
is imported. The layers, bottom to top (docs/install.md, "The repository"):

* the base: ``errors``, ``_version``, ``_system``, ``_process``, ``_lazy``, ``atomic``,
  ``jsonio``, ``frame``, ``cloud``, ``scene``, ``geometry``, ``io``, ``params``;
* the stages, side by side: ``scan``, ``compare``, ``reconstruct``, ``models``; none imports
  another, except ``reconstruct → models`` (cylinders to mesh) and ``scan → models`` (the
  cylinder table a swaying tree is read from);
* ``report``, above ``compare``;
* ``steps``, ``run``, ``plot``, ``batch``, ``sweep``, ``executors``, ``plan``, ``twin``: one
  stage on files, one tree, a plot of trees, many trees, a grid of settings on trees,
  where they run, where to scan, a plot made from a field cloud;
* ``cli``, on top. The facade (``pipeline/__init__.py``) is imported by nobody inside.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "pipeline"

#: The base layer, bottom first: a base module imports only those listed before it.
BASE_ORDER = [
    "errors",
    "_version",
    "_system",
    "_process",
    "_lazy",
    "atomic",
    "jsonio",
    "frame",
    "cloud",
    "scene",
    "geometry",
    "params",
    "io",
]
BASE = set(BASE_ORDER)
STAGES = {"scan", "compare", "reconstruct", "models"}
LAYER = {
    **{m: 0 for m in BASE},
    **{m: 1 for m in STAGES},
    "report": 2,
    "steps": 3,
    "run": 3,
    "batch": 3,
    "sweep": 3,
    "executors": 3,
    "plot": 3,
    "plan": 3,
    "twin": 3,
    "cli": 4,
}
#: The allowed arrows between stages.
STAGE_ARROWS = {("reconstruct", "models"), ("scan", "models")}
#: Order inside the top library layer: a batch runs trees on executors; a sweep runs its
#: points through the batch's engine; steps are the single stages on files, beside run; a
#: plot scans its trees station by station through steps, and the batch runs plots;
#: a plan scans plots to verify itself; a twin makes a plot from a field cloud, its trees
#: reconstructed through the batch.
TOP_ORDER = ["executors", "steps", "run", "plot", "batch", "sweep", "plan", "twin"]
WEB = {"fastapi", "starlette", "uvicorn", "pydantic", "pydantic_settings", "sqlalchemy"}


def _module_name(path: Path) -> str:
    """The installed name of a module under pipeline/ (the folder is the package treesim)."""
    parts = ["treesim", *path.relative_to(PKG).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _path(name: str) -> Path:
    """The path (without suffix) of the installed module name ``name`` under pipeline/."""
    return PKG.joinpath(*name.split(".")[1:])


def _is_package(name: str) -> bool:
    return (_path(name) / "__init__.py").exists()


def _exists(name: str) -> bool:
    if name.split(".")[0] != "treesim":
        return False
    p = _path(name)
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


def _imports() -> dict[str, set[str]]:
    """module -> the pipeline modules it imports (anywhere in its body)."""
    graph: dict[str, set[str]] = defaultdict(set)
    for path in sorted(PKG.rglob("*.py")):
        mod = _module_name(path)
        package = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
        graph[mod]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                for a in node.names:
                    graph[mod].add(a.name)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    graph[mod].add(sub if _exists(sub) else target)
            elif (
                isinstance(node, ast.Call)
                and getattr(node.func, "attr", "") == "import_module"
                and node.args
                and isinstance(node.args[0], ast.JoinedStr)
            ):
                graph[mod].add(f"{mod}.*")  # cli's command modules: its own children
    return graph


GRAPH = _imports()


def _top(name: str) -> str | None:
    parts = name.split(".")
    if parts[0] != "treesim":
        return None
    return parts[1] if len(parts) > 1 else ""


def test_the_graph_is_read():
    assert "treesim.run" in GRAPH and "treesim.cli.scan" in GRAPH
    assert "treesim.params" in GRAPH["treesim.run"]


def test_no_import_of_web_libraries():
    bad = [(m, t) for m, ts in GRAPH.items() for t in ts if t.split(".")[0] in WEB]
    assert not bad, f"the library imports web code: {bad}"


def test_nobody_inside_imports_the_facade():
    bad = [m for m, ts in GRAPH.items() if "treesim" in ts and m != "treesim"]
    assert not bad, f"these import the facade (pipeline/__init__.py, treesim): {bad}"


def _arrow_ok(src: str, dst: str) -> bool:
    if src == dst or dst == "":
        return src == dst
    if src not in LAYER or dst not in LAYER:
        return False
    if LAYER[src] == 0 and LAYER[dst] == 0:
        return BASE_ORDER.index(dst) < BASE_ORDER.index(src)
    if LAYER[src] == 1 and LAYER[dst] == 1:
        return (src, dst) in STAGE_ARROWS
    if src == "report":
        return LAYER[dst] == 0 or dst == "compare"
    if LAYER[src] == 3 and LAYER[dst] == 3:
        return TOP_ORDER.index(dst) < TOP_ORDER.index(src)
    return LAYER[dst] < LAYER[src]


def test_every_arrow_points_down():
    bad = []
    for mod, targets in GRAPH.items():
        src = _top(mod)
        if not src:
            continue  # the facade may import everything
        for t in targets:
            dst = _top(t)
            if dst is None or dst == src:
                continue
            if not _arrow_ok(src, dst):
                bad.append(f"{mod} -> {t}")
    assert not bad, "imports against the layers:\n" + "\n".join(sorted(bad))


def test_every_module_has_a_layer():
    tops = {_top(m) for m in GRAPH} - {""}
    assert tops <= set(LAYER) | {"data"}, f"modules outside the layer map: {tops - set(LAYER)}"


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    found, state, stack = [], {}, []

    def visit(n: str) -> None:
        state[n] = 1
        stack.append(n)
        for m in sorted(edges.get(n, ())):
            if state.get(m) == 1:
                found.append(stack[stack.index(m) :] + [m])
            elif m not in state:
                visit(m)
        stack.pop()
        state[n] = 2

    for n in sorted(edges):
        if n not in state:
            visit(n)
    return found


def test_no_cycle_between_layers_or_packages():
    edges: dict[str, set[str]] = defaultdict(set)
    for mod, targets in GRAPH.items():
        src = _top(mod)
        for t in targets:
            dst = _top(t)
            if src and dst and dst != src:
                edges[src].add(dst)
    assert not _cycles(edges), _cycles(edges)


def test_no_cycle_between_modules():
    """Module to module, a package's ``__init__`` importing its own children excepted."""
    edges: dict[str, set[str]] = defaultdict(set)
    for mod, targets in GRAPH.items():
        for t in targets:
            if not t.startswith("treesim") or t == mod or t.endswith(".*"):
                continue
            if _is_package(mod) and t.startswith(mod + "."):
                continue
            edges[mod].add(t)
    # a child importing its own package's __init__ is a cycle only if the __init__ imports
    # it back, which the exemption above hides: forbid it outright
    upward = [
        (m, t)
        for m, ts in edges.items()
        for t in ts
        if _is_package(t) and m.startswith(t + ".") and not m.endswith(".__main__")
    ]
    assert not upward, f"modules importing their own package's __init__: {upward}"
    assert not _cycles(edges), _cycles(edges)


@pytest.mark.parametrize(
    "src, dst, ok",
    [
        ("scan", "compare", False),
        ("compare", "scan", False),
        ("reconstruct", "models", True),
        ("models", "reconstruct", False),
        ("report", "compare", True),
        ("report", "scan", False),
        ("io", "scan", False),
        ("cloud", "errors", True),
        ("errors", "cloud", False),
        ("run", "cli", False),
        ("cli", "run", True),
        ("batch", "run", True),
        ("run", "batch", False),
    ],
)
def test_the_rule_itself(src, dst, ok):
    assert _arrow_ok(src, dst) is ok


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}})
    assert not _cycles({"a": {"b"}, "b": {"c"}, "c": set()})
