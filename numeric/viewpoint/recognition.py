"""Simulated object recognition: the "true" match counts a camera would get from a cuboid
object with 4 faces, standing in for SIFT matching on real images (Masuzawa & Miura,
§3.1).

The simulator's ground truth is deliberately *not* of the model's functional form: the
expected matches of face ``j`` seen from distance ``d`` at angle ``theta`` to its normal
are ``F_j / (1 + (d / d_half)^2) * max(0, cos theta)^gamma`` (features shrink below the
detector's scale as the distance grows; foreshortening), drawn Poisson. Faces behind the
object or hidden by walls give nothing. The appearance model of §3.2 is then *fitted* to
match counts measured in this simulator (:func:`measure_tables`), as the paper fitted
real measurements.
"""

from __future__ import annotations

import functools

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.geometry import line_of_sight, wrap_angle
from chizu.numeric.viewpoint.appearance import (
    N_FACES,
    AngleSample,
    AppearanceModel,
    DistanceSample,
    MeasurementTables,
)
from chizu.numeric.world import World


class ObjectKind(BaseModel):
    """A known object type: SIFT features on each face, its value (eq. 16) and the mean
    number per room (n_bar, eqs. 10 and 17)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=64)
    features: tuple[int, int, int, int] = (80, 60, 45, 70)
    d_half_m: float = Field(0.7, gt=0, allow_inf_nan=False)
    gamma: float = Field(1.5, gt=0, allow_inf_nan=False)
    value: float = Field(50.0, ge=0, allow_inf_nan=False)
    mean_count: float = Field(1.0, ge=0, allow_inf_nan=False)


#: The paper's three target objects (Fig. 4): A, B, C, with different texture per face.
OBJECT_KINDS: dict[str, ObjectKind] = {
    "A": ObjectKind(name="A", features=(90, 70, 50, 75), d_half_m=0.7),
    "B": ObjectKind(name="B", features=(70, 55, 60, 40), d_half_m=0.65),
    "C": ObjectKind(name="C", features=(60, 45, 35, 55), d_half_m=0.6),
}


class Recogniser:
    """Simulated recognition of the world's objects: match counts per face."""

    def __init__(self, world: World, kinds: dict[str, ObjectKind] | None = None,
                 th_match: float = 15.0) -> None:
        self.world = world
        self.kinds = kinds or OBJECT_KINDS
        self.th_match = th_match

    def expected(self, kind: ObjectKind, robot_xy: np.ndarray, obj_xy: np.ndarray,
                 obj_theta: float) -> np.ndarray:
        """Expected (noise-free) matches (4,) of each face."""
        u = np.asarray(robot_xy, float) - np.asarray(obj_xy, float)
        d = float(np.hypot(*u))
        ang = wrap_angle(np.arctan2(u[1], u[0]) - obj_theta - np.arange(N_FACES) * np.pi / 2)
        scale = 1.0 / (1.0 + (d / kind.d_half_m) ** 2)
        return np.asarray(np.array(kind.features) * scale
                          * np.maximum(np.cos(ang), 0.0) ** kind.gamma)

    def observe(self, robot_xy: np.ndarray, object_id: str, rng: np.random.Generator,
                ) -> np.ndarray:
        """Measured matches (4,) of the world object ``object_id`` from ``robot_xy``; zeros
        when a wall hides it."""
        obj = next(o for o in self.world.description.objects if o.id == object_id)
        centre = np.array([obj.x, obj.y])
        if len(self.world.wall_a) and not line_of_sight(robot_xy, centre[None, :],
                                                        self.world.wall_a,
                                                        self.world.wall_b)[0]:
            return np.zeros(N_FACES)
        kind = self.kinds.get(obj.type, next(iter(self.kinds.values())))
        return rng.poisson(self.expected(kind, robot_xy, centre, obj.theta)).astype(float)

    def recognised(self, z: np.ndarray) -> bool:
        return bool(np.max(z) >= self.th_match)


def measure_tables(kind: ObjectKind, rng: np.random.Generator,
                   distances_m: np.ndarray | None = None, angles_rad: np.ndarray | None = None,
                   repeats: int = 5, angle_distance_m: float = 0.5) -> MeasurementTables:
    """The measurement campaign of §3.2 in the simulator: every face face-on at a range
    of distances, and face 0 at a range of angles (as a fraction of its face-on count)."""
    d = np.arange(0.3, 2.51, 0.1) if distances_m is None else distances_m
    th = np.radians(np.arange(-80, 81, 10)) if angles_rad is None else angles_rad
    dummy = World.__new__(World)
    rec = Recogniser(dummy, {kind.name: kind})
    origin = np.zeros(2)
    dist_rows: list[DistanceSample] = []
    for j in range(N_FACES):
        for dk in d:
            normal = j * np.pi / 2
            at = dk * np.array([np.cos(normal), np.sin(normal)])
            for _ in range(repeats):
                z = rng.poisson(rec.expected(kind, at, origin, 0.0))[j]
                dist_rows.append(DistanceSample(face=j, d_m=float(dk), matches=float(z)))
    face_on = rec.expected(kind, np.array([angle_distance_m, 0.0]), origin, 0.0)[0]
    ang_rows = []
    for t in th:
        at = angle_distance_m * np.array([np.cos(t), np.sin(t)])
        for _ in range(repeats):
            z = rng.poisson(rec.expected(kind, at, origin, 0.0))[0]
            ang_rows.append(AngleSample(theta_rad=float(t), ratio=float(min(z / face_on, 2.0))))
    return MeasurementTables(distance=dist_rows, angle=ang_rows)


def fitted_models(kinds: dict[str, ObjectKind] | None = None, seed: int = 0,
                  th_match: float = 15.0, n_theta: int = 8) -> dict[str, AppearanceModel]:
    """Appearance models fitted to simulated measurements, one per object kind (the
    built-in kinds' fits are computed once per process)."""
    if kinds is None:
        return dict(_builtin_models(seed, th_match, n_theta))
    rng = np.random.default_rng(seed)
    out = {}
    for name, kind in kinds.items():
        model, _ = AppearanceModel.fit(measure_tables(kind, rng), th_match, n_theta)
        out[name] = model
    return out


@functools.cache
def _builtin_models(seed: int, th_match: float, n_theta: int) -> dict[str, AppearanceModel]:
    return fitted_models(OBJECT_KINDS, seed, th_match, n_theta)
