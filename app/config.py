"""Settings in one place: environment variables prefixed ``FLEETHEALTH_``."""

from __future__ import annotations

from datetime import timedelta
from functools import lru_cache
from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FLEETHEALTH_", env_file=".env", extra="ignore")

    data_dir: Path = Field(
        default=Path("data"), description="Where the SQLite file, recordings and caches live."
    )
    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL; defaults to a SQLite file under data_dir."
    )
    redis_url: str = "redis://127.0.0.1:6379/0"
    job_runner: str = Field(default="inprocess", pattern="^(inprocess|celery)$")
    job_host: str = Field(
        default="process", pattern="^(process|thread)$",
        description="Where the embedded runner (job_runner=inprocess) runs jobs: a child process "
        "of the server (both cores, requests never wait on a job's compute) or threads of the "
        "server process.",
    )
    job_heartbeat_seconds: float = Field(
        default=15.0, gt=0, description="How often a running job marks itself alive."
    )
    job_stale_after_seconds: float = Field(
        default=120.0,
        gt=0,
        description="The heartbeat timeout: a running job whose last heartbeat is older is "
        "taken as abandoned by a stopped worker and requeued.",
    )
    estimation_workers: int = Field(
        default=2, ge=1,
        description="Processes one operator's estimation job spreads its engine groups over on "
        "PostgreSQL, its own included: the embedded default starts a pool of one fewer; under "
        "Celery the groups go to the workers as tasks. 1: the job estimates alone.",
    )
    upload_lateness_days: float = Field(
        default=7.0, gt=0,
        description="An upload's records recorded longer than this before it arrived are late.",
    )
    data_overdue_days: float = Field(
        default=7.0, gt=0,
        description="An installed engine without data for longer than this is overdue.",
    )
    stream_retention_days: float | None = Field(
        default=None, gt=0,
        description="Raw stream samples (the Parquet files of closed recordings) are deleted "
        "this many days after the recording closed, by the purge_stream_samples job; the "
        "recordings' metadata, estimates and steady-window records are kept. Unset: kept "
        "for ever.",
    )
    host: str = "127.0.0.1"
    port: int = 8000
    log_level: str = "INFO"
    log_json: bool = True
    max_body_bytes: int = Field(default=256 * 1024 * 1024, gt=0)

    @model_validator(mode="after")
    def _heartbeat_within_timeout(self) -> Settings:
        if self.job_heartbeat_seconds >= self.job_stale_after_seconds:
            raise ValueError("job_heartbeat_seconds must be shorter than job_stale_after_seconds")
        return self

    @property
    def job_stale_after(self) -> timedelta:
        return timedelta(seconds=self.job_stale_after_seconds)

    @property
    def upload_lateness(self) -> timedelta:
        return timedelta(days=self.upload_lateness_days)

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'fleethealth.sqlite3').resolve()}"


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings; tests clear the cache (``get_settings.cache_clear()``)."""
    return Settings()
