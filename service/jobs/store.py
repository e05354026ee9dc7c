"""The job store: uploads, jobs, workers and counters in SQL tables (SQLAlchemy Core).

SQLite (a file in the data folder, WAL mode) by default; Postgres by URL, for several
workers on several machines. The schema is created and migrated by Alembic
(``service/jobs/migrations``) when a store opens.

Jobs move ``accepted → running → successful | failed``, or to ``dismissed`` at any point
(the OGC API – Processes words). A worker takes a job with :meth:`Store.claim`, one atomic
statement on the database's clock (``FOR UPDATE SKIP LOCKED`` on Postgres, a
``BEGIN IMMEDIATE`` transaction on SQLite), which increments the job's ``attempt`` and
gives the worker a lease until ``lease_expires``. Every later write of that worker names
the attempt (``WHERE id = ? AND attempt = ? AND status = 'running'``): when no row
matches, the lease was lost (it expired and another worker took the job, or the user
dismissed it) and the worker must stop. :meth:`Store.expire_leases` hands jobs whose lease
ran out back to the queue, or fails them once they have used their attempts.

All times are seconds since the Unix epoch, taken from the database's clock (never the
workers'), stored as double precision.
"""

from __future__ import annotations

import base64
import json
import os
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from filelock import FileLock
from sqlalchemy import (
    JSON,
    BigInteger,
    Column,
    Connection,
    Engine,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    and_,
    create_engine,
    delete,
    event,
    func,
    insert,
    or_,
    select,
    text,
    update,
)
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.sql.expression import FunctionElement

__all__ = [
    "ACTIVE",
    "STATUSES",
    "Claim",
    "Store",
    "db_now",
    "jobs",
    "metadata",
    "upload_owners",
    "uploads",
]

#: Job statuses, in the OGC API – Processes vocabulary.
STATUSES = ("accepted", "running", "successful", "failed", "dismissed")
#: Statuses of a job that may still use its inputs.
ACTIVE = ("accepted", "running")

metadata = MetaData()

uploads = Table(
    "uploads",
    metadata,
    Column("id", String(36), primary_key=True),
    Column("sha256", String(64), nullable=False, unique=True),
    Column("filename", String(255), nullable=False),
    Column("format", String(16), nullable=False),
    Column("kind", String(8), nullable=False),
    Column("size_bytes", BigInteger, nullable=False),
    Column("n_points", BigInteger),
    Column("n_triangles", BigInteger),
    Column("info", JSON, nullable=False),
    Column("path", String(512), nullable=False),
    Column("created", Float(53), nullable=False),
)

jobs = Table(
    "jobs",
    metadata,
    Column("id", String(36), primary_key=True),
    Column("process", String(32), nullable=False),
    Column("status", String(16), nullable=False),
    Column("inputs", JSON, nullable=False),
    Column("parameters", JSON, nullable=False),
    Column("progress", Float(53), nullable=False),
    Column("stage", String(200)),
    Column("message", Text),
    Column("error", JSON),
    Column("attempt", Integer, nullable=False),
    Column("max_attempts", Integer, nullable=False),
    Column("time_limit_s", Float(53), nullable=False),
    Column("worker_id", String(200)),
    Column("lease_expires", Float(53)),
    Column("created", Float(53), nullable=False),
    Column("started", Float(53)),
    Column("finished", Float(53)),
    Column("updated", Float(53), nullable=False),
    Column("results", JSON),
    Column("summary", JSON),
    Column("owner", String(64)),
    # the output ids the execute request asked for (its "outputs"); NULL: every output
    Column("outputs", JSON),
    Index("ix_jobs_status_created", "status", "created"),
    Index("ix_jobs_owner", "owner"),
    Index("ix_jobs_created", "created", "id"),
)

#: Who owns an upload: each user who sent its content (uploads are stored once per content,
#: so one upload may have several owners); uploads sent while no token was set have none.
upload_owners = Table(
    "upload_owners",
    metadata,
    Column("upload_id", String(36), ForeignKey("uploads.id", ondelete="CASCADE"), primary_key=True),
    Column("owner", String(64), primary_key=True),
)

