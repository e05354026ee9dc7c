"""``docker/compose.yaml`` and ``docker/Dockerfile`` without a Docker engine: the compose
file is valid against the Compose Specification's JSON Schema (kept in the repo), and it
agrees with the code: its commands parse with the real ``treesim`` parser, every
``TREESIM_*`` variable is a setting, the ports, the data volume, the healthchecks' routes
and heartbeat file, the token and the profiles are what the service and the image use."""

from __future__ import annotations

import copy
import hashlib
import json
import re
import shlex
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml", reason="needs pyyaml (dev extra)")
jsonschema = pytest.importorskip("jsonschema")

DOCKER = Path(__file__).resolve().parents[2] / "docker"
COMPOSE = yaml.safe_load((DOCKER / "compose.yaml").read_text())
COMPOSE_TEXT = (DOCKER / "compose.yaml").read_text()
DOCKERFILE = (DOCKER / "Dockerfile").read_text()
SERVICES = COMPOSE["services"]
#: Services that run the treesim command (the image's entrypoint unchanged).
TREESIM_SERVICES = [n for n, s in SERVICES.items() if "entrypoint" not in s and "build" in s]


def _validator():
    schema = json.loads((DOCKER / "compose-spec.json").read_text())
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def _dockerfile(instruction: str) -> list[str]:
    """The arguments of every line starting with ``instruction`` (continuations joined)."""
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE)
    return [ln.split(None, 1)[1] for ln in text.splitlines() if ln.startswith(instruction + " ")]


def _env(service: str) -> dict[str, str]:
    return {k: str(v) for k, v in (SERVICES[service].get("environment") or {}).items()}


def test_the_vendored_schema_is_the_recorded_one():
    digest = hashlib.sha256((DOCKER / "compose-spec.json").read_bytes()).hexdigest()
    assert digest in (DOCKER / "compose-spec.PROVENANCE.md").read_text()


def test_compose_file_is_valid_against_the_compose_spec():
    errors = sorted(_validator().iter_errors(COMPOSE), key=lambda e: e.json_path)
    assert not errors, [f"{e.json_path}: {e.message}" for e in errors]


def test_the_schema_would_catch_a_mistake():
    bad = copy.deepcopy(COMPOSE)
    bad["services"]["api"]["comand"] = ["serve"]
    assert list(_validator().iter_errors(bad))
    bad = copy.deepcopy(COMPOSE)
    bad["services"]["worker"]["depends_on"]["api"]["condition"] = "when_ready"
    assert list(_validator().iter_errors(bad))


def test_the_roles_are_there():
    assert {"api", "worker"} <= set(TREESIM_SERVICES)
    profiles = {p for s in SERVICES.values() for p in s.get("profiles", [])}
    assert profiles == {"postgres", "dask"}
    assert "postgres" in SERVICES["postgres"]["profiles"]
    assert SERVICES["postgres"]["image"].startswith("postgres:16")
    for name in ("dask-scheduler", "dask-worker"):
        assert SERVICES[name]["profiles"] == ["dask"]
        assert SERVICES[name]["entrypoint"][0] == "dask"


@pytest.mark.parametrize("service", ["api", "worker"])
def test_commands_parse_with_the_real_cli(service):
    from treesim.cli import build_parser

    cmd = SERVICES[service]["command"]
    argv = shlex.split(cmd) if isinstance(cmd, str) else list(cmd)
    args = build_parser().parse_args(argv)
    assert args.command == argv[0]
    assert callable(args.func)


def test_every_treesim_variable_is_a_setting():
    from treesim.service.settings import Settings

    known = set(Settings.env_names().values())
    named = set(re.findall(r"\b(TREESIM_[A-Z_]+)\b", COMPOSE_TEXT))
    assert named, "compose.yaml sets no TREESIM_* variable"
    assert named <= known, f"not settings: {sorted(named - known)}"


def test_the_token_is_required_and_the_api_listens_on_all_addresses():
    # serve refuses a public host without a token: compose must require one
    assert re.search(r"TREESIM_API_TOKEN: \$\{TREESIM_API_TOKEN:\?", COMPOSE_TEXT)
    from treesim.cli import build_parser

    args = build_parser().parse_args(SERVICES["api"]["command"])
    assert args.host == "0.0.0.0" and not args.insecure


