"""Localization runs on a world's committed map: scans in, the pose in the map out."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from chizu.service.schemas.common import PoseOut


class LocalizationRunIn(BaseModel):
    """A localization run takes the world's committed map as it is now and one parameter
    set for every map (numeric.slam.map_localization); nothing to choose."""

    model_config = ConfigDict(extra="forbid")


class LocalizationRunOut(BaseModel):
    """A run: the map it localizes on, its scans so far, where it stands."""

    id: str
    world: str
    map: str = Field(description="sha256 of the map.chizu the run localizes on")
    scans: int
    last_t: float | None
    state: Literal["searching", "confirming", "tracking"] = Field(
        description="searching: lost, a global search over the whole map; confirming: a "
                    "fix is being checked; tracking: localized")
    pose: PoseOut | None = Field(description="the last scan's pose in the map's frame; "
                                 "null unless tracking")
    score: float | None = Field(description="the last scan's match score (0-1)")
    first_fix_s: float | None = Field(description="log seconds from the first scan to the "
                                      "first fix; null: not yet")
    fixes: list[float] = Field(description="stamps of every fix (the first, then the "
                               "recoveries)")
    losses: list[float] = Field(description="stamps at which a tracked pose was lost")


class LocalizationRunListed(BaseModel):
    id: str
    map: str
    scans: int | None = Field(description="null until the run is replayed after a restart")


class LocalizedTrajectoryOut(BaseModel):
    t: list[float]
    poses: list[list[float] | None] = Field(description="x, y, theta per scan in the map's "
                                            "frame; null where the scan was not localized")
