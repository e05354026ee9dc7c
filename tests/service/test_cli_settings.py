"""``treesim serve`` / ``treesim worker`` and the TREESIM_* settings: security by default,
clear errors for bad settings, flags over the environment, docs that match."""

from __future__ import annotations

import subprocess
import sys

import pytest

from treesim.service.cli import is_loopback
from treesim.service.settings import Settings

from .conftest import REPO, service_env


def _treesim(*args: str, env: dict[str, str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "treesim.cli", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.10", "::", "example.org"])
def test_serve_refuses_a_public_host_without_a_token(host, tmp_path):
    r = _treesim("serve", "--host", host, env=service_env(tmp_path / "d"))
    assert r.returncode != 0
    assert "TREESIM_API_TOKEN" in r.stderr and "--insecure" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "d" / "treesim.db").exists()  # nothing started


def test_loopback_hosts():
    assert all(is_loopback(h) for h in ("127.0.0.1", "127.1.2.3", "::1", "localhost"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "::", "10.0.0.1", "localhost.evil"))


@pytest.mark.parametrize(
    "env, flags, expect",
    [
        ({"TREESIM_LEASE_S": "0.5"}, [], "TREESIM_LEASE_S"),
        ({"TREESIM_MAX_UPLOAD_BYTES": "lots"}, [], "TREESIM_MAX_UPLOAD_BYTES"),
        ({}, ["--workers", "-1"], "workers"),
        ({"TREESIM_EXECUTOR": "threads"}, [], "TREESIM_EXECUTOR"),
    ],
)
def test_bad_settings_are_one_clear_line(env, flags, expect, tmp_path):
    r = _treesim("worker", *flags, env=service_env(tmp_path / "d", **env))
    assert r.returncode != 0
    assert expect in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_worker_checks_its_executor(tmp_path):
    r = _treesim("worker", "--executor", "dask", env=service_env(tmp_path / "d"))
    assert r.returncode != 0 and "--scheduler" in r.stderr
    r = _treesim("worker", "--workers", "0", env=service_env(tmp_path / "d"))
    assert r.returncode != 0 and "--workers 1" in r.stderr


def test_flags_override_the_environment(tmp_path, monkeypatch):
    import argparse

    from treesim.service.cli import settings_from_args

    monkeypatch.setenv("TREESIM_WORKERS", "3")
    monkeypatch.setenv("TREESIM_DATA_DIR", str(tmp_path / "env"))
    args = argparse.Namespace(data_dir=str(tmp_path / "flag"), database_url=None, workers=None)
    s = settings_from_args(args)
    assert s.workers == 3 and s.data_dir == (tmp_path / "flag").resolve()
    args.workers = 0
    assert settings_from_args(args).workers == 0


def test_settings_defaults_and_urls(tmp_path, monkeypatch):
    for k in Settings.env_names().values():
        monkeypatch.delenv(k, raising=False)
    s = Settings(data_dir=tmp_path)
    assert s.db_url == f"sqlite:///{tmp_path / 'treesim.db'}"
    assert s.token() is None and s.max_upload_bytes == 4 * 1024**3
    pg = Settings(data_dir=tmp_path, database_url="postgresql://u:p@h/db")
    assert pg.db_url == "postgresql+psycopg://u:p@h/db"
    monkeypatch.setenv("TREESIM_API_TOKEN", "")  # compose passes ${VAR:-} as empty: unset
    assert Settings(data_dir=tmp_path).token() is None
    monkeypatch.setenv("TREESIM_API_TOKEN", "t0k")
    s = Settings(data_dir=tmp_path)
    assert s.token() == "t0k" and "t0k" not in repr(s)  # a secret never printed


def test_every_setting_is_documented_in_the_manual():
    page = (REPO / "docs" / "guides" / "service.md").read_text(encoding="utf-8")
    missing = [env for env in Settings.env_names().values() if f"`{env}`" not in page]
    assert missing == [], f"docs/guides/service.md's settings table lacks {missing}"


def test_the_flags_help_states_the_settings_defaults():
    from treesim.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if hasattr(a, "choices") and a.choices)
    serve = sub.choices["serve"]
    helps = {a.dest: a.help for a in serve._actions}
    fields = Settings.model_fields
    assert f"default {fields['host'].default}" in helps["host"]
    assert f"default {fields['port'].default}" in helps["port"]
    assert f"default {fields['workers'].default}" in helps["workers"]
    assert f"default ./{fields['data_dir'].default}" in helps["data_dir"]
    for dest in ("host", "port", "workers", "data_dir", "database_url"):
        assert Settings.env_names()[dest] in helps[dest], dest
