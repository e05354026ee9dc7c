"""What ``pip install treesim`` installs: one top-level package, ``treesim`` (the library and
the command line, the service as ``treesim.service``), no web stack among the core
requirements, and every folder of the repository's packages in the wheel.

The wheel is built from this checkout (``pip wheel``, the build backend in an isolated
environment, as ``pip install .`` does), once per session.
"""

from __future__ import annotations

import email.parser
import importlib.util
import subprocess
import sys
import tomllib
import zipfile
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
#: The distributions of the web stack: only the service extra may require them.
WEB = {
    "fastapi",
    "uvicorn",
    "sqlalchemy",
    "alembic",
    "pydantic-settings",
    "pydantic",
    "prometheus-client",
    "starlette",
    "jsonschema",
}


def _folder_packages(folder: str, name: str) -> set[str]:
    """Installed names of every package (folder with ``__init__.py``) under ``folder``."""
    base = ROOT / folder
    return {
        ".".join([name, *p.parent.relative_to(base).parts])
        for p in base.rglob("__init__.py")
        if "migrations" not in p.parts
    }


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    want = _folder_packages("pipeline", "treesim") | _folder_packages("service", "treesim.service")
    assert listed == want, (
        f"pyproject.toml [tool.setuptools] packages: missing {sorted(want - listed)}, "
        f"extra {sorted(listed - want)}"
    )


def test_core_requirements_hold_no_web_stack():
    core = {_dist_name(r) for r in PYPROJECT["project"]["dependencies"]}
    assert not core & WEB, f"core requirements pull in the web stack: {sorted(core & WEB)}"
    service = {_dist_name(r) for r in PYPROJECT["project"]["optional-dependencies"]["service"]}
    assert {"fastapi", "uvicorn", "sqlalchemy", "alembic"} <= service


def _dist_name(req: str) -> str:
    name = req.split(";")[0]
    for sep in "<>=!~[ ":
        name = name.split(sep)[0]
    return name.strip().lower().replace("_", "-")


@cache
def _wheel(tmp: Path) -> Path:
    out = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if out.returncode != 0:
        pytest.fail(f"pip wheel failed:\n{out.stderr[-3000:]}")
    (whl,) = tmp.glob("treesim-*.whl")
    return whl


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    return _wheel(tmp_path_factory.mktemp("wheel"))


@pytest.mark.slow
def test_the_wheel_installs_treesim_alone_at_the_top(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    dist_info = {t for t in tops if t.endswith(".dist-info")}
    assert tops - dist_info == {"treesim"}, f"top-level names in the wheel: {sorted(tops)}"
    for must in (
        "treesim/__init__.py",
        "treesim/cli/__init__.py",
        "treesim/service/app.py",
        "treesim/service/static/index.html",
        "treesim/service/static/jobs.js",
        "treesim/service/jobs/migrations/env.py",
        "treesim/data/coffee_tree/cloud.txt",
    ):
        assert must in names, f"{must} is not in the wheel"


@pytest.mark.slow
def test_the_wheels_core_requirements_hold_no_web_stack(wheel):
    with zipfile.ZipFile(wheel) as z:
        meta_name = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        meta = email.parser.Parser().parsestr(z.read(meta_name).decode("utf-8"))
    reqs = meta.get_all("Requires-Dist") or []
    core = {_dist_name(r) for r in reqs if "extra ==" not in r}
    assert {"numpy", "open3d", "laspy", "filelock"} <= core
    assert not core & WEB, f"the wheel's core requirements hold {sorted(core & WEB)}"
    service = {_dist_name(r) for r in reqs if 'extra == "service"' in r}
    assert {"fastapi", "uvicorn", "sqlalchemy", "alembic"} <= service
    assert meta["Requires-Python"] == ">=3.11"


def test_no_module_named_pipeline_or_service_is_importable_from_outside(tmp_path):
    """Outside the checkout (the repository root is not on sys.path), only treesim."""
    code = (
        "import importlib.util as u, json; "
        "print(json.dumps([bool(u.find_spec(n)) for n in ('treesim', 'pipeline', 'service')]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[true, false, false]", out.stdout


def test_serve_without_the_service_extra_names_the_extra(monkeypatch):
    from treesim.errors import InvalidParameterError
    from treesim.service import cli

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == "fastapi" else real(n, *a)
    )
    with pytest.raises(InvalidParameterError, match=r"pip install 'treesim\[service\]'"):
        cli.require_service_extra("serve")


def test_one_version_everywhere() -> None:
    """The version the package reports, pyproject.toml's and CITATION.cff's agree."""
    import re

    from treesim._version import __version__

    root = Path(__file__).resolve().parents[2]
    project = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    cff = re.search(r"^version: (\S+)$", (root / "CITATION.cff").read_text(), re.M)
    assert cff is not None
    assert __version__ == project["version"] == cff[1]
