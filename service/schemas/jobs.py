"""Durable jobs (service.jobs)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field


class JobError(BaseModel):
    detail: str
    field: str | None = None


class JobOut(BaseModel):
    """A durable job (chizu.service.jobs). A job the server was running when it stopped
    (a crash or a shutdown) is queued again at its next start and runs from the start
    (``attempts`` counts those starts) if its kind can be re-run from its request (an
    eigenspace learning); otherwise it is ``interrupted``. ``result`` when done (for a
    learning job, the analysis summary); ``error`` naming the field when it failed.
    Times are Unix seconds."""

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
    attempts: int = Field(0, ge=0, description="how many times it was started again "
                          "after the server stopped")