#: Which uploads and earlier jobs' results a job reads (a job's inputs, queryable).
job_inputs = Table(
    "job_inputs",
    metadata,
    Column("job_id", String(36), ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("name", String(64), primary_key=True),
    Column("upload_id", String(36), index=True),
    Column("source_job_id", String(36), index=True),
)

workers = Table(
    "workers",
    metadata,
    Column("id", String(200), primary_key=True),
    Column("hostname", String(255), nullable=False),
    Column("pid", Integer, nullable=False),
    Column("executor", String(16), nullable=False),
    Column("slots", Integer, nullable=False),
    Column("started", Float(53), nullable=False),
    Column("heartbeat", Float(53), nullable=False),
    Column("stopped", Float(53)),
)

#: Cumulative counters shared by every process (read by /metrics at scrape time).
counters = Table(
    "counters",
    metadata,
    Column("name", String(64), primary_key=True),
    Column("label", String(64), primary_key=True),
    Column("count", BigInteger, nullable=False),
    Column("total", Float(53), nullable=False),
)


class db_now(FunctionElement):  # noqa: N801 - reads as a SQL function
    """The database's clock, in seconds since the epoch (double precision)."""

    type = Float(53)
    inherit_cache = True


@compiles(db_now)
def _now_default(element: Any, compiler: Any, **kw: Any) -> str:
    return "CAST(EXTRACT(EPOCH FROM clock_timestamp()) AS DOUBLE PRECISION)"


@compiles(db_now, "sqlite")
def _now_sqlite(element: Any, compiler: Any, **kw: Any) -> str:
    return "((julianday('now') - 2440587.5) * 86400.0)"


@dataclass(frozen=True)
class Claim:
    """A job a worker has claimed: what it needs to run it and to fence its writes."""

    id: str
    attempt: int
    max_attempts: int
    process: str
    inputs: dict[str, Any]
    parameters: dict[str, Any]
    time_limit_s: float
    #: the claimant: with the attempt, it fences every write (a released attempt's number
    #: is handed out again, to another claim of another worker)
    worker_id: str = ""


def _row(r: Any) -> dict[str, Any] | None:
    return None if r is None else dict(r._mapping)


def encode_cursor(created: float, job_id: str) -> str:
    raw = json.dumps([created, job_id]).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str) -> tuple[float, str] | None:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        created, job_id = json.loads(raw)
        return float(created), str(job_id)
    except (ValueError, TypeError):
        return None


