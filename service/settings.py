"""The service's settings, typed: ``TREESIM_*`` environment variables, then command-line flags.

Every setting is a field of :class:`Settings`; its environment variable is ``TREESIM_`` and
the field's name in capitals (``data_dir`` → ``TREESIM_DATA_DIR``). ``treesim serve`` and
``treesim worker`` pass their flags as keyword arguments, which win over the environment.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["ENV_PREFIX", "Settings"]

ENV_PREFIX = "TREESIM_"


class Settings(BaseSettings):
    """What a treesim service process needs to know: where its data and job store are, who
    may call it, and how it runs jobs."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, extra="ignore", frozen=True)

    host: str = Field(
        "127.0.0.1",
        min_length=1,
        description="address treesim serve binds (a non-loopback one needs a token)",
    )
    port: int = Field(8000, ge=1, le=65535, description="port treesim serve listens on")
    data_dir: Path = Field(
        Path("treesim-data"),
        description="folder for uploads, job results and the default SQLite job store "
        "(shared by every worker of one service)",
    )
    database_url: str | None = Field(
        None,
        description="job store URL (postgresql://user:pass@host/db for several machines); "
        "default: a SQLite file treesim.db in the data folder",
    )
    api_token: SecretStr | None = Field(
        None,
        description="if set, every /v1 request must send 'Authorization: Bearer <token>'",
    )
    tokens_file: Path | None = Field(
        None,
        description="a TOML file of named users: [name] token_sha256 = '<hex>', role = "
        "'user' or 'admin'; each user sees only their own uploads and jobs, an admin all "
        "(api_token, if set too, is one more admin)",
    )
    metrics_open: bool = Field(
        False,
        description="serve /metrics to anyone; off: /metrics needs an admin's token when "
        "a token is set",
    )
    max_upload_bytes: int = Field(
        4 * 1024**3, gt=0, description="largest upload accepted, in bytes (larger: 413)"
    )
    min_free_mb: float = Field(
        500.0,
        ge=0,
        description="free space the data folder's disk must keep, in MiB: below it /readyz "
        "answers 503 (0: no floor)",
    )
    upload_stall_s: float = Field(
        60.0,
        gt=0,
        le=3600,
        description="an upload whose body sends no bytes for this long is refused (408) and "
        "its partial file removed (s)",
    )
    job_time_limit_s: float = Field(
        6 * 3600.0, gt=0, description="a job running longer than this is stopped and failed (s)"
    )
    max_attempts: int = Field(
        3,
        ge=1,
        le=100,
        description="attempts per job: a job whose process crashed or whose worker died is "
        "retried until it has started this many times, then failed",
    )
    lease_s: float = Field(
        30.0,
        ge=2.0,
        description="a worker renews its claim on a running job at least this often; a job "
        "whose lease ran out is taken up again (s)",
    )
    workers: int = Field(
        1,
        ge=0,
        le=256,
        description="jobs this process runs at once (serve: its embedded worker; 0: the API alone)",
    )
    job_threads: int = Field(
        0, ge=0, description="threads per job (0: the machine's cores divided by workers)"
    )
    executor: Literal["local", "dask"] = Field(
        "local",
        description="where a job's compute runs: local (a child process per job) or dask",
    )
    scheduler: str | None = Field(
        None, description="the Dask scheduler's address (tcp://host:8786) for executor dask"
    )
    poll_interval_s: float = Field(
        1.0,
        gt=0,
        le=60,
        description="how often a worker looks for new jobs and reports progress (s)",
    )
    heartbeat_file: Path | None = Field(
        None,
        description="a worker touches this file every poll (a container healthcheck reads its age)",
    )
    allow_remote_hrefs: bool = Field(
        False,
        description="an execute request's input may name a file on another host by href "
        "(the service downloads it as an upload, within max_upload_bytes); off: only this "
        "service's own uploads and job results",
    )
    remote_href_hosts: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="with allow_remote_hrefs: hosts (names or addresses, comma-separated) "
        "whose hrefs may be fetched although they resolve to a loopback, link-local, "
        "private or multicast address (a lab's file server); any other such href is "
        "refused (422), so that a request cannot make the service read its own network",
    )
    remote_href_timeout_s: float = Field(
        60.0,
        gt=0,
        le=3600,
        description="with allow_remote_hrefs: a remote href's download (connect, redirects "
        "and body) must end within this many seconds, else it is refused (s)",
    )
    cors_origins: list[str] = Field(
        default_factory=list,
        description="origins allowed to call the API from a browser (CORS off when empty)",
    )

    @field_validator("data_dir")
    @classmethod
    def _absolute(cls, v: Path) -> Path:
        return v.expanduser().resolve()

    @field_validator("remote_href_hosts", mode="before")
    @classmethod
    def _host_list(cls, v: object) -> object:
        # the environment's text: comma-separated (or a JSON list); names compared lowercase
        if isinstance(v, str):
            text = v.strip()
            if text.startswith("["):
                import json

                v = json.loads(text)
            else:
                v = text.split(",")
        if isinstance(v, list | tuple):
            return [str(h).strip().lower().strip("[]") for h in v if str(h).strip()]
        return v

    @field_validator(
        "database_url", "scheduler", "api_token", "heartbeat_file", "tokens_file", mode="before"
    )
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        # compose files pass ${VAR:-} through as an empty string: that means "not set"
        return None if isinstance(v, str) and not v.strip() else v

    @property
    def db_url(self) -> str:
        """The job store's SQLAlchemy URL (the SQLite default resolved)."""
        if self.database_url:
            url = self.database_url
            # plain postgres URLs mean the psycopg 3 driver (the one treesim installs)
            for prefix in ("postgresql://", "postgres://"):
                if url.startswith(prefix):
                    return "postgresql+psycopg://" + url[len(prefix) :]
            return url
        return f"sqlite:///{self.data_dir / 'treesim.db'}"

    @property
    def threads_per_job(self) -> int:
        """Threads each job uses: :attr:`job_threads`, or cores // workers."""
        if self.job_threads:
            return self.job_threads
        from treesim._system import cpu_count

        return max(1, cpu_count() // max(1, self.workers))

    def token(self) -> str | None:
        return self.api_token.get_secret_value() if self.api_token else None

    @classmethod
    def env_names(cls) -> dict[str, str]:
        """Field name → its environment variable."""
        return {name: ENV_PREFIX + name.upper() for name in cls.model_fields}
