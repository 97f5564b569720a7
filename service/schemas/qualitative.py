"""Qualitative navigation (Yamamoto & Ohya): observations, reached landmarks,
relations, the DRM, paths, sandboxed queries."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.world import Id

RelationKind = Literal["rec", "frec", "lr", "align", "rea", "reachable"]


class ReachedIn(BaseModel):
    model_config = {"extra": "forbid", "populate_by_name": True}
    from_: Id = Field(alias="from")
    to: Id


class ObservationOut(BaseModel):
    world: str
    at: str
    relations: int = Field(description="lr/align relations now known from this landmark")


class ReachedOut(BaseModel):
    """The arc's outcomes so far, this one counted."""

    model_config = ConfigDict(validate_by_name=True)  # from_= here, "from" on the wire

    world: str
    from_: str = Field(alias="from")
    to: str
    succeeded: int = Field(ge=0, description="times the robot drove the arc")
    failed: int = Field(ge=0, description="times it set out on the arc and did not arrive")


class DrmEdgeOut(BaseModel):
    model_config = ConfigDict(validate_by_name=True)  # from_= here, "from" on the wire

    from_: str = Field(alias="from")
    to: str
    p: float = Field(description="the best derivation's probability weighed with the "
                     "arc's outcomes (prolog/drm.pl)")
    method: str
    via: list[str]
    succeeded: int = Field(0, ge=0, description="times the robot drove the arc")
    failed: int = Field(0, ge=0, description="times it set out on the arc and did not "
                        "arrive")


class DrmOut(BaseModel):
    nodes: list[str]
    edges: list[DrmEdgeOut]


class StepOut(BaseModel):
    model_config = ConfigDict(validate_by_name=True)  # from_= here, "from" on the wire

    from_: str = Field(alias="from")
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


class RelationOut(BaseModel):
    """One relation and its probability (observed 1; derived P(rule)·ΠP(body)). Its
    fields depend on the kind: rec and rea ``from``, ``to``; frec also ``feature``; lr
    ``at``, ``left``, ``right``; align ``at``, ``first``, ``second``, ``kind``
    (same | opposite); reachable ``from``, ``to``, ``method``, ``via``."""

    model_config = ConfigDict(populate_by_name=True)
    p: float
    from_: str | None = Field(None, alias="from")
    to: str | None = None
    feature: str | None = None
    at: str | None = None
    left: str | None = None
    right: str | None = None
    first: str | None = None
    second: str | None = None
    kind: str | None = None
    method: str | None = None
    via: list[str] | None = None
