"""Response schemas (request bodies are the numeric models themselves)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from numeric.world import Id

RelationKind = Literal["rec", "frec", "lr", "align", "rea", "reachable"]


class Health(BaseModel):
    status: Literal["ok"]
    worlds: int
    engine_thread_alive: bool
    prolog_thread: int = Field(description="Prolog thread id that answered")
    python_thread: int = Field(description="ident of the Python thread owning the engine")


class WorldSummary(BaseModel):
    name: str
    template: str | None
    landmarks: int
    walls: int
    objects: int
    events: int


class ReachedIn(BaseModel):
    model_config = {"extra": "forbid", "populate_by_name": True}
    from_: Id = Field(alias="from")
    to: Id


class ObservationOut(BaseModel):
    world: str
    at: str
    relations: int = Field(description="lr/align relations now known from this landmark")


class ReachedOut(BaseModel):
    world: str
    from_: str = Field(serialization_alias="from")
    to: str


class DrmEdgeOut(BaseModel):
    from_: str = Field(serialization_alias="from")
    to: str
    p: float
    method: str
    via: list[str]


class DrmOut(BaseModel):
    nodes: list[str]
    edges: list[DrmEdgeOut]


class StepOut(BaseModel):
    from_: str = Field(serialization_alias="from")
    to: str
    method: str
    p: float
    via: list[str]


class PathOut(BaseModel):
    found: bool
    detail: str | None = None
    path: list[str]
    steps: list[StepOut]
    probability: float


class QueryIn(BaseModel):
    model_config = {"extra": "forbid"}
    goal: str = Field(min_length=1, max_length=4096,
                      examples=["reachable(c0, To, P, Method), P > 0.9"])
    max_solutions: int = Field(100, ge=1, le=10_000)


class QueryOut(BaseModel):
    solutions: list[dict[str, Any]]
    truncated: bool
