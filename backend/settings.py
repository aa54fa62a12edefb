"""One settings class for the API, the CLI and the workers: `VARBOT_*` environment variables and `.env`."""

from functools import lru_cache
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from core.paths import data_dir

DEFAULT_SECRET = "changethis"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="VARBOT_", env_file=".env", extra="ignore")

    environment: Literal["development", "test", "production"] = "development"
    secret_key: str = DEFAULT_SECRET
    # Empty means the embedded defaults under the data directory.
    database_url: str = ""
    broker_url: str = ""
    blob_dir: str = ""

    # Argon2id cost (RFC 9106 "low memory" profile by default); tests lower it to stay fast.
    password_hash_time_cost: int = Field(default=3, ge=1)
    password_hash_memory_kib: int = Field(default=65536, ge=8)
    # At most this many hashes at once per process (each holds password_hash_memory_kib while it runs)...
    password_hash_concurrency: int = Field(default=1, ge=1)
    # ...and sign-ins waiting for one beyond this many are answered 503 at once.
    password_hash_queue: int = Field(default=16, ge=0)
    # Wrong passwords allowed within the sliding window, per account and per client address; more get 429.
    login_window_seconds: float = Field(default=900, gt=0)
    login_failures_per_account: int = Field(default=10, ge=1)
    login_failures_per_address: int = Field(default=20, ge=1)
    session_ttl_hours: int = Field(default=24 * 14, ge=1)
    # None: Secure cookies in production (behind HTTPS), not on the plain-HTTP development and test servers.
    cookie_secure: bool | None = None
    max_clip_bytes: int = 5 * 1024 * 1024
    min_clip_seconds: float = 0.3
    max_clip_seconds: float = 10.0
    max_image_bytes: int = 10 * 1024 * 1024
    max_capture_count: int = 500
    capture_views_per_hour: int = Field(default=2000, ge=1)  # per household: renders cost the robot worker
    min_triplets_for_training: int = Field(default=20, ge=0)
    orphan_grace_seconds: int = 3600
    sse_poll_seconds: float = 1.0
    # Training workers: where the VAR and the policy run (learning/device.py). auto: the GPU when torch sees
    # one; cuda: the GPU or the run fails saying what is missing.
    device: Literal["auto", "cpu", "cuda"] = "auto"

    @model_validator(mode="after")
    def _refuse_default_secrets(self) -> "Settings":
        if self.environment == "development":
            return self
        if self.secret_key == DEFAULT_SECRET:
            raise ValueError(
                f"VARBOT_SECRET_KEY is still {DEFAULT_SECRET!r} in {self.environment}; "
                "set it to a long random value, e.g. "
                'python -c "import secrets; print(secrets.token_urlsafe(32))"'
            )
        if urlsplit(self.database_url).password == DEFAULT_SECRET:
            raise ValueError(f"the database password in VARBOT_DATABASE_URL is still {DEFAULT_SECRET!r}")
        return self

    @property
    def secure_cookies(self) -> bool:
        return self.cookie_secure if self.cookie_secure is not None else self.environment == "production"

    @property
    def sqlalchemy_url(self) -> str:
        if self.database_url:
            url = self.database_url
            # psycopg 3 is the one PostgreSQL driver we ship.
            if url.startswith("postgresql://") or url.startswith("postgres://"):
                url = "postgresql+psycopg://" + url.split("://", 1)[1]
            return url
        return f"sqlite:///{data_dir() / 'varbot.db'}"

    @property
    def celery_broker_url(self) -> str:
        return self.broker_url or f"redis+socket://{data_dir() / 'redis' / 'redis.sock'}"

    @property
    def redis_url(self) -> str:
        """The broker as a redis-py URL (for pub/sub and the health check)."""
        url = self.celery_broker_url
        if url.startswith("redis+socket://"):
            return "unix://" + url.removeprefix("redis+socket://")
        return url

    @property
    def blob_path(self) -> Path:
        return Path(self.blob_dir).expanduser().resolve() if self.blob_dir else data_dir() / "blobs"


@lru_cache
def get_settings() -> Settings:
    return Settings()
