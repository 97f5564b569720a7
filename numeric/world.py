"""The one shared 2D world model.

Walls are segments with a texture id (camera images) and a laser
reflectivity; landmarks carry directional features; objects are cuboids.
The JSON world description (the body of ``POST /worlds``) is exactly
:class:`WorldDescription`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import (
    enclosed_cells,
    inside_outline,
    point_segment_distance,
    ray_crossings,
)
from chizu.numeric.textures import TEXTURE_NAMES

ID_PATTERN = r"^[a-z][a-zA-Z0-9_]{0,63}$"
Id = Annotated[str, Field(pattern=ID_PATTERN, description="id: ^[a-z][a-zA-Z0-9_]{0,63}$")]
Point = tuple[FiniteFloat, FiniteFloat]
Probability = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]

#: the built-in worlds (numeric/worlds.py TEMPLATES; a test keeps the two in step)
TemplateName = Literal["corridor", "loop", "demo", "office", "room_a", "room_b",
                       "summary_room", "fig11a", "fig11b", "room_c", "room_d",
                       "twin_hexagon", "mission"]

MAX_WALLS = 20_000
MAX_LANDMARKS = 5_000
MAX_OBJECTS = 2_000


def _known_texture(name: str) -> str:
    if name not in TEXTURE_NAMES:
        raise ValueError(f"unknown texture {name!r}; known: {', '.join(TEXTURE_NAMES)}")
    return name


Texture = Annotated[str, Field(max_length=64, description="a built-in texture id",
                               json_schema_extra={"enum": list(TEXTURE_NAMES)}),
                    AfterValidator(_known_texture)]
Brightness = Annotated[float, Field(
    gt=0.0, le=4.0, allow_inf_nan=False,
    description="lighting gain on the texture (1 = as photographed)")]


class Wall(BaseModel):
    model_config = ConfigDict(extra="forbid")
    a: Point
    b: Point
    texture: Texture = "brick"
    reflectivity: Probability = 0.5
    brightness: Brightness = 1.0

    @model_validator(mode="after")
    def _not_degenerate(self) -> Wall:
        if self.a == self.b:
            raise ValueError("wall endpoints a and b coincide")
        return self


class Feature(BaseModel):
    """A directional feature: visible from directions within half_width of direction."""

    model_config = ConfigDict(extra="forbid")
    name: Id
    direction_rad: FiniteFloat = 0.0
    half_width_rad: Annotated[float, Field(gt=0.0, le=np.pi, allow_inf_nan=False)] = np.pi / 2


class Landmark(BaseModel):
    """A recognisable landmark; coordinates are optional for purely qualitative worlds."""

    model_config = ConfigDict(extra="forbid")
    id: Id
    x: FiniteFloat | None = None
    y: FiniteFloat | None = None
    features: Annotated[list[Feature], Field(max_length=32)] = []

    @model_validator(mode="after")
    def _both_or_neither(self) -> Landmark:
        if (self.x is None) != (self.y is None):
            raise ValueError("give both x and y, or neither")
        return self

    @property
    def position(self) -> np.ndarray | None:
        return None if self.x is None else np.array([self.x, self.y])


class WorldObject(BaseModel):
    """A cuboid object with 4 side faces (used by the viewpoint planner)."""

    model_config = ConfigDict(extra="forbid")
    id: Id
    type: Annotated[str, Field(max_length=64)] = "A"
    x: FiniteFloat
    y: FiniteFloat
    theta: FiniteFloat = 0.0
    size_m: tuple[
        Annotated[float, Field(gt=0, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, allow_inf_nan=False)],
        Annotated[float, Field(gt=0, allow_inf_nan=False)],
    ] = (0.4, 0.3, 0.5)
    texture: Texture = "coffee"
    brightness: Brightness = 1.0
    reflectivity: Probability = 0.5

    def footprint(self) -> np.ndarray:
        """Corners (4, 2) of the cuboid's footprint, counter-clockwise."""
        hx, hy = self.size_m[0] / 2, self.size_m[1] / 2
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = np.cos(self.theta), np.sin(self.theta)
        return local @ np.array([[c, s], [-s, c]]) + np.array([self.x, self.y])


class WorldDescription(BaseModel):
    """A world as clients describe it."""

    model_config = ConfigDict(extra="forbid")
    name: Id
    walls: Annotated[list[Wall], Field(max_length=MAX_WALLS)] = []
    landmarks: Annotated[list[Landmark], Field(max_length=MAX_LANDMARKS)] = []
    objects: Annotated[list[WorldObject], Field(max_length=MAX_OBJECTS)] = []
    template: TemplateName | None = None
    rule_probabilities: Annotated[dict[Id, Probability], Field(max_length=64)] = {}
    parameters: Annotated[dict[Id, Annotated[float, Field(ge=0, allow_inf_nan=False)]],
                          Field(max_length=64)] = {}

    @model_validator(mode="after")
    def _unique_ids(self) -> WorldDescription:
        for kind, ids in (("landmarks", [lm.id for lm in self.landmarks]),
                          ("objects", [o.id for o in self.objects])):
            seen: set[str] = set()
            for i, x in enumerate(ids):
                if x in seen:
                    raise ValueError(f"{kind}[{i}].id {x!r} is not unique")
                seen.add(x)
        return self


