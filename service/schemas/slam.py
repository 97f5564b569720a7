"""Laser SLAM runs (Hara et al.; graph SLAM after Hess et al. 2016): scans in, run
status, committed maps."""

from __future__ import annotations

from typing import Annotated

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    ValidationInfo,
    field_validator,
    model_validator,
)

from chizu.numeric.slam.runner import SlamOptions
from chizu.service.schemas.common import PoseOut


class SlamRunIn(SlamOptions):
    """The body of POST /slam-runs: the run's options (the CLI's too), whose estimator
    parameters carry the estimator configs' own bounds (``to_config()`` gives the
    estimator's config), and whether the run continues the world's map."""

    resume: bool = Field(False, description="join the world's committed map: at the "
                         "commit the run is found in it and joined to it (graph SLAM only; "
                         "chizu.numeric.slam.merge), and its trajectory is in the map's frame; "
                         "a world without a map yet gets this run's")

    @field_validator("resume")
    @classmethod
    def _resume_needs_graph(cls, v: bool, info: ValidationInfo) -> bool:
        if v and info.data.get("method", "graph") != "graph":
            raise ValueError("resume continues a map with graph SLAM: method graph")
        return v

NonNegFinite = Annotated[float, Field(ge=0, allow_inf_nan=False)]
MAX_BEAMS = 4096


class ScanIn(BaseModel):
    """One laser scan with the odometry pose at its time stamp (like a ROS
    ``sensor_msgs/LaserScan`` plus ``nav_msgs/Odometry``). No-returns are ranges at or
    beyond ``range_max`` (NaN is rejected)."""

    model_config = ConfigDict(extra="forbid")
    t: FiniteFloat = Field(description="time stamp (s), strictly increasing within a run")
    ranges: Annotated[list[NonNegFinite], Field(min_length=1, max_length=MAX_BEAMS)]
    intensities: Annotated[list[NonNegFinite], Field(max_length=MAX_BEAMS)] | None = None
    angle_min: FiniteFloat = Field(description="direction of the first beam (rad)")
    angle_increment: Annotated[float, Field(gt=0, le=1.0, allow_inf_nan=False)]
    range_min: NonNegFinite = 0.02
    range_max: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 30.0
    odom: tuple[FiniteFloat, FiniteFloat, FiniteFloat] = Field(
        description="odometry pose (x, y, theta) at t")

    @model_validator(mode="after")
    def _consistent(self) -> ScanIn:
        if self.intensities is not None and len(self.intensities) != len(self.ranges):
            raise ValueError(f"intensities has {len(self.intensities)} values for "
                             f"{len(self.ranges)} ranges")
        if self.range_min >= self.range_max:
            raise ValueError("range_min must be below range_max")
        return self


class ScansIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scans: Annotated[list[ScanIn], Field(min_length=1, max_length=500)]


class SlamRunOut(BaseModel):
    """A run: its options, scans and keyframes so far, the last stamp and pose."""

    id: str
    world: str
    options: SlamRunIn
    scans: int
    keyframes: int
    last_t: float | None
    pose: PoseOut | None


class SlamRunListed(BaseModel):
    id: str
    method: str
    scans: int | None = Field(description="null until the run is replayed after a restart")


class SlamPoseOut(BaseModel):
    t: float | None
    pose: PoseOut | None
    scans: int


class TrajectoryOut(BaseModel):
    t: list[float]
    poses: list[list[float]]


class CommittedFactsOut(BaseModel):
    world: str
    run: str
    poses: int
    regions: int
    closures: int


class MapSummaryOut(BaseModel):
    free_m2: float
    occupied_m2: float
    unknown_m2: float
    resolution_m: float
    width: int
    height: int


class UnknownRegionOut(BaseModel):
    x: float
    y: float
    area_m2: float


class CommitOut(BaseModel):
    world: str
    run: str
    facts: CommittedFactsOut
    map: MapSummaryOut
    unknown_regions: list[UnknownRegionOut]
    loop_closures: int


class MapRegionOut(BaseModel):
    id: int
    x: float
    y: float
    area_m2: float


class NearRegionOut(MapRegionOut):
    distance: float


class WorldMapOut(BaseModel):
    """The committed map as the knowledge base sees it (prolog/slam.pl)."""

    run: str
    explored_fraction: float
    path_length_m: float
    resolution_m: float
    free_m2: float
    occupied_m2: float
    unknown_m2: float
    regions: list[MapRegionOut]
    loop_closures: int
