"""Service and worker configuration (pydantic-settings): every field is ``PRT_<NAME>``.

Embedded defaults need no server: a SQLite job store and a SQLite huey queue under
``PRT_DATA_DIR``. Scale-out is configuration only: ``PRT_DATABASE_URL`` (PostgreSQL),
``PRT_QUEUE_URL`` (Redis), ``PRT_ARTIFACTS_DIR`` on a shared mount, and ``prtcore worker``
started on as many machines as needed.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

MiB = 1 << 20


def _split(v: object) -> object:
    if isinstance(v, str):
        return [t.strip() for t in v.split(",") if t.strip()]
    return v


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="PRT_", extra="ignore")

    data_dir: Path = Field(Path("prtcore-data"), description="root of embedded-mode state")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL of the job store, e.g. "
        "postgresql+psycopg://user@host/db; default sqlite:///DATA_DIR/jobs.db")
    queue_url: str | None = Field(
        None, description="redis://host:port/db for a Redis queue; default a SQLite "
        "queue at DATA_DIR/queue.db")
    queue_name: str = "prtcore-bakes"
    artifacts_dir: Path | None = Field(
        None, description="where inputs and bundles live (shared by API and workers); "
        "default DATA_DIR/artifacts")

    # Limits enforced before work.
    max_upload_bytes: int = 256 * MiB
    max_spec_bytes: int = 256 * 1024
    job_time_limit_s: float = 3600.0

    # Leases and retries.
    max_attempts: int = 3
    lease_s: float = 30.0
    heartbeat_s: float = 5.0
    reaper_interval_s: float = 2.0
    requeue_after_s: float = 300.0  # a queued job whose message was lost is re-sent
    poll_max_delay_s: float = 1.0  # SQLite queue: longest sleep between polls

    # Supervision (``prtcore serve``): a worker that dies is restarted after a delay that
    # doubles from ``restart_backoff_s`` up to ``restart_backoff_max_s``, and goes back to
    # the start once a worker has stayed up ``restart_reset_after_s``.
    restart_backoff_s: float = 0.5
    restart_backoff_max_s: float = 30.0
    restart_reset_after_s: float = 60.0

    # Workers.
    concurrency: int = 1  # bakes run at once by one ``prtcore worker``
    bake_nice: int = 10  # bakes run niced so status calls stay fast
    worker_name: str | None = None

    # API.
    api_tokens: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="comma-separated bearer tokens; when set, "
        "every /v1 route requires one")
    page_limit_max: int = 100

    #: Testing hook (fault injection): the bake process kills itself with SIGKILL when
    #: it reaches this stage, on every attempt. Never set in production.
    fault_crash_stage: str | None = None

    @field_validator("api_tokens", mode="before")
    @classmethod
    def _tokens(cls, v: object) -> object:
        return _split(v)

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'jobs.db').resolve()}"

    @property
    def artifacts(self) -> Path:
        return (self.artifacts_dir or self.data_dir / "artifacts").resolve()

    @property
    def uploads(self) -> Path:
        """Staging area for uploads being received (same file system as artifacts)."""
        return self.artifacts / ".uploads"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
