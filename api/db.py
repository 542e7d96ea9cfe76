"""Persistence: SQLAlchemy 2 models and the engine (SQLite by default, PostgreSQL through psycopg 3).

SQLite runs in WAL mode with ``synchronous=FULL`` (set on every connection), so a committed job survives
a power cut, and readers never block the writer. PostgreSQL is selected by a ``postgresql+psycopg://``
URL; an optional schema (``Settings.database_schema``) keeps the tables of one deployment (or one test
run) apart. Times are stored as UNIX seconds (float) so that both back ends agree.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Engine,
    Float,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
    create_engine,
    event,
    inspect,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

#: Job states; the last three are terminal.
JOB_STATES: tuple[str, ...] = ("queued", "running", "succeeded", "failed", "cancelled")
ACTIVE_STATES: tuple[str, ...] = ("queued", "running")
TERMINAL_STATES: tuple[str, ...] = ("succeeded", "failed", "cancelled")


def now_s() -> float:
    """Wall-clock time as UNIX seconds."""
    return time.time()


class Base(DeclarativeBase):
    """Declarative base of every table."""

    type_annotation_map = {dict[str, Any]: JSON}


class ApiKey(Base):
    """An API key bound to a tenant; only the SHA-256 of the secret is stored."""

    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant: Mapped[str] = mapped_column(String(64), index=True)
    name: Mapped[str] = mapped_column(String(100), default="")
    key_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[float] = mapped_column(Float)
    revoked_at: Mapped[float | None] = mapped_column(Float, nullable=True)


class Mesh(Base):
    """Metadata of an uploaded cabin mesh; the bytes live in the data directory under their SHA-256."""

    __tablename__ = "meshes"
    __table_args__ = (UniqueConstraint("tenant", "sha256", name="uq_mesh_tenant_sha256"),)

    pk: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    tenant: Mapped[str] = mapped_column(String(64), index=True)
    sha256: Mapped[str] = mapped_column(String(64))
    name: Mapped[str] = mapped_column(String(100))
    filename: Mapped[str] = mapped_column(String(255))
    units: Mapped[str] = mapped_column(String(4))
    byte_size: Mapped[int] = mapped_column(Integer)
    n_faces: Mapped[int] = mapped_column(Integer)
    n_vertices: Mapped[int] = mapped_column(Integer)
    report: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[float] = mapped_column(Float)


class MeshBlob(Base):
    """The bytes of an uploaded mesh file, by SHA-256: every instance sharing the database can read them.

    Each instance keeps the files it plans with in its own data directory as a cache
    (:meth:`api.store.MeshStore.localize`), filled from here when another instance took the upload.
    """

    __tablename__ = "mesh_blobs"

    sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    data: Mapped[bytes] = mapped_column(LargeBinary, deferred=True)
    created_at: Mapped[float] = mapped_column(Float)


class Job(Base):
    """A job (a plan, or another kind): its input as submitted, its state, and (when done) its result."""

    __tablename__ = "jobs"
    __table_args__ = (
        UniqueConstraint("tenant", "idempotency_key", name="uq_job_tenant_idempotency_key"),
        Index("ix_job_tenant_status_created", "tenant", "status", "created_at"),
        Index("ix_job_status_created", "status", "created_at"),
        Index("ix_job_status_finished", "status", "finished_at"),
    )

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant: Mapped[str] = mapped_column(String(64))
    #: The job's kind (:mod:`api.jobkinds`); ``None`` on rows written before kinds: plans.
    kind: Mapped[str | None] = mapped_column(String(16), nullable=True)
    status: Mapped[str] = mapped_column(String(16))
    stage: Mapped[str | None] = mapped_column(String(32), nullable=True)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    #: What the job reports beyond its stage and fraction (a campaign: ``{"units": [...]}``), JSON.
    progress_detail: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    scenario: Mapped[dict[str, Any]] = mapped_column(JSON)
    scenario_name: Mapped[str] = mapped_column(String(100))
    request_sha256: Mapped[str] = mapped_column(String(64))
    idempotency_key: Mapped[str | None] = mapped_column(String(200), nullable=True)
    meshes: Mapped[dict[str, Any]] = mapped_column(JSON)
    provenance: Mapped[dict[str, Any]] = mapped_column(JSON)
    time_limit_s: Mapped[float] = mapped_column(Float)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    #: Service instance running the job and until when its lease holds (UNIX s); see api.jobs.
    owner: Mapped[str | None] = mapped_column(String(32), nullable=True)
    lease_expires_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    cancel_requested: Mapped[bool | None] = mapped_column(Boolean, nullable=True, default=False)
    created_at: Mapped[float] = mapped_column(Float)
    started_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    reason: Mapped[str | None] = mapped_column(String(64), nullable=True)
    message: Mapped[str | None] = mapped_column(Text, nullable=True)
    result_json: Mapped[str | None] = mapped_column(Text, nullable=True, deferred=True)
    #: The result document packed by :func:`api.compact.pack_document` (new rows; ``result_json`` is None).
    result_packed: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True, deferred=True)
    #: Files written by earlier versions with every result (now made on request: :class:`JobFile`).
    profile_csv: Mapped[str | None] = mapped_column(Text, nullable=True, deferred=True)
    plot_png: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True, deferred=True)


class JobFile(Base):
    """A file made from a finished job's result on its first request and kept (a plot); see api.jobkinds."""

    __tablename__ = "job_files"

    job_id: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    data: Mapped[bytes] = mapped_column(LargeBinary)


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA busy_timeout=10000")
    cur.close()


