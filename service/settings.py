"""Settings (env prefix ``CHIZU_``), built once and handed out by a cached dependency."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

PROLOG_DIR = Path(__file__).resolve().parent.parent / "prolog"


def default_workers() -> int:
    """One compute worker per core this process may run on, but one (at least one)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    return max(1, cores - 1)


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="CHIZU_")

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    data_dir: Path = Path("./var")
    prolog_dir: Path = PROLOG_DIR
    demo_world: str | None = Field("demo", description="built-in world created at start-up")
    kb_time_limit_s: float = Field(10.0, gt=0)
    kb_inference_limit: int = Field(200_000_000, gt=0)
    kb_query_time_limit_s: float = Field(2.0, gt=0, description="time limit of a client's "
                                         "own Prolog goals (POST /query)")
    workers: int = Field(default_factory=lambda: default_workers(), ge=0, le=64,
                         description="compute worker processes (image decoding, projection, "
                         "rendering, planning); default: one per core but one, which the "
                         "event loop and the Prolog engine use; 0 runs that work in threads "
                         "of the server, without budgets")
    request_budget_s: float = Field(30.0, gt=0, description="time budget of one request's "
                                    "work in a compute worker; past it the worker is stopped "
                                    "and the request answered 503")
    job_budget_s: float = Field(3600.0, gt=0, description="time budget of a background job "
                                "(eigenspace learning); past it the job fails")
    max_body_bytes: int = Field(8 * 1024 * 1024, gt=0)
    max_event_streams: int = Field(64, gt=0, description="live event streams (GET "
                                   "/worlds/{world}/events) open at once; past it 503")
    max_learning_pixels: int = Field(200_000_000, gt=0, description="pixels an eigenspace "
                                     "learning job may render (the paper's room: 5 M)")
    max_upload_bytes: int = Field(256 * 1024 * 1024, gt=0,
                                  description="bodies of image-set uploads")

    @property
    def db_path(self) -> Path:
        return self.data_dir / "chizu.sqlite3"


@lru_cache
def get_settings() -> Settings:
    return Settings()
