"""Settings in one place: environment variables prefixed ``FLEETHEALTH_``."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field
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
    host: str = "127.0.0.1"
    port: int = 8000
    log_level: str = "INFO"
    log_json: bool = True
    max_body_bytes: int = Field(default=256 * 1024 * 1024, gt=0)

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'fleethealth.sqlite3').resolve()}"


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings; tests clear the cache (``get_settings.cache_clear()``)."""
    return Settings()