class World:
    """A world description with numpy views for the simulators."""

    def __init__(self, description: WorldDescription) -> None:
        self.description = description

    @property
    def name(self) -> str:
        return self.description.name

    @cached_property
    def wall_a(self) -> np.ndarray:
        """Wall start points (W, 2)."""
        return np.array([w.a for w in self.description.walls], dtype=float).reshape(-1, 2)

    @cached_property
    def wall_b(self) -> np.ndarray:
        """Wall end points (W, 2)."""
        return np.array([w.b for w in self.description.walls], dtype=float).reshape(-1, 2)

    @cached_property
    def placed_landmarks(self) -> list[Landmark]:
        """Landmarks that have coordinates."""
        return [lm for lm in self.description.landmarks if lm.x is not None]

    @cached_property
    def landmark_ids(self) -> list[str]:
        return [lm.id for lm in self.placed_landmarks]

    @cached_property
    def landmark_xy(self) -> np.ndarray:
        """Positions (L, 2) of :attr:`placed_landmarks`."""
        return np.array([[lm.x, lm.y] for lm in self.placed_landmarks], dtype=float).reshape(-1, 2)

    @cached_property
    def landmark_index(self) -> dict[str, int]:
        return {lid: i for i, lid in enumerate(self.landmark_ids)}

    def landmark_position(self, landmark_id: str) -> np.ndarray:
        try:
            return self.landmark_xy[self.landmark_index[landmark_id]]
        except KeyError:
            raise InvalidInput(f"landmark {landmark_id!r} has no position in world "
                               f"{self.name!r}", field="landmark") from None

    @cached_property
    def surfaces(self) -> Surfaces:
        """Everything the camera and the laser see: walls, then the 4 side faces of every
        object."""
        d = self.description
        a = [w.a for w in d.walls]
        b = [w.b for w in d.walls]
        tex = [w.texture for w in d.walls]
        gain = [w.brightness for w in d.walls]
        refl = [w.reflectivity for w in d.walls]
        top = [np.inf] * len(d.walls)
        for o in d.objects:
            c = o.footprint()
            for k in range(4):
                a.append(tuple(c[k]))
                b.append(tuple(c[(k + 1) % 4]))
                tex.append(o.texture)
                gain.append(o.brightness)
                refl.append(o.reflectivity)
                top.append(o.size_m[2])
        return Surfaces(a=np.array(a, dtype=float).reshape(-1, 2),
                        b=np.array(b, dtype=float).reshape(-1, 2),
                        texture=tex, brightness=np.array(gain, dtype=float),
                        top_m=np.array(top, dtype=float),
                        reflectivity=np.array(refl, dtype=float))

    def is_free(self, xy: np.ndarray, clearance_m: float = 0.3) -> np.ndarray:
        """True for positions ``(M, 2)`` inside the walls (even-odd rule), outside every
        object and at least ``clearance_m`` from every surface."""
        surf = self.surfaces
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        near = point_segment_distance(xy, surf.a, surf.b).min(axis=1, initial=np.inf)
        walls = ~np.isfinite(surf.top_m)
        in_object = ray_crossings(xy, surf.a[~walls], surf.b[~walls]) % 2 == 1
        return np.asarray((near >= clearance_m) & self.inside(xy) & ~in_object)

    def inside(self, xy: np.ndarray) -> np.ndarray:
        """True for positions ``(M, 2)`` inside the building: enclosed by the walls (no
        path from outside without crossing one) and inside their outline by the even-odd
        rule in some axis direction, so rooms between partition walls count and the
        inside of a closed pillar does not (:func:`chizu.numeric.geometry.inside_outline`). A
        building whose outer walls leave a gap encloses nothing: then the even-odd rule
        towards +x alone decides, as it always did."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        walls = ~np.isfinite(self.surfaces.top_m)
        a, b = self.surfaces.a[walls], self.surfaces.b[walls]
        lo, res, enclosed = self._enclosed
        if not enclosed.any():
            return np.asarray(ray_crossings(xy, a, b) % 2 == 1)
        ij = np.floor((xy - lo) / res).astype(int)
        ok = ((ij >= 0) & (ij < np.array(enclosed.shape[::-1]))).all(axis=1)
        hit = np.zeros(len(xy), dtype=bool)
        hit[ok] = enclosed[ij[ok, 1], ij[ok, 0]]
        return np.asarray(hit & inside_outline(xy, a, b))

    @cached_property
    def _enclosed(self) -> tuple[np.ndarray, float, np.ndarray]:
        walls = ~np.isfinite(self.surfaces.top_m)
        if not walls.any():
            return np.zeros(2), 1.0, np.zeros((1, 1), dtype=bool)
        return enclosed_cells(self.surfaces.a[walls], self.surfaces.b[walls], 0.05)

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners ``(2,)`` of the bounding box of all surfaces."""
        surf = self.surfaces
        if len(surf.a) == 0:
            raise InvalidInput("the world has no walls", field="world")
        pts = np.vstack([surf.a, surf.b])
        return pts.min(axis=0), pts.max(axis=0)

    def sample_free(self, n: int, rng: np.random.Generator,
                    clearance_m: float = 0.3) -> np.ndarray:
        """``n`` positions ``(n, 2)`` drawn uniformly from the free space (rejection
        sampling in the walls' bounding box)."""
        lo, hi = self.bounds
        out: list[np.ndarray] = []
        got = 0
        for _ in range(1000):
            cand = rng.uniform(lo, hi, size=(max(2 * n, 64), 2))
            cand = cand[self.is_free(cand, clearance_m)]
            out.append(cand)
            got += len(cand)
            if got >= n:
                return np.vstack(out)[:n]
        raise InvalidInput("the world has (almost) no free space", field="world")


@dataclass(frozen=True)
class Surfaces:
    """Vertical surfaces: segments a->b (S, 2), texture id, lighting gain, top height
    (``inf`` for walls, which reach the ceiling) and laser reflectivity in [0, 1]."""

    a: np.ndarray
    b: np.ndarray
    texture: list[str]
    brightness: np.ndarray
    top_m: np.ndarray
    reflectivity: np.ndarray
