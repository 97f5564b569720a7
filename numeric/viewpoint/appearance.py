"""The object appearance model (Masuzawa & Miura, §3.2, eqs. 1-4): expected SIFT
matches per face of a cuboid.

A cuboid object is seen through its four side faces; face ``j`` has its outward normal
at ``theta_obj + j * pi/2``. For a robot at ``X`` the observation parameters of a face
are the distance ``d = |X - X_obj|`` and the angle ``theta_j`` between the face normal
and the direction to the robot (Fig. 3). The model is

    z_hat_j(d, theta_j) = a_j * exp(-b_j * d) * s(theta_j),
    s(theta) = 1 / (1 + exp(k * (|theta| - theta_half)))

-- an exponential fit per face over distance and one sigmoid fit over angle shared by
every object (Fig. 5); faces turned away (``|theta_j| >= pi/2``) give 0. The fits come
from measurement tables: simulated ones (:mod:`chizu.numeric.viewpoint.recognition`) or a
user's own measurements (:meth:`AppearanceModel.fit`).

From the model: the predicted matches z_hat (§3.2), the orientation posterior over
``N_theta`` discrete orientations (eqs. 1-2, ``k_pose = 0.1``), the recognition
probability P_recog (eqs. 3-4), the maximum recognition distance R_max (§4.2) and the
three verification radii of §5.1.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from scipy.optimize import curve_fit

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import wrap_angle

FloatArray = NDArray[np.float64]
N_FACES = 4
K_POSE = 0.1


class DistanceSample(BaseModel):
    """One measurement: ``matches`` SIFT matches on face ``face`` seen face-on from
    ``d_m`` metres."""

    model_config = ConfigDict(extra="forbid")
    face: int = Field(ge=0, lt=N_FACES)
    d_m: float = Field(gt=0, le=100, allow_inf_nan=False)
    matches: float = Field(ge=0, le=1e5, allow_inf_nan=False)


class AngleSample(BaseModel):
    """One measurement: the fraction ``ratio`` of the face-on matches that remain when the
    face is seen at ``theta_rad`` from its normal."""

    model_config = ConfigDict(extra="forbid")
    theta_rad: float = Field(ge=-np.pi, le=np.pi, allow_inf_nan=False)
    ratio: float = Field(ge=0, le=2, allow_inf_nan=False)


class MeasurementTables(BaseModel):
    """Measured match counts: over distance per face, and over angle (shared)."""

    model_config = ConfigDict(extra="forbid")
    distance: list[DistanceSample] = Field(min_length=2 * N_FACES, max_length=100_000)
    angle: list[AngleSample] = Field(min_length=3, max_length=100_000)


def exp_distance(d: ArrayLike, a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Matches of a face seen face-on from ``d``: ``a exp(-b d)`` (the distance fit)."""
    return np.asarray(np.asarray(a) * np.exp(-np.asarray(b) * np.asarray(d, dtype=float)))


def sigmoid_angle(theta: ArrayLike, k: float, theta_half: float) -> FloatArray:
    """Fraction of face-on matches left at ``theta`` from the normal (the angle fit);
    0 for a face turned away."""
    t = np.abs(np.asarray(theta, dtype=float))
    s = 1.0 / (1.0 + np.exp(np.clip(k * (t - theta_half), -50, 50)))
    return np.asarray(np.where(t < np.pi / 2, s, 0.0))


MAX_RANGE_M = 50.0
Matches = Annotated[float, Field(ge=0, le=1e6, allow_inf_nan=False)]
Decay = Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)]


