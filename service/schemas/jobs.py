"""Durable jobs (service.jobs)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field


class JobError(BaseModel):
    detail: str
    field: str | None = None


class JobOut(BaseModel):
    """A durable job (service.jobs): ``interrupted`` when the server stopped while it
    was queued or running; ``result`` when done (for a learning job, the analysis
    summary); ``error`` naming the field when it failed. Times are Unix seconds."""

    id: str
    world: str
    kind: str = Field(description="e.g. eigenspace_learning")
    status: Literal["queued", "running", "done", "failed", "cancelled", "interrupted"]
    stage: str
    progress: float = Field(ge=0, le=1)
    result: dict[str, Any] | None = None
    error: JobError | None = None
    created_at: float
    updated_at: float
