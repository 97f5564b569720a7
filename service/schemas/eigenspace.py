"""Eigenspace localization (Maeda & Shirai): turns of images in, localization
answers, the learned eigenspace, the camera."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from chizu.numeric.camera import CameraConfig
from chizu.service.schemas.common import PoseOut

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
    (counter-clockwise from the robot's heading), exactly one of: nested lists
    ``images[n][H][W]``; base64 PNG files ``images_png`` (grey, 8 or 16 bit), one per
    image; or ``turn_png``, one base64 PNG of the whole turn, its n images side by side
    from left to right (n x W wide; one file to decode, the cheapest to localize from)."""

    # exactly one of the three, and none is null: so the schema says (oneOf)
    model_config = ConfigDict(extra="forbid", json_schema_extra={
        "oneOf": [{"required": ["images"]}, {"required": ["images_png"]},
                  {"required": ["turn_png"]}]})
    images: Annotated[list[Image], Field(min_length=1, max_length=MAX_TURN_IMAGES)] = Field(
        default=None)  # type: ignore[assignment,arg-type]
    images_png: Annotated[list[Annotated[str, Field(max_length=1_000_000)]],
                          Field(min_length=1, max_length=MAX_TURN_IMAGES)] = Field(
        default=None)  # type: ignore[assignment,arg-type]
    turn_png: Annotated[str, Field(min_length=1, max_length=10_000_000)] = Field(
        default=None)  # type: ignore[assignment]

    @model_validator(mode="after")
    def _exactly_one(self) -> TurnIn:
        if sum(v is not None for v in (self.images, self.images_png, self.turn_png)) != 1:
            raise ValueError("give exactly one of images, images_png or turn_png")
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
    format: Literal["list", "png", "turn_png"] = Field(
        "png", description="turn_png: a turn as one base64 PNG, its images side by side "
                           "(`turn_png`, the cheapest to localize from); "
                           "png: base64 PNG images (`images_png`, ~10x smaller and faster "
                           "to localize from); list: nested lists in [0, 1] (`images`)")
    camera: CameraConfig | None = None


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


class LocalizationCandidate(BaseModel):
    """A group of agreeing candidates: its strongest member's pose at this stop."""

    pose: PoseOut
    votes: float
    triplet: int
    members: int


class RefusalOut(BaseModel):
    """Why a stop left the session without a unique answer: the first of the paper's
    tests to refuse it (``no_region``: eq. 6 admitted no image; ``plane_test``: none lay
    near its triplet's plane, eq. 4; ``vote_threshold``, ``vote_margin``: the vote of
    §2.5; ``candidate_set``: every hit in one candidate-multiple set, §3.3) and the figure
    it refused on."""

    test: Literal["no_region", "plane_test", "vote_threshold", "vote_margin",
                  "candidate_set"]
    d_err_min_m: float | None = Field(
        None, description="the turn's smallest D_err (eq. 6) when no image was admitted")
    votes: float | None = Field(None, description="the leading group's votes")
    rival_votes: float | None = Field(None, description="the strongest disagreeing group's")


class LocalizationOut(BaseModel):
    """The state after this stop, what the stop showed (``outcome``: none, unique,
    in_set, across, unlisted), the pose when z (the weighted mean of the winning group,
    averaged with the interpolation of the stop's whole turn), the numeric vote and up
    to 10 candidate groups, strongest first."""

    state: LocalizationState
    outcome: Literal["none", "unique", "in_set", "across", "unlisted"]
    pose: PoseOut | None
    stops: int
    unique: bool
    candidates: list[LocalizationCandidate]
    refused_by: RefusalOut | None = Field(
        None, description="why there is no unique answer yet (null when there is one)")
    answered_by: Literal["vote", "whole_turn_check"] | None = Field(
        None, description="what made the answer unique: the vote of single images (§2.5) "
                          "or the latest stop's whole turn fitting one place (null when "
                          "there is no unique answer)")


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


class LearningPointOut(BaseModel):
    id: int
    x: float
    y: float


class PointOut(BaseModel):
    x: float
    y: float


class TripletOut(BaseModel):
    """A localizable triplet (§2.3): its learning points' ids, the three directions, the
    triangle's area, the common target and its candidate-multiple set (§3.3), if any."""

    id: int
    points: list[int]
    directions_rad: list[float]
    area_m2: float
    target: PointOut
    candidate_set: int | None


class EntryModelOut(BaseModel):
    """Eq. 7's entry probability, c0 + c1 · distance."""

    c0: float
    c1_per_m: float


class EigenspaceSummaryOut(BaseModel):
    """What learning produced (a learning job's result)."""

    images: int
    learning_points: int
    directions: int
    k: int = Field(description="eigenspace dimension K")
    image_shape: list[int]
    triplets: int
    candidate_sets: int
    rejected_triplets: int
    source: str = Field(description="simulator | images")
    c_a: float
    d_thd_m: float
    entry_model: EntryModelOut | None
    region_coverage: float
    learning_strategy: list[dict[str, Any]] | None = Field(
        description="§4.2: each addition of learning points and P(Z) after it")
    timings_s: dict[str, float]


class EigenspaceOut(EigenspaceSummaryOut):
    points: list[LearningPointOut]
    triplet_list: list[TripletOut]


#: cells a coverage map may have (a 0.05 m raster of a 22 m x 22 m building)
MAX_COVERAGE_CELLS = 200_000


class CoverageOut(BaseModel):
    """Where one turn enters some localizable region (Maeda & Shirai eq. 7): the
    probability per cell of a raster over the world's bounds, row ``i`` and column ``j``
    centred at ``origin + cell_m (j + 1/2, i + 1/2)``; ``null`` where the floor is not
    free. ``share`` is the covered share (probability at least 0.5) of the free floor,
    the summary's ``region_coverage`` at the default cell."""

    origin: PointOut
    cell_m: float
    rows: int
    columns: int
    share: float
    p_enter: list[list[float | None]]


class CoveringOut(BaseModel):
    triplet: int
    distance_m: float


class CameraOut(BaseModel):
    """Base64 PNG images (``format`` png) or nested lists in [0, 1] (``format`` list)."""

    images_png: list[str] | None = None
    images: list[list[list[float]]] | None = None
    turn_png: str | None = Field(None, description="the turn's images side by side, left "
                                 "to right (format turn_png)")
