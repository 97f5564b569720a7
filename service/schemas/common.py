"""Schemas every domain shares: health, worlds."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field


class Health(BaseModel):
    status: Literal["ok"]
    worlds: int
    engine_thread_alive: bool
    engine_busy: bool = Field(description="the engine did not answer the probe at once: "
                              "a request holds it (up to its time limit)")
    prolog_thread: int = Field(description="Prolog thread id of the engine (0 until it "
                               "has answered a probe)")
    python_thread: int = Field(description="ident of the Python thread owning the engine")
    compute_workers: int = Field(0, description="compute worker processes (0: threads)")
    compute_restarts: int = Field(0, description="times the compute pool broke (a worker "
                                  "killed while idle) and was started again")
    event_streams: int = Field(0, description="live event streams open (GET "
                               "/worlds/{world}/events)")


class WorldSummary(BaseModel):
    name: str
    template: str | None
    landmarks: int
    walls: int
    objects: int
    events: int
    artifacts: list[str] = Field(
        [], description="what the world has learned or been given, by kind: eigenspace "
        "(an eigenspace analysis), saved_map (a committed SLAM map), mission (the last "
        "mission's record), viewpoint_scene, ...")


class PoseOut(BaseModel):
    """A pose in the world frame (m, m, rad)."""

    x: float
    y: float
    theta: float
