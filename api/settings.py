"""Service settings, read from the environment (prefix ``CABINPLAN_``) with embedded defaults.

Every field can be set as ``CABINPLAN_<FIELD>`` (e.g. ``CABINPLAN_DATABASE_URL``, ``CABINPLAN_WORKERS``).
Sizes are in bytes, times in seconds. The defaults serve one machine on 127.0.0.1 with SQLite in
``./var/cabinplan``.
"""

from __future__ import annotations

from pathlib import Path

from limits import parse
from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Configuration of the HTTP service (see the README's settings table)."""

    model_config = SettingsConfigDict(env_prefix="CABINPLAN_", extra="ignore", frozen=True)

    host: str = Field("127.0.0.1", description="Interface uvicorn binds to.")
    port: int = Field(8000, ge=1, le=65535, description="TCP port.")
    data_dir: Path = Field(
        Path("var/cabinplan"), description="Folder of the SQLite file and uploaded meshes."
    )
    database_url: str | None = Field(
        None,
        description="SQLAlchemy URL; default sqlite:///<data_dir>/cabinplan.db. PostgreSQL: "
        "postgresql+psycopg://user@host:5432/db.",
    )
    database_schema: str | None = Field(
        None, pattern=r"^[a-z_][a-z0-9_]{0,62}$", description="PostgreSQL schema of the tables (created)."
    )
    workers: int = Field(2, ge=1, le=64, description="Planning jobs run at the same time (one process each).")
    worker_nice: int = Field(
        5, ge=0, le=19, description="Niceness added to job processes, so the API stays responsive under load."
    )
    worker_max_jobs: int = Field(
        100,
        ge=1,
        le=100_000,
        description="Jobs one worker process runs before a fresh one replaces it (1: a fresh process per "
        "job).",
    )
    worker_max_rss_bytes: int = Field(
        1 << 30,
        ge=64 << 20,
        description="A worker process whose resident memory exceeds this after a job is replaced by a fresh "
        "one.",
    )
    job_grace_s: float = Field(
        15.0,
        ge=0.0,
        le=600.0,
        description="Wall-clock grace beyond a job's time_limit_s before it is killed.",
    )
    max_body_bytes: int = Field(
        16 << 20, ge=1024, description="Largest request body except mesh uploads (a profile is ~3 MB)."
    )
    max_upload_bytes: int = Field(50 << 20, ge=1024, description="Largest mesh upload (multipart body).")
    max_mesh_faces: int = Field(500_000, ge=1, description="Largest accepted face count of an uploaded mesh.")
    time_limit_ceiling_s: float = Field(
        120.0, gt=0.0, le=600.0, description="Largest options.time_limit_s a scenario may ask for."
    )
    tenant_max_active_jobs: int = Field(4, ge=1, description="Queued + running jobs allowed per tenant.")
    sweep_max_plans: int = Field(
        1000, ge=1, le=100_000, description="Most plans one POST /sweeps may expand to."
    )
    retry_after_s: int = Field(5, ge=1, description="Retry-After of a 429 (quota) answer.")
    admin_key: SecretStr | None = Field(None, description="API key of the administrator (manages keys).")
    page_size_max: int = Field(100, ge=1, le=1000, description="Largest page of GET /plans and /cabins.")
    job_lease_s: float = Field(
        15.0,
        ge=0.5,
        le=600.0,
        description="Lease of a running job, renewed by its instance every third of it; a job whose lease "
        "lapses (its instance died) is re-queued by any instance.",
    )
    retention_days: float = Field(
        30.0, gt=0.0, le=36500.0, description="Finished plans are deleted this long after they finish."
    )
    rate_limit: str = Field(
        "120 per 10 seconds",
        description="Authenticated requests allowed per tenant (moving window, the `limits` notation, e.g. "
        "'120 per 10 seconds'); beyond it 429 with Retry-After. Counted per instance unless "
        "rate_limit_storage_uri names a shared store.",
    )
    rate_limit_storage_uri: str = Field(
        "memory://",
        description="Where the rate-limit windows live (a `limits` storage URI): 'memory://' counts per "
        "instance; 'redis://host:6379/0' shares one window per tenant among every instance using it.",
    )
    body_timeout_s: float = Field(
        10.0, gt=0.0, le=600.0, description="Longest wait for the next chunk of a request body (408 beyond)."
    )
    job_wait_max_s: float = Field(
        30.0,
        ge=0.0,
        le=60.0,
        description="Longest a job document request waits for the job to end (its wait_s is capped to this).",
    )
    forkserver_preload: bool = Field(
        True, description="Import the planner once in the forkserver so that each job forks warm."
    )

    @field_validator("rate_limit")
    @classmethod
    def _parse_rate_limit(cls, value: str) -> str:
        try:
            parse(value)
        except ValueError as exc:
            raise ValueError(f"not a rate limit such as '120 per 10 seconds': {exc}") from None
        return value

    rate_limit_namespace: str = Field(
        "cabinplan",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_.-]+$",
        description="Prefix of the rate-limit keys in a shared store: one per deployment sharing a Redis.",
    )

    @field_validator("rate_limit_storage_uri")
    @classmethod
    def _check_storage(cls, value: str) -> str:
        scheme = value.partition("://")[0]
        if scheme not in ("memory", "redis", "rediss", "redis+unix"):
            raise ValueError(f"not a storage URI such as 'memory://' or 'redis://host:6379/0': {value!r}")
        return value

    def resolved_database_url(self) -> str:
        """The database URL, defaulting to the SQLite file in the data directory."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'cabinplan.db').resolve()}"

    @property
    def mesh_dir(self) -> Path:
        """Folder of the uploaded mesh files, named by their SHA-256."""
        return self.data_dir / "meshes"


__all__ = ["Settings"]
