"""The mission (service.mission): what a run is asked to do, and its record."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from chizu.numeric.eigenspace.analysis import EigenspaceConfig
from chizu.numeric.eigenspace.learning import LearningConfig
from chizu.numeric.simulator import ObserverConfig, OdometryConfig
from chizu.numeric.world import Id
from chizu.numeric.worlds import MISSION_DOOR, MISSION_GOAL, MISSION_ROOM

Point = tuple[FiniteFloat, FiniteFloat]


def mission_eigenspace() -> EigenspaceConfig:
    """The eigenspace the mission learns when the world has none: the paper's camera and
    directions on a 1 m grid (an office's walls hide most of a 2 m grid's triplets from
    each other), no learning strategy."""
    return EigenspaceConfig(learning=LearningConfig(spacing_m=1.0), learning_strategy=None)


class MissionConfig(BaseModel):
    """What one mission run is asked to do; the defaults fit the built-in ``mission``
    world (its goal landmark, door and goal room)."""

    model_config = ConfigDict(extra="forbid")
    goal: Id = Field(MISSION_GOAL, description="the landmark to reach")
    door: Point = Field(MISSION_DOOR, description="a point just inside the goal room's door")
    room: tuple[Point, Point] = Field(MISSION_ROOM,
                                      description="the goal room's lower and upper corner")
    start: tuple[Point, Point] | None = Field(
        None, description="where the robot may wake up (lower, upper corner); null: "
                          "anywhere in the free space")
    seed: int = Field(0, ge=0, le=2**31 - 1)
    max_stops: int = Field(10, ge=1, le=50, description="localization stops at most")
    max_replans: int = Field(3, ge=0, le=20, description="after a DRM arc fails, how many "
                             "times the robot reaches a landmark and plans again")
    camera_noise: float = Field(0.02, ge=0.0, le=1.0, description="pixel noise sigma")
    slam_method: Literal["graph", "gated", "rbpf"] = "graph"
    time_limit_s: float = Field(90.0, gt=0.0, le=3600.0, allow_inf_nan=False,
                                description="the goal room's summary (L1: hard)")
    loss: Literal["L1", "L2", "L3"] = "L1"
    eigenspace: EigenspaceConfig = Field(
        default_factory=mission_eigenspace,
        description="learned if the world has no eigenspace yet")
    odometry: OdometryConfig = OdometryConfig()
    observer: ObserverConfig = ObserverConfig(bearing_noise_rad=0.02, distance_noise_m=0.05)


class MissionStepOut(BaseModel):
    step: int = Field(ge=0)
    what: str = Field(description="localize, drm_path, slam_map, verify, evaluation, ...")
    result: dict[str, Any] = Field(description="the step's inputs and outputs; ok = false "
                                   "marks the step that ended the mission")


class MissionRecordOut(BaseModel):
    world: str
    steps: list[MissionStepOut]