class AppearanceParams(BaseModel):
    """Fitted model of one object type: ``a``, ``b`` per face, the shared sigmoid and the
    match threshold ``th_match`` (matches needed to call the object recognised)."""

    model_config = ConfigDict(extra="forbid")
    a: tuple[Matches, Matches, Matches, Matches] = Field(
        description="matches of each face seen face-on at 0 m")
    b: tuple[Decay, Decay, Decay, Decay] = Field(
        description="decay of the matches with distance, 1/m (> 0: fewer matches farther)")
    k: float = Field(ge=0, le=1e3, allow_inf_nan=False, description="sigmoid slope, 1/rad")
    theta_half: float = Field(gt=0, le=np.pi / 2, allow_inf_nan=False,
                              description="angle from the normal at half the matches, rad")
    th_match: float = Field(15.0, gt=0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _finite_range(self) -> AppearanceParams:
        """A recognition range past MAX_RANGE_M is not a physical camera (and would make
        the viewpoint circles and joint-point grids unbounded)."""
        reach = max((np.log(a / self.th_match) / b for a, b in zip(self.a, self.b, strict=True)
                     if a > self.th_match), default=0.0)
        if reach > MAX_RANGE_M:
            raise ValueError(f"b: these parameters recognise the object from {reach:.3g} m; "
                             f"at most {MAX_RANGE_M:g} m (is b too small?)")
        return self


@dataclass(frozen=True)
class FitReport:
    """Root-mean-square residuals of the fits (matches; ratio)."""

    distance_rmse: tuple[float, ...]
    angle_rmse: float


@dataclass(frozen=True)
class AppearanceModel:
    """The appearance model of one object type (§3.2) over ``n_theta`` orientations."""

    params: AppearanceParams
    n_theta: int = 8

    # -- fitting ----------------------------------------------------------------------
    @classmethod
    def fit(cls, tables: MeasurementTables, th_match: float = 15.0,
            n_theta: int = 8) -> tuple[AppearanceModel, FitReport]:
        """Fit the exponential per face and the shared sigmoid to measured tables
        (scipy ``curve_fit``); raises :class:`InvalidInput` when a face has fewer than two
        distances or a fit does not converge."""
        a, b, rmse = [], [], []
        for j in range(N_FACES):
            rows = [(s.d_m, s.matches) for s in tables.distance if s.face == j]
            if len({r[0] for r in rows}) < 2:
                raise InvalidInput(f"face {j} needs measurements at two or more distances",
                                   field="tables.distance")
            d, z = np.array(rows).T
            p0 = (max(float(z.max()), 1.0) * 1.5, 0.5)
            try:
                (aj, bj), _ = curve_fit(exp_distance, d, z, p0=p0, maxfev=10_000,
                                        bounds=([0.0, 0.0], [1e6, 50.0]))
            except (RuntimeError, ValueError) as exc:
                raise InvalidInput(f"the distance fit of face {j} failed: {exc}",
                                   field="tables.distance") from None
            a.append(float(aj))
            b.append(float(bj))
            rmse.append(float(np.sqrt(np.mean((exp_distance(d, aj, bj) - z) ** 2))))
        th, r = np.array([(s.theta_rad, s.ratio) for s in tables.angle]).T
        try:
            (k, half), _ = curve_fit(sigmoid_angle, th, r, p0=(6.0, 0.8), maxfev=10_000,
                                     bounds=([0.1, 0.0], [200.0, np.pi / 2]))
        except (RuntimeError, ValueError) as exc:
            raise InvalidInput(f"the angle fit failed: {exc}", field="tables.angle") from None
        try:
            params = AppearanceParams(a=tuple(a), b=tuple(b), k=float(k),  # type: ignore[arg-type]
                                      theta_half=float(half), th_match=th_match)
        except ValidationError as exc:  # e.g. matches that do not fall with distance
            err = exc.errors()[0]
            raise InvalidInput(f"the fitted model is not physical: {err['msg']}",
                               field="tables.distance" if "theta" not in str(err["loc"])
                               else "tables.angle") from None
        report = FitReport(tuple(rmse),
                           float(np.sqrt(np.mean((sigmoid_angle(th, k, half) - r) ** 2))))
        return cls(params, n_theta), report

    # -- prediction (§3.2) ------------------------------------------------------------
    @property
    def thetas(self) -> FloatArray:
        """The discrete object orientations theta_1..theta_N."""
        return np.asarray(np.arange(self.n_theta) * (2 * np.pi / self.n_theta))

    def predict(self, robot_xy: ArrayLike, obj_xy: ArrayLike, obj_theta: ArrayLike,
                ) -> FloatArray:
        """Predicted matches z_hat (..., 4) for robots ``(..., 2)`` and object orientations
        (broadcast): face ``j``'s normal is at ``obj_theta + j pi/2``."""
        p = self.params
        u = np.asarray(robot_xy, dtype=float) - np.asarray(obj_xy, dtype=float)
        d = np.hypot(u[..., 0], u[..., 1])
        view = np.arctan2(u[..., 1], u[..., 0])
        normals = np.asarray(obj_theta, dtype=float)[..., None] + np.arange(N_FACES) * np.pi / 2
        ang = wrap_angle(view[..., None] - normals)
        return np.asarray(exp_distance(d[..., None], np.array(p.a), np.array(p.b))
                          * sigmoid_angle(ang, p.k, p.theta_half))

    def recognisable(self, robot_xy: ArrayLike, obj_xy: ArrayLike) -> NDArray[np.bool_]:
        """Eq. 4's indicator ``exists j: z_hat_j >= th_match`` for every robot position
        ``(V, 2)`` and every discrete orientation: bool ``(V, n_theta)``."""
        xy = np.atleast_2d(np.asarray(robot_xy, dtype=float))
        z = self.predict(xy[:, None, :], obj_xy, self.thetas[None, :])
        return np.asarray(z.max(axis=-1) >= self.params.th_match)

    def posterior(self, z: ArrayLike, robot_xy: ArrayLike, obj_xy: ArrayLike,
                  prior: ArrayLike | None = None) -> FloatArray:
        """Orientation posterior after observing matches ``z`` (4,) from ``robot_xy``
        (eqs. 1-2): ``P(theta_i|z) ~ exp(-k_pose sum_j |z_j - z_hat_j|) P(theta_i)``."""
        zz = np.asarray(z, dtype=float)
        if zz.shape != (N_FACES,) or not np.all(np.isfinite(zz)) or np.any(zz < 0):
            raise InvalidInput("z must be 4 finite match counts >= 0", field="z")
        pr = self.uniform_prior() if prior is None else np.asarray(prior, dtype=float)
        zh = self.predict(np.asarray(robot_xy, dtype=float)[None, :], obj_xy, self.thetas)
        log_l = -K_POSE * np.abs(zz[None, :] - zh).sum(axis=1)
        w = np.exp(log_l - log_l.max()) * pr
        s = w.sum()
        return np.asarray(w / s) if s > 0 else self.uniform_prior()

    def p_recog(self, robot_xy: ArrayLike, obj_xy: ArrayLike,
                belief: ArrayLike | None = None) -> FloatArray:
        """Recognition probability per robot position ``(V,)`` (eqs. 3-4): the belief mass
        of the orientations under which some face gives ``th_match`` matches."""
        b = self.uniform_prior() if belief is None else np.asarray(belief, dtype=float)
        return np.asarray(self.recognisable(robot_xy, obj_xy).astype(float) @ b)

    def uniform_prior(self) -> FloatArray:
        return np.full(self.n_theta, 1.0 / self.n_theta)

    # -- distances (§4.2, §5.1) -------------------------------------------------------
    def face_range(self, theta: ArrayLike) -> FloatArray:
        """Largest distance (..., 4) at which each face seen at ``theta`` (..., 4) from
        its normal still gives ``th_match`` matches (negative: never)."""
        p = self.params
        s = sigmoid_angle(theta, p.k, p.theta_half) * np.array(p.a)
        with np.errstate(divide="ignore"):
            return np.asarray(np.where(s > 0, np.log(np.maximum(s, 1e-300) / p.th_match)
                                       / np.maximum(np.array(p.b), 1e-12), -np.inf))

    @cached_property
    def r_max(self) -> float:
        """R_max: the farthest distance at which the object can be recognised (its best
        face seen face-on); computed once per model (the model is immutable)."""
        return float(max(self.face_range(np.zeros(N_FACES)).max(), 0.0))

    @cached_property
    def _r_min_720(self) -> float:
        return self._r_min(720)

    def r_min(self, n_dirs: int = 720) -> float:
        """The largest distance at which the object is recognisable whatever direction
        it is seen from (0 when some direction never recognises it); the default
        resolution is computed once per model (every re-plan asks for it)."""
        return self._r_min_720 if n_dirs == 720 else self._r_min(n_dirs)

    def _r_min(self, n_dirs: int) -> float:
        phi = np.linspace(-np.pi, np.pi, n_dirs, endpoint=False)
        ang = wrap_angle(phi[:, None] - np.arange(N_FACES) * np.pi / 2)
        reach = self.face_range(ang).max(axis=1)
        return float(max(reach.min(), 0.0))

    def radii(self, min_standoff_m: float) -> tuple[float, float, float]:
        """The three verification circles of §5.1: r_min (any side), their mean, r_max
        (one face only; 0.95 R_max so that the best face still counts), each at least
        ``min_standoff_m`` from the object."""
        hi = max(0.95 * self.r_max, min_standoff_m)  # just inside R_max: P_recog > 0
        lo = min(max(self.r_min(), min_standoff_m), hi)
        return lo, 0.5 * (lo + hi), hi