def test_ports_agree_with_the_api_and_the_image():
    from treesim.cli import build_parser

    args = build_parser().parse_args(SERVICES["api"]["command"])
    published = SERVICES["api"]["ports"]
    assert len(published) == 1
    host_ip, host_port, container_port = published[0].split(":")
    assert host_ip == "127.0.0.1", "publish on loopback by default; a proxy does TLS"
    assert int(container_port) == args.port
    assert str(args.port) in " ".join(_dockerfile("EXPOSE"))


def test_every_treesim_service_mounts_the_data_volume_at_the_data_dir():
    data_dir = next(
        v for line in _dockerfile("ENV") for k, v in re.findall(r"(\w+)=(\S+)", line)
        if k == "TREESIM_DATA_DIR"
    )  # fmt: skip
    assert data_dir in " ".join(_dockerfile("VOLUME"))
    for name in [*TREESIM_SERVICES, "dask-worker"]:
        mounts = SERVICES[name].get("volumes", [])
        assert f"treesim-data:{data_dir}" in mounts, name
        assert _env(name).get("TREESIM_DATA_DIR", data_dir) == data_dir, name
    assert "treesim-data" in COMPOSE["volumes"]


def _python_check(test: list[str]) -> str:
    assert test[:3] == ["CMD", "python", "-c"], test
    return test[3]


def test_healthchecks_ask_routes_the_app_answers(tmp_path):
    from fastapi.testclient import TestClient

    from treesim.service.app import create_app
    from treesim.service.settings import Settings

    app = create_app(Settings(data_dir=tmp_path, workers=0, database_url=None))
    client = TestClient(app)  # no lifespan: what a fresh container's API answers first
    checks = [_python_check(SERVICES["api"]["healthcheck"]["test"])]
    checks.append(_dockerfile("HEALTHCHECK")[0])
    for code in checks:
        urls = re.findall(r"http://127\.0\.0\.1:(\d+)(/[\w/]*)", code)
        assert urls, code
        for port, path in urls:
            assert client.get(path).status_code == 200, path
            assert port == "8000"


def test_the_worker_healthcheck_reads_the_heartbeat_file_it_sets():
    beat = _env("worker")["TREESIM_HEARTBEAT_FILE"]
    code = _python_check(SERVICES["worker"]["healthcheck"]["test"])
    assert repr(beat) in code
    from treesim.service.settings import Settings

    s = Settings(heartbeat_file=beat)
    assert str(s.heartbeat_file) == beat


def test_profiles_point_at_their_services():
    text = COMPOSE_TEXT
    url = re.search(r"postgresql://(\w+):(\w+)@([\w-]+):(\d+)/(\w+)", text)
    assert url, "the postgres profile's URL is documented in compose.yaml"
    user, password, host, port, db = url.groups()
    env = SERVICES["postgres"]["environment"]
    assert (env["POSTGRES_USER"], env["POSTGRES_PASSWORD"], env["POSTGRES_DB"]) == (
        user,
        password,
        db,
    )
    assert host in SERVICES and port == "5432"
    scheduler = re.search(r"TREESIM_SCHEDULER=tcp://([\w-]+):(\d+)", text)
    assert scheduler and scheduler.group(1) in SERVICES
    assert f"tcp://{scheduler.group(1)}:{scheduler.group(2)}" in SERVICES["dask-worker"]["command"]
    assert scheduler.group(2) in SERVICES["dask-scheduler"]["command"]


def _image_extras() -> list[str]:
    """The extras the image's ``pip install ".[...]"`` asks for."""
    installs = " ".join(line for line in _dockerfile("RUN") if "pip install" in line)
    wanted = re.findall(r"\.\[([\w,]+)\]", installs)
    assert len(wanted) == 1, installs
    return wanted[0].split(",")


def test_the_image_asks_for_extras_that_exist_and_what_compose_runs_needs():
    import tomllib

    from packaging.requirements import Requirement

    pyproject = tomllib.loads((DOCKER.parent / "pyproject.toml").read_text())
    extras = pyproject["project"]["optional-dependencies"]
    wanted = _image_extras()
    assert set(wanted) <= set(extras), sorted(set(wanted) - set(extras))
    # the distributions the image gets, and what each role in compose.yaml runs on: the
    # API and workers (the service extra), the postgres profile's URL (a psycopg driver),
    # the dask profile's `dask scheduler` / `dask worker` (distributed)
    got = {Requirement(r).name.lower() for e in wanted for r in extras[e]}
    assert {"fastapi", "uvicorn", "sqlalchemy", "alembic"} <= got, got
    assert "postgresql://" in COMPOSE_TEXT and "psycopg" in got, got
    dask = [Requirement(r) for e in wanted for r in extras[e] if Requirement(r).name == "dask"]
    assert dask and "distributed" in dask[0].extras, dask
    assert _dockerfile("FROM")[0].startswith("python:3.11")
    assert any(line.strip() != "root" for line in _dockerfile("USER"))


