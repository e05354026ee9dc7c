"""``treesim serve`` and ``treesim worker``: the service's commands.

They are added to the ``treesim`` command line through the ``treesim.commands`` entry point
(``pyproject.toml``), so :mod:`treesim` stays free of web code. Flags override the
``TREESIM_*`` environment (:class:`treesim.service.settings.Settings`).
"""

from __future__ import annotations

import argparse
import importlib.util
import ipaddress
from typing import Any

from treesim.cli._options import whole_number
from treesim.errors import InvalidParameterError

__all__ = ["register", "require_service_extra", "settings_from_args"]

#: Flag destination → Settings field, for the flags that are settings.
_SETTING_FLAGS = ("host", "port", "data_dir", "database_url", "workers", "executor", "scheduler")


#: The importable modules the ``service`` extra installs (``pyproject.toml``).
SERVICE_MODULES = (
    "fastapi",
    "uvicorn",
    "sqlalchemy",
    "alembic",
    "pydantic_settings",
    "prometheus_client",
    "jsonschema",
)


def require_service_extra(command: str) -> None:
    """Raise a clear error when the web stack is not installed (``pip install treesim``
    gives the library and the command line only)."""
    missing = [m for m in SERVICE_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        raise InvalidParameterError(
            f"treesim {command} needs the service extra, which is not installed (missing: "
            f"{', '.join(missing)}): pip install 'treesim[service]'"
        )


def settings_from_args(args: argparse.Namespace) -> Any:
    """Settings from the environment, overridden by the flags given."""
    require_service_extra(getattr(args, "command", None) or "serve")
    from pydantic import ValidationError

    from .settings import Settings

    given = {k: getattr(args, k) for k in _SETTING_FLAGS if getattr(args, k, None) is not None}
    try:
        return Settings(**given)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"]) or "settings"
        env = Settings.env_names().get(where, "")
        raise InvalidParameterError(
            f"{where}{f' ({env} or its flag)' if env else ''}: {err['msg']}"
        ) from None


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cmd_serve(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    tokenless = settings.api_token is None and settings.tokens_file is None
    if not is_loopback(settings.host) and tokenless and not args.insecure:
        raise InvalidParameterError(
            f"refusing to serve on {settings.host} without TREESIM_API_TOKEN or "
            "TREESIM_TOKENS_FILE: anyone who "
            "reaches the port could run jobs and read results. Set a token, or give --insecure"
        )
    import uvicorn

    from .app import create_app

    app = create_app(settings)
    uvicorn.run(
        app, host=settings.host, port=settings.port, log_level=args.log_level, access_log=False
    )
    return 0


def cmd_worker(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    if settings.workers < 1:
        raise InvalidParameterError("a worker needs --workers 1 or more")
    if settings.executor == "dask" and not settings.scheduler:
        raise InvalidParameterError("--executor dask needs --scheduler tcp://HOST:8786")
    from .jobs.worker import run_worker

    return run_worker(settings)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data-dir",
        metavar="DIR",
        help="uploads, results and the SQLite job store (TREESIM_DATA_DIR; default ./treesim-data)",
    )
    p.add_argument(
        "--database-url",
        metavar="URL",
        help="job store, e.g. postgresql://user:pass@host/db (TREESIM_DATABASE_URL; "
        "default sqlite in the data folder)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``serve`` and ``worker`` to ``treesim``'s parser."""
    s = sub.add_parser(
        "serve",
        help="run the HTTP service (API, job store and an embedded worker)",
        description="Serve treesim over HTTP: uploads, the processes run/reconstruct/scan/"
        "compare as jobs, results and reports (OpenAPI at /docs, a jobs page at /). "
        "Settings come from TREESIM_* environment variables; flags override them.",
    )
    s.add_argument("--host", help="address to bind (TREESIM_HOST; default 127.0.0.1)")
    s.add_argument("--port", type=whole_number(1), help="port (TREESIM_PORT; default 8000)")
    _common(s)
    s.add_argument(
        "--workers",
        type=whole_number(0),
        metavar="N",
        help="jobs the embedded worker runs at once; 0: the API alone (TREESIM_WORKERS; default 1)",
    )
    s.add_argument(
        "--insecure",
        action="store_true",
        help="allow a non-loopback --host without TREESIM_API_TOKEN",
    )
    s.add_argument(
        "--log-level",
        default="info",
        choices=["critical", "error", "warning", "info", "debug"],
        help="server log level (default info)",
    )
    s.set_defaults(func=cmd_serve)

    w = sub.add_parser(
        "worker",
        help="run jobs from a service's job store (several may share one Postgres database)",
        description="Claim jobs from the job store and run each in its own process (or on a "
        "Dask cluster) until stopped (Ctrl-C or SIGTERM hands running jobs back). Every "
        "worker of one service needs the same data folder (a shared file system) and "
        "database.",
    )
    _common(w)
    w.add_argument(
        "--workers",
        type=whole_number(0),
        metavar="N",
        help="jobs run at once (TREESIM_WORKERS; default 1)",
    )
    w.add_argument(
        "--executor",
        choices=["local", "dask"],
        help="local: a child process per job; dask: on a Dask cluster (TREESIM_EXECUTOR)",
    )
    w.add_argument(
        "--scheduler",
        metavar="ADDR",
        help="Dask scheduler address, e.g. tcp://scheduler:8786 (TREESIM_SCHEDULER)",
    )
    w.set_defaults(func=cmd_worker)