class Store:
    """The job store at ``url`` (a SQLAlchemy URL).

    Parameters
    ----------
    url : str
        ``sqlite:///path/treesim.db`` or ``postgresql+psycopg://user:pass@host/db``.
    migrate : bool
        Create or upgrade the schema now (Alembic), under a lock so that processes starting
        together migrate once.
    """

    def __init__(self, url: str, *, migrate: bool = True) -> None:
        self.url = url
        self.is_sqlite = url.startswith("sqlite")
        if self.is_sqlite:
            path = url.split("///", 1)[1] if "///" in url else ""
            if path and path != ":memory:":
                Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._sqlite_path = path
            self.engine = self._sqlite_engine(url, immediate=True)
            self.read_engine = self._sqlite_engine(url, immediate=False)
        else:
            self._sqlite_path = ""
            self.engine = create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=20)
            self.read_engine = self.engine
        # No in-process lock: every method is one database transaction, which the database
        # serialises across threads and processes alike (BEGIN IMMEDIATE on SQLite, row
        # locks on Postgres).
        if migrate:
            self.migrate()

    # -- engines and transactions ----------------------------------------------------------
    @staticmethod
    def _sqlite_engine(url: str, *, immediate: bool) -> Engine:
        engine = create_engine(
            url, connect_args={"check_same_thread": False, "timeout": 60}, pool_size=10
        )

        @event.listens_for(engine, "connect")
        def _connect(dbapi_conn: Any, _record: Any) -> None:
            dbapi_conn.isolation_level = None  # SQLAlchemy's begin event issues BEGIN
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA busy_timeout=60000")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        @event.listens_for(engine, "begin")
        def _begin(conn: Connection) -> None:
            # writers take the write lock at BEGIN, so a read-then-write transaction can
            # never fail to upgrade its lock half-way (SQLITE_BUSY_SNAPSHOT in WAL mode)
            conn.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")

        return engine

    @contextmanager
    def write(self) -> Iterator[Connection]:
        """A write transaction (SQLite: ``BEGIN IMMEDIATE``)."""
        with self.engine.begin() as conn:
            yield conn

    @contextmanager
    def read(self) -> Iterator[Connection]:
        """A read-only transaction."""
        with self.read_engine.begin() as conn:
            yield conn

    def migrate(self) -> None:
        """Create or upgrade the schema to Alembic's head, once across processes."""
        from alembic import command
        from alembic.config import Config

        cfg = Config()
        cfg.set_main_option("script_location", str(Path(__file__).parent / "migrations"))
        if self.is_sqlite and self._sqlite_path and self._sqlite_path != ":memory:":
            # An exclusive lock file beside the database, waited for without a timeout
            # (filelock: flock on POSIX, msvcrt on Windows; the OS frees it if its holder
            # dies), so that processes starting together migrate once.
            lock_path = Path(self._sqlite_path).with_suffix(".migrate.lock")
            with FileLock(lock_path):
                with self.write() as conn:
                    cfg.attributes["connection"] = conn
                    command.upgrade(cfg, "head")
            return
        with self.write() as conn:
            if not self.is_sqlite:
                conn.execute(text("SELECT pg_advisory_xact_lock(727217001)"))
            cfg.attributes["connection"] = conn
            command.upgrade(cfg, "head")

    def ping(self) -> float:
        """The database's clock (and proof that it answers)."""
        with self.read() as conn:
            return float(conn.execute(select(db_now())).scalar_one())

    def dispose(self) -> None:
        self.engine.dispose()
        if self.read_engine is not self.engine:
            self.read_engine.dispose()

    # -- uploads ---------------------------------------------------------------------------
    def add_upload(
        self,
        record: Mapping[str, Any],
        place: Callable[[], None] | None = None,
        *,
        owner: str | None = None,
    ) -> tuple[dict[str, Any], bool]:
        """Insert an upload; if the same content (sha256) is stored already, return that
        record instead. Returns ``(record, created)``. ``place()`` (which moves the file
        into the store) runs inside the transaction, just before the insert, so a
        concurrent delete of the same content cannot remove the new file. ``owner`` (a
        user's name) becomes one of the upload's owners, new content or not."""
        values = dict(record)
        values.setdefault("id", str(uuid.uuid4()))
        try:
            with self.write() as conn:
                existing = _row(
                    conn.execute(
                        select(uploads).where(uploads.c.sha256 == values["sha256"])
                    ).first()
                )
                if existing is None:
                    if place is not None:
                        place()
                    conn.execute(insert(uploads).values(**values, created=db_now()))
                    row = conn.execute(select(uploads).where(uploads.c.id == values["id"])).one()
                    existing = _row(row)
                self._own(conn, existing["id"], owner)  # type: ignore[index]
                return existing, existing["id"] == values["id"]  # type: ignore[return-value,index]
        except IntegrityError:  # a concurrent upload of the same content won
            got = self.upload_by_sha(values["sha256"])
            if got is None:
                raise
            if owner is not None:
                with self.write() as conn:
                    self._own(conn, got["id"], owner)
            return got, False

    @staticmethod
    def _own(conn: Connection, upload_id: str, owner: str | None) -> None:
        if owner is None:
            return
        have = conn.execute(
            select(upload_owners.c.owner).where(
                upload_owners.c.upload_id == upload_id, upload_owners.c.owner == owner
            )
        ).first()
        if have is None:
            conn.execute(insert(upload_owners).values(upload_id=upload_id, owner=owner))

    @staticmethod
    def _uploads_of(q: Any, owner: str | None) -> Any:
        """``q`` (a select over uploads) narrowed to ``owner``'s uploads; all with None."""
        if owner is None:
            return q
        mine = select(upload_owners.c.upload_id).where(upload_owners.c.owner == owner)
        return q.where(uploads.c.id.in_(mine))

    def upload(self, upload_id: str, *, owner: str | None = None) -> dict[str, Any] | None:
        """The upload, or None when there is none or ``owner`` (if given) does not own it."""
        q = self._uploads_of(select(uploads).where(uploads.c.id == upload_id), owner)
        with self.read() as conn:
            return _row(conn.execute(q).first())

    def upload_by_sha(self, sha256: str) -> dict[str, Any] | None:
        with self.read() as conn:
            return _row(conn.execute(select(uploads).where(uploads.c.sha256 == sha256)).first())

    def list_uploads(
        self, limit: int = 100, offset: int = 0, *, owner: str | None = None
    ) -> list[dict[str, Any]]:
        q = select(uploads).order_by(uploads.c.created.desc(), uploads.c.id)
        q = self._uploads_of(q, owner)
        with self.read() as conn:
            return [
                _row(r)  # type: ignore[misc]
                for r in conn.execute(q.limit(limit).offset(offset))
            ]

    def delete_upload(
        self,
        upload_id: str,
        remove: Callable[[dict[str, Any]], None] | None = None,
        *,
        owner: str | None = None,
    ) -> tuple[dict[str, Any] | None, list[str]]:
        """Delete an upload's record unless an accepted or running job reads it;
        ``remove(record)`` (which deletes the file) runs inside the transaction. With
        ``owner``, only an upload that user owns; while others own it too, only the
        user's ownership goes (the content stays for them).

        Returns ``(record, [])`` when deleted, ``(record, job_ids)`` when refused, and
        ``(None, [])`` when there is no such upload (for ``owner``)."""
        with self.write() as conn:
            q = self._uploads_of(select(uploads).where(uploads.c.id == upload_id), owner)
            if not self.is_sqlite:
                q = q.with_for_update()
            rec = _row(conn.execute(q).first())
            if rec is None:
                return None, []
            if owner is not None:
                others = conn.execute(
                    select(func.count()).where(
                        upload_owners.c.upload_id == upload_id, upload_owners.c.owner != owner
                    )
                ).scalar()
                if others:
                    conn.execute(
                        delete(upload_owners).where(
                            upload_owners.c.upload_id == upload_id,
                            upload_owners.c.owner == owner,
                        )
                    )
                    return rec, []
            users = [
                r[0]
                for r in conn.execute(
                    select(job_inputs.c.job_id)
                    .join(jobs, jobs.c.id == job_inputs.c.job_id)
                    .where(job_inputs.c.upload_id == upload_id, jobs.c.status.in_(ACTIVE))
                )
            ]
            if users:
                return rec, users
            conn.execute(delete(upload_owners).where(upload_owners.c.upload_id == upload_id))
            conn.execute(delete(uploads).where(uploads.c.id == upload_id))
            if remove is not None:
                remove(rec)
            return rec, []

    # -- jobs: the API's side --------------------------------------------------------------
    def create_job(
        self,
        *,
        process: str,
        inputs: Mapping[str, Any],
        parameters: Mapping[str, Any],
        max_attempts: int,
        time_limit_s: float,
        links: Sequence[tuple[str, str | None, str | None]] = (),
        check: Any = None,
        owner: str | None = None,
        outputs: Sequence[str] | None = None,
    ) -> dict[str, Any]:
        """Insert an accepted job. ``links`` are ``(input name, upload id, source job id)``;
        ``check(conn)`` runs first inside the transaction (with the uploads and source jobs
        locked on Postgres) and may raise to refuse the job. ``owner``: the user who
        submitted it (None: no token was set). ``outputs``: the output ids the request
        asked for (None or empty: every output)."""
        job_id = str(uuid.uuid4())
        with self.write() as conn:
            upload_ids = [u for _, u, _ in links if u]
            source_ids = [j for _, _, j in links if j]
            if not self.is_sqlite and upload_ids:
                conn.execute(
                    select(uploads.c.id).where(uploads.c.id.in_(upload_ids)).with_for_update()
                )
            if not self.is_sqlite and source_ids:
                conn.execute(select(jobs.c.id).where(jobs.c.id.in_(source_ids)).with_for_update())
            if check is not None:
                check(conn)
            conn.execute(
                insert(jobs).values(
                    id=job_id,
                    process=process,
                    status="accepted",
                    inputs=dict(inputs),
                    parameters=dict(parameters),
                    progress=0.0,
                    stage="queued",
                    message="waiting for a worker",
                    attempt=0,
                    max_attempts=int(max_attempts),
                    time_limit_s=float(time_limit_s),
                    created=db_now(),
                    updated=db_now(),
                    owner=owner,
                    outputs=list(outputs) if outputs else None,
                )
            )
            for name, upload_id, source in links:
                conn.execute(
                    insert(job_inputs).values(
                        job_id=job_id, name=name, upload_id=upload_id, source_job_id=source
                    )
                )
            return _row(conn.execute(select(jobs).where(jobs.c.id == job_id)).one())  # type: ignore[return-value]

    def job(self, job_id: str, *, owner: str | None = None) -> dict[str, Any] | None:
        """The job, or None when there is none or ``owner`` (if given) did not submit it."""
        q = select(jobs).where(jobs.c.id == job_id)
        if owner is not None:
            q = q.where(jobs.c.owner == owner)
        with self.read() as conn:
            return _row(conn.execute(q).first())

    def list_jobs(
        self,
        *,
        status: Sequence[str] = (),
        limit: int = 50,
        cursor: str | None = None,
        owner: str | None = None,
    ) -> tuple[list[dict[str, Any]], str | None]:
        """Jobs, newest first; ``(jobs, next_cursor)`` (keyset pagination); with
        ``owner``, only that user's."""
        q = select(jobs).order_by(jobs.c.created.desc(), jobs.c.id.desc())
        if owner is not None:
            q = q.where(jobs.c.owner == owner)
        if status:
            q = q.where(jobs.c.status.in_(list(status)))
        if cursor:
            pos = decode_cursor(cursor)
            if pos is not None:
                created, job_id = pos
                q = q.where(
                    or_(
                        jobs.c.created < created,
                        and_(jobs.c.created == created, jobs.c.id < job_id),
                    )
                )
        with self.read() as conn:
            rows = [_row(r) for r in conn.execute(q.limit(limit + 1))]
        nxt = None
        if len(rows) > limit:
            rows = rows[:limit]
            last = rows[-1]
            nxt = encode_cursor(last["created"], last["id"])  # type: ignore[index]
        return rows, nxt  # type: ignore[return-value]

    def jobs_reading(self, source_job_id: str) -> list[str]:
        """Active jobs that read a result of ``source_job_id``."""
        with self.read() as conn:
            return [
                r[0]
                for r in conn.execute(
                    select(job_inputs.c.job_id)
                    .join(jobs, jobs.c.id == job_inputs.c.job_id)
                    .where(job_inputs.c.source_job_id == source_job_id, jobs.c.status.in_(ACTIVE))
                )
            ]

    def dismiss(
        self, job_id: str, *, owner: str | None = None
    ) -> tuple[dict[str, Any] | None, str | None, list[str]]:
        """Mark a job dismissed (a running one's worker sees it at its next write and stops
        it). Returns ``(job after, status before, active jobs reading its results)``; when
        the last list is not empty nothing changed. With ``owner``, only that user's job
        (another's is None, as if there were none)."""
        with self.write() as conn:
            q = select(jobs).where(jobs.c.id == job_id)
            if owner is not None:
                q = q.where(jobs.c.owner == owner)
            if not self.is_sqlite:
                q = q.with_for_update()
            before = _row(conn.execute(q).first())
            if before is None:
                return None, None, []
            readers = [
                r[0]
                for r in conn.execute(
                    select(job_inputs.c.job_id)
                    .join(jobs, jobs.c.id == job_inputs.c.job_id)
                    .where(job_inputs.c.source_job_id == job_id, jobs.c.status.in_(ACTIVE))
                )
            ]
            if readers:
                return before, before["status"], readers
            if before["status"] != "dismissed":
                conn.execute(
                    update(jobs)
                    .where(jobs.c.id == job_id)
                    .values(
                        status="dismissed",
                        message="dismissed",
                        stage=None,
                        lease_expires=None,
                        finished=db_now(),
                        updated=db_now(),
                    )
                )
            after = _row(conn.execute(select(jobs).where(jobs.c.id == job_id)).one())
            return after, before["status"], []

    def count_by_status(self) -> dict[str, int]:
        with self.read() as conn:
            rows = conn.execute(select(jobs.c.status, func.count()).group_by(jobs.c.status))
            counts = {s: 0 for s in STATUSES}
            counts.update({s: int(n) for s, n in rows})
            return counts

    # -- jobs: the worker's side -----------------------------------------------------------
    def claim(self, worker_id: str, lease_s: float) -> Claim | None:
        """Take the oldest accepted job, atomically: ``running``, attempt + 1, leased to
        ``worker_id`` until now + ``lease_s`` on the database's clock."""
        pick = (
            select(jobs.c.id)
            .where(jobs.c.status == "accepted")
            .order_by(jobs.c.created, jobs.c.id)
            .limit(1)
        )
        if not self.is_sqlite:
            pick = pick.with_for_update(skip_locked=True)
        stmt = (
            update(jobs)
            .where(jobs.c.id == pick.scalar_subquery(), jobs.c.status == "accepted")
            .values(
                status="running",
                attempt=jobs.c.attempt + 1,
                worker_id=worker_id,
                lease_expires=db_now() + float(lease_s),
                started=func.coalesce(jobs.c.started, db_now()),
                updated=db_now(),
                progress=0.0,
                stage="starting",
                message=None,
            )
            .returning(
                jobs.c.id,
                jobs.c.attempt,
                jobs.c.max_attempts,
                jobs.c.process,
                jobs.c.inputs,
                jobs.c.parameters,
                jobs.c.time_limit_s,
            )
        )
        with self.write() as conn:
            row = conn.execute(stmt).first()
        if row is None:
            return None
        return Claim(
            id=row.id,
            attempt=int(row.attempt),
            max_attempts=int(row.max_attempts),
            process=row.process,
            inputs=dict(row.inputs),
            parameters=dict(row.parameters),
            time_limit_s=float(row.time_limit_s),
            worker_id=worker_id,
        )

    def _fenced(self, claim: Claim) -> Any:
        return and_(
            jobs.c.id == claim.id,
            jobs.c.attempt == claim.attempt,
            jobs.c.worker_id == claim.worker_id,
            jobs.c.status == "running",
        )

    def heartbeat(
        self,
        claim: Claim,
        lease_s: float,
        *,
        progress: float | None = None,
        stage: str | None = None,
    ) -> bool:
        """Renew the lease and report progress; False if the lease is lost (stop now)."""
        values: dict[str, Any] = {"lease_expires": db_now() + float(lease_s), "updated": db_now()}
        if progress is not None:
            values["progress"] = max(0.0, min(100.0, float(progress)))
        if stage is not None:
            values["stage"] = stage[:200]
        with self.write() as conn:
            return (
                conn.execute(update(jobs).where(self._fenced(claim)).values(**values)).rowcount == 1
            )

    def succeed(
        self,
        claim: Claim,
        *,
        results: list[dict[str, Any]],
        summary: dict[str, Any],
        message: str = "done",
    ) -> bool:
        with self.write() as conn:
            n = conn.execute(
                update(jobs)
                .where(self._fenced(claim))
                .values(
                    status="successful",
                    progress=100.0,
                    stage="done",
                    message=message,
                    results=results,
                    summary=summary,
                    error=None,
                    lease_expires=None,
                    finished=db_now(),
                    updated=db_now(),
                )
            ).rowcount
            return n == 1

    def fail(self, claim: Claim, problem: dict[str, Any], *, retry: bool) -> str | None:
        """End an attempt that did not succeed. With ``retry`` and attempts left the job
        goes back to ``accepted``; otherwise it is ``failed`` with ``problem``. Returns the
        new status, or None if the lease was lost."""
        again = retry and claim.attempt < claim.max_attempts
        detail = problem.get("detail", "")
        values: dict[str, Any] = {"lease_expires": None, "worker_id": None, "updated": db_now()}
        if again:
            values.update(
                status="accepted",
                stage="queued",
                progress=0.0,
                message=f"attempt {claim.attempt} of {claim.max_attempts} failed ({detail}); "
                "retrying",
                error=problem,
            )
        else:
            if retry:
                problem = {
                    **problem,
                    "detail": f"{detail} (attempt {claim.attempt} of {claim.max_attempts}: "
                    "no attempts left)",
                }
            values.update(
                status="failed", message=problem.get("detail"), error=problem, finished=db_now()
            )
        with self.write() as conn:
            n = conn.execute(update(jobs).where(self._fenced(claim)).values(**values)).rowcount
        return None if n != 1 else values["status"]

    def release(self, claim: Claim, reason: str) -> bool:
        """Hand a running job back unfinished (its worker is shutting down): accepted again,
        and the attempt does not count."""
        with self.write() as conn:
            n = conn.execute(
                update(jobs)
                .where(self._fenced(claim))
                .values(
                    status="accepted",
                    attempt=jobs.c.attempt - 1,
                    stage="queued",
                    progress=0.0,
                    message=reason,
                    lease_expires=None,
                    worker_id=None,
                    updated=db_now(),
                )
            ).rowcount
        return n == 1

    def expire_leases(self) -> list[tuple[str, str]]:
        """Jobs whose worker stopped renewing its lease: back to ``accepted`` while attempts
        are left, else ``failed`` with the reason. Returns ``[(job id, new status)]``."""
        out: list[tuple[str, str]] = []
        with self.write() as conn:
            q = select(jobs.c.id, jobs.c.attempt, jobs.c.max_attempts, jobs.c.worker_id).where(
                jobs.c.status == "running", jobs.c.lease_expires < db_now()
            )
            if not self.is_sqlite:
                q = q.with_for_update(skip_locked=True)
            for r in conn.execute(q).all():
                claim = Claim(
                    r.id, int(r.attempt), int(r.max_attempts), "", {}, {}, 0.0, r.worker_id
                )
                reason = (
                    f"the worker running attempt {r.attempt} ({r.worker_id}) stopped renewing "
                    "its lease: it was killed or lost its connection"
                )
                problem = {
                    "type": "/problems#worker-lost",
                    "title": "Worker lost",
                    "status": 500,
                    "detail": reason,
                }
                again = claim.attempt < claim.max_attempts
                values: dict[str, Any] = {
                    "lease_expires": None,
                    "worker_id": None,
                    "updated": db_now(),
                    "error": problem,
                }
                if again:
                    values.update(
                        status="accepted",
                        stage="queued",
                        progress=0.0,
                        message=f"{reason}; retrying",
                    )
                else:
                    problem["detail"] = (
                        f"{reason} (attempt {r.attempt} of {r.max_attempts}: no attempts left)"
                    )
                    values.update(
                        status="failed",
                        message=problem["detail"],
                        error=problem,
                        finished=db_now(),
                    )
                n = conn.execute(
                    update(jobs)
                    .where(self._fenced(claim), jobs.c.lease_expires < db_now())
                    .values(**values)
                ).rowcount
                if n == 1:
                    out.append((r.id, values["status"]))
                    self._bump(conn, "lease_expiries", "", 1.0)
        return out

    # -- workers ---------------------------------------------------------------------------
    def register_worker(self, worker_id: str, *, executor: str, slots: int) -> None:
        import socket

        with self.write() as conn:
            conn.execute(delete(workers).where(workers.c.id == worker_id))
            conn.execute(
                insert(workers).values(
                    id=worker_id,
                    hostname=socket.gethostname(),
                    pid=os.getpid(),
                    executor=executor,
                    slots=int(slots),
                    started=db_now(),
                    heartbeat=db_now(),
                )
            )

    def worker_heartbeat(self, worker_id: str) -> None:
        with self.write() as conn:
            conn.execute(
                update(workers).where(workers.c.id == worker_id).values(heartbeat=db_now())
            )

    def worker_stopped(self, worker_id: str) -> None:
        with self.write() as conn:
            conn.execute(update(workers).where(workers.c.id == worker_id).values(stopped=db_now()))

    def live_workers(self, within_s: float) -> list[dict[str, Any]]:
        """Workers that beat within the last ``within_s`` seconds and have not stopped."""
        with self.read() as conn:
            q = select(workers).where(
                workers.c.stopped.is_(None), workers.c.heartbeat > db_now() - float(within_s)
            )
            return [_row(r) for r in conn.execute(q)]  # type: ignore[misc]

    # -- counters --------------------------------------------------------------------------
    def _bump(self, conn: Connection, name: str, label: str, value: float) -> None:
        n = conn.execute(
            update(counters)
            .where(counters.c.name == name, counters.c.label == label)
            .values(count=counters.c.count + 1, total=counters.c.total + float(value))
        ).rowcount
        if n == 0:
            try:
                with conn.begin_nested():
                    conn.execute(
                        insert(counters).values(name=name, label=label, count=1, total=value)
                    )
            except IntegrityError:  # created concurrently: add to it
                conn.execute(
                    update(counters)
                    .where(counters.c.name == name, counters.c.label == label)
                    .values(count=counters.c.count + 1, total=counters.c.total + float(value))
                )

    def bump(self, name: str, label: str = "", value: float = 1.0) -> None:
        """Add one observation of ``value`` to the counter ``name{label}``."""
        with self.write() as conn:
            self._bump(conn, name, label, value)

    def counters(self) -> list[dict[str, Any]]:
        with self.read() as conn:
            return [_row(r) for r in conn.execute(select(counters))]  # type: ignore[misc]