def _copied_tree(dst: Path) -> Path:
    """What the image's COPY lines put into its WORKDIR, copied from this checkout."""
    import shutil

    for args in _dockerfile("COPY"):
        *sources, target = args.split()
        for src in sources:
            path = DOCKER.parent / src
            to = dst / target / path.name if target.endswith("/") else dst / target
            if path.is_dir():
                shutil.copytree(path, to, ignore=shutil.ignore_patterns("__pycache__"))
            else:
                to.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(path, to)
    return dst


def test_the_image_builds_from_what_it_copies_and_its_entrypoint_runs_treesim(tmp_path):
    # no Docker engine here: the image's steps done by hand. Its COPY lines' files alone
    # build the package (pip, as its RUN line), the wheel installs the ENTRYPOINT's script,
    # and that script's target, imported from the wheel, runs the image's CMD and the
    # compose services' commands
    import configparser
    import subprocess
    import sys
    import zipfile

    src = _copied_tree(tmp_path / "image")
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(src)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = tmp_path.glob("treesim-*.whl")
    with zipfile.ZipFile(wheel) as z:
        info = next(n for n in z.namelist() if n.endswith(".dist-info/entry_points.txt"))
        meta = z.read(info.replace("entry_points.txt", "METADATA")).decode()
        points = configparser.ConfigParser()
        points.read_string(z.read(info).decode())
        z.extractall(tmp_path / "site")
    (script,) = json.loads(_dockerfile("ENTRYPOINT")[0])
    module, func = points["console_scripts"][script].split(":")
    assert set(_image_extras()) <= set(re.findall(r"^Provides-Extra: (\S+)", meta, re.M))
    # the wheel's treesim first on the path (the checkout's editable install comes after)
    run = f"""
import sys
sys.path.insert(0, {str(tmp_path / "site")!r})
import importlib
mod = importlib.import_module({module!r})
assert mod.__file__.startswith({str(tmp_path / "site")!r}), mod.__file__
sys.exit(getattr(mod, {func!r})(sys.argv[1:]))
"""
    cmd = json.loads(_dockerfile("CMD")[-1])
    for argv in (cmd, *([*SERVICES[s]["command"], "--help"] for s in ("api", "worker"))):
        done = subprocess.run(
            [sys.executable, "-c", run, *argv], capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, (argv, done.stderr[-2000:])
        assert "usage: treesim" in done.stdout, (argv, done.stdout[:500])


def test_references_between_services_and_volumes_resolve():
    """What the schema cannot check: every depends_on names a service, every named volume a
    service mounts is declared."""
    declared = set(COMPOSE.get("volumes") or {})
    for name, svc in SERVICES.items():
        deps = svc.get("depends_on") or []
        for dep in deps if isinstance(deps, list) else deps.keys():
            assert dep in SERVICES, f"{name} depends on unknown service {dep!r}"
        for mount in svc.get("volumes") or []:
            source = mount.split(":", 1)[0] if isinstance(mount, str) else mount.get("source")
            if source and not source.startswith((".", "/", "~", "$")):
                assert source in declared, f"{name} mounts undeclared volume {source!r}"


def test_the_kernels_are_warmed_by_the_user_that_runs_them_into_a_cache_it_can_write():
    # numba caches only in a folder it can write: kernels compiled by root beside the
    # package are passed over by the image's user, which would compile them again (tens
    # of seconds) in every new container. So the warm-up runs as the image's last USER,
    # with NUMBA_CACHE_DIR set (for every later process too) to a folder chowned to it
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    warm = next(i for i, ln in enumerate(lines) if "warm_edge_model()" in ln)
    users = [ln.split()[1] for ln in lines if ln.startswith("USER ")]
    before = [ln.split()[1] for ln in lines[:warm] if ln.startswith("USER ")]
    assert users and before and before[-1] == users[-1], (before, users)
    envs = [ln for ln in lines[:warm] if ln.startswith("ENV ") and "NUMBA_CACHE_DIR=" in ln]
    assert envs, "NUMBA_CACHE_DIR is not set before the warm-up"
    cache = re.search(r"NUMBA_CACHE_DIR=(\S+)", envs[-1]).group(1)
    chown = [ln for ln in lines[:warm] if f"chown {users[-1]}" in ln and cache in ln]
    assert chown, f"{cache} is not given to {users[-1]} before the warm-up"
