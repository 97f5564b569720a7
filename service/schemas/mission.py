"""The mission record (service.mission)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class MissionStepOut(BaseModel):
    step: int = Field(ge=0)
    what: str = Field(description="localize, drm_path, slam_map, verify, evaluation, ...")
    result: dict[str, Any] = Field(description="the step's inputs and outputs; ok = false "
                                   "marks the step that ended the mission")


class MissionRecordOut(BaseModel):
    world: str
    steps: list[MissionStepOut]
