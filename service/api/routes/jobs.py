"""Durable jobs (service.jobs): list them, poll one, cancel one."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query

from chizu.numeric.world import ID_PATTERN
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import JobsDep
from chizu.service.schemas.jobs import JobOut

router = APIRouter(prefix="/jobs", tags=["jobs"], route_class=StrictJsonRoute)
JobId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="job id")]
Status = Literal["queued", "running", "done", "failed", "cancelled", "interrupted"]


@router.get("", response_model=list[JobOut])
async def list_jobs(jobs: JobsDep,
                    world: Annotated[str | None, Query(pattern=ID_PATTERN)] = None,
                    status: Status | None = None) -> list[JobOut]:
    """Every job, oldest first; filtered by world and status."""
    return jobs.list(world, status)


@router.get("/{job_id}", response_model=JobOut)
async def get_job(job_id: JobId, jobs: JobsDep) -> JobOut:
    return jobs.get(job_id)


@router.delete("/{job_id}", response_model=JobOut)
async def cancel_job(job_id: JobId, jobs: JobsDep) -> JobOut:
    """Cancel a queued or running job: it ends ``cancelled`` and commits nothing; 409
    for a job that has already ended."""
    return await jobs.cancel(job_id)