_TENANT_LOCKS: dict[str, threading.Lock] = {}
_TENANT_LOCKS_GUARD = threading.Lock()


def _process_tenant_lock(tenant: str) -> threading.Lock:
    with _TENANT_LOCKS_GUARD:
        return _TENANT_LOCKS.setdefault(tenant, threading.Lock())


class Database:
    """The engine, its session factory and schema creation.

    Args:
        url: SQLAlchemy URL (``sqlite:///path`` or ``postgresql+psycopg://...``).
        schema: PostgreSQL schema for the tables (created if missing); ``None`` for the default.
    """

    def __init__(self, url: str, schema: str | None = None) -> None:
        self.url = url
        self.schema = schema
        self.is_sqlite = url.startswith("sqlite")
        # A pooled PostgreSQL connection may have been dropped by the server or the network: ping it when
        # it is checked out. A SQLite connection is a file handle in this process; pinging it is a
        # query per session for nothing.
        kwargs: dict[str, Any] = {"pool_pre_ping": not self.is_sqlite}
        if self.is_sqlite:
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 10.0}
        engine = create_engine(url, **kwargs)
        if self.is_sqlite:
            event.listen(engine, "connect", _sqlite_pragmas)
        if schema is not None:
            engine = engine.execution_options(schema_translate_map={None: schema})
        self.engine: Engine = engine
        self.sessions = sessionmaker(bind=self.engine, expire_on_commit=False)

    def create_all(self) -> None:
        """Create the schema (PostgreSQL), every missing table, and missing nullable columns.

        Columns added by later versions (all nullable) are added to existing tables with ``ALTER TABLE
        ... ADD COLUMN``, so a database written by an older version keeps working.
        """
        if self.schema is not None:
            with self.engine.begin() as conn:
                conn.execute(text(f'CREATE SCHEMA IF NOT EXISTS "{self.schema}"'))
        Base.metadata.create_all(self.engine)
        with self.engine.begin() as conn:
            insp = inspect(conn)
            for table in Base.metadata.sorted_tables:
                have = {c["name"] for c in insp.get_columns(table.name, schema=self.schema)}
                for column in table.columns:
                    if column.name not in have and column.nullable:
                        kind = column.type.compile(dialect=conn.dialect)
                        prefix = f'"{self.schema}".' if self.schema is not None else ""
                        conn.execute(
                            text(f'ALTER TABLE {prefix}"{table.name}" ADD COLUMN "{column.name}" {kind}')
                        )

    def drop_schema(self) -> None:
        """Drop the PostgreSQL schema and everything in it (tests); a no-op without a schema."""
        if self.schema is not None:
            with self.engine.begin() as conn:
                conn.execute(text(f'DROP SCHEMA IF EXISTS "{self.schema}" CASCADE'))

    def ping(self) -> bool:
        """True when a trivial query succeeds."""
        try:
            with self.engine.connect() as conn:
                conn.execute(text("SELECT 1"))
        except Exception:
            return False
        return True

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session that commits on success and rolls back on error."""
        with self.sessions() as s:
            try:
                yield s
                s.commit()
            except BaseException:
                s.rollback()
                raise

    @contextmanager
    def tenant_quota_session(self, tenant: str) -> Iterator[Session]:
        """A session whose transaction holds ``tenant``'s quota lock: count the active jobs, then insert.

        Two submissions of one tenant cannot both pass the quota between their count and their insert: a
        lock per tenant in this process, and on PostgreSQL also a transaction-level advisory lock keyed by
        the schema and the tenant, so the instances sharing the database take turns too (released at
        commit or rollback). SQLite serves one instance (its file lives on that machine).
        """
        with _process_tenant_lock(tenant), self.session() as s:
            if not self.is_sqlite:
                digest = hashlib.sha256(f"quota:{self.schema or ''}:{tenant}".encode()).digest()
                key = int.from_bytes(digest[:8], "big", signed=True)
                s.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": key})
            yield s

    def dispose(self) -> None:
        """Close every pooled connection."""
        self.engine.dispose()


__all__ = [
    "ACTIVE_STATES",
    "JOB_STATES",
    "TERMINAL_STATES",
    "ApiKey",
    "Base",
    "Database",
    "Job",
    "JobFile",
    "Mesh",
    "MeshBlob",
    "now_s",
]
