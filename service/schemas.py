"""Response schemas (request bodies are the numeric models themselves)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from numeric.camera import CameraConfig
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


# -- eigenspace localization ---------------------------------------------------------------
MAX_TURN_IMAGES = 360
MAX_IMAGE_SIDE = 256


class PoseIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    x: FiniteFloat
    y: FiniteFloat
    theta: FiniteFloat = 0.0


Row = Annotated[list[FiniteFloat], Field(min_length=1, max_length=MAX_IMAGE_SIDE)]
Image = Annotated[list[Row], Field(min_length=1, max_length=MAX_IMAGE_SIDE)]


class TurnIn(BaseModel):
    """One full turn of grey images in [0, 1], in order of relative heading 2*pi*j/n
    (counter-clockwise from the robot's heading): as nested lists ``images`` [n][H][W]
    or as base64 PNG files ``images_png`` (8-bit grey), exactly one of the two."""

    model_config = ConfigDict(extra="forbid")
    images: Annotated[list[Image], Field(min_length=1, max_length=MAX_TURN_IMAGES)] | None = None
    images_png: Annotated[list[Annotated[str, Field(max_length=1_000_000)]],
                          Field(min_length=1, max_length=MAX_TURN_IMAGES)] | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> TurnIn:
        if (self.images is None) == (self.images_png is None):
            raise ValueError("give exactly one of images or images_png")
        return self


class OdometryIn(BaseModel):
    """Motion from the previous stop's start pose, in that pose's frame (m, m, rad)."""

    model_config = ConfigDict(extra="forbid")
    dx: FiniteFloat
    dy: FiniteFloat
    dtheta: FiniteFloat


class StopIn(TurnIn):
    odometry: OdometryIn | None = None


class CameraIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    pose: PoseIn
    turn: Annotated[int, Field(ge=1, le=MAX_TURN_IMAGES)] | None = Field(
        None, description="render a full turn of this many images instead of one")
    format: Literal["list", "png"] = Field(
        "png", description="png: base64 PNG images (`images_png`, ~10x smaller and faster "
                           "to localize from); list: nested lists in [0, 1] (`images`)")
    camera: CameraConfig | None = None


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


# -- eigenspace localization answers (Maeda & Shirai §2.5, §3.4, Fig. 4) ----------------
class StateX(BaseModel):
    """No localizable region entered yet: position unknown."""

    state: Literal["x"]


class StateY(BaseModel):
    """Regions entered but not told apart: ambiguous within candidate-multiple set
    ``set`` (§3.3), or "unlisted": among regions in no known set, or in several."""

    state: Literal["y"]
    set: int | Literal["unlisted"]


class StateZ(BaseModel):
    """Localized (absorbing)."""

    state: Literal["z"]


LocalizationState = Annotated[StateX | StateY | StateZ, Field(discriminator="state")]


class PoseOut(BaseModel):
    x: float
    y: float
    theta: float


class LocalizationCandidate(BaseModel):
    """A group of agreeing candidates: its strongest member's pose at this stop."""

    pose: PoseOut
    votes: float
    triplet: int
    members: int


class LocalizationOut(BaseModel):
    """The state after this stop, what the stop showed (``outcome``: none, unique,
    in_set, across, unlisted), the pose when z (the weighted mean of the winning group),
    the numeric vote and up to 10 candidate groups, strongest first."""

    state: LocalizationState
    outcome: Literal["none", "unique", "in_set", "across", "unlisted"]
    pose: PoseOut | None
    stops: int
    unique: bool
    candidates: list[LocalizationCandidate]


class SessionLocalizationOut(LocalizationOut):
    """:class:`LocalizationOut` of a multi-stop session."""

    id: str


class SessionCreated(BaseModel):
    id: str
    world: str
    state: LocalizationState
    stops: int


class MoveOut(BaseModel):
    alpha_rad: float
    l_m: float
    beta_rad: float


class NextMoveOut(BaseModel):
    """The movement strategy's action a = (alpha, l, beta) maximising Q(Z) (eq. 8), or
    none once localized."""

    state: LocalizationState
    action: MoveOut | None
    q_z: float


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
