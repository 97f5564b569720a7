"""Step 1 of the paper (§3): an observation at a landmark and its quantities.

An :class:`Observation` is what the robot sees in one panoramic look at
landmark ``at``.  :func:`observation_quantities` turns it into the paper's
quantitative facts ``angle(L1, At, L2, D)`` (D = ∠L1·At·L2, the signed angle
from the ray At->L2 to the ray At->L1, counter-clockwise positive) and
``distance(At, L, D)``; the knowledge base converts the angles into the
qualitative ``lr``/``align`` relations and drops all quantities.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from chizu.numeric.geometry import wrap_angle
from chizu.numeric.world import Id

MAX_SEEN = 512


class SeenLandmark(BaseModel):
    model_config = ConfigDict(extra="forbid")
    landmark: Id
    bearing_rad: FiniteFloat = Field(description="robot frame, counter-clockwise, rad")
    distance_m: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    features: Annotated[list[Id], Field(max_length=32)] = []


class Observation(BaseModel):
    """One panoramic observation taken at landmark ``at``."""

    model_config = ConfigDict(extra="forbid")
    at: Id
    seen: Annotated[list[SeenLandmark], Field(max_length=MAX_SEEN)]

    @model_validator(mode="after")
    def _consistent(self) -> Observation:
        ids: set[str] = set()
        for i, s in enumerate(self.seen):
            if s.landmark == self.at:
                raise ValueError(f"seen[{i}].landmark is the observing landmark {self.at!r}")
            if s.landmark in ids:
                raise ValueError(f"seen[{i}].landmark {s.landmark!r} appears twice")
            ids.add(s.landmark)
        return self


def observation_quantities(
    obs: Observation,
) -> tuple[list[tuple[str, str, float]], list[tuple[str, float]]]:
    """The paper's angle and distance facts of one observation.

    Returns ``angles`` as (L1, L2, D) with D = ∠L1·at·L2 in (-pi, pi] for every
    unordered pair of seen landmarks, and ``distances`` as (L, metres).
    """
    angles = []
    s = obs.seen
    for i in range(len(s)):
        for j in range(i + 1, len(s)):
            d = float(wrap_angle(s[i].bearing_rad - s[j].bearing_rad))
            angles.append((s[i].landmark, s[j].landmark, d))
    distances = [(x.landmark, float(x.distance_m)) for x in s]
    return angles, distances
