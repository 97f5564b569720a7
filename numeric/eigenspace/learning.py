"""Learning (paper §2.1): images at N_w points x N_theta directions, PCA, projections.

``x' = P^T (x - mean)`` (eq. 1, mean-centred), ``f_d(x'1, x'2) = ||x'1 - x'2|| / (B sqrt N)``
(eq. 2) and ``d(x, s_ij) = f_d(x'(s_ij), P^T x)`` (eq. 3).  Images are floats in [0, 1],
so the dynamic range B is 1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import linalg
from scipy.sparse.linalg import svds

from chizu.numeric.camera import Camera
from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import wrap_angle
from chizu.numeric.world import World

DYNAMIC_RANGE = 1.0


class LearningConfig(BaseModel):
    """Where and how to learn: a grid of points inside the walls, N_theta directions, K."""

    model_config = ConfigDict(extra="forbid")
    spacing_m: float = Field(2.0, gt=0.05, le=100.0, description="learning grid spacing")
    margin_m: float = Field(1.0, ge=0.0, le=100.0,
                            description="grid offset from the bounding box of the walls")
    n_directions: int = Field(72, ge=4, le=360,
                              description="N_theta (72 = 5 deg; at 10 deg a regular grid "
                              "has no non-degenerate triplets at D_alpha = 50 mm)")
    k: int = Field(20, ge=1, le=512, description="eigenvectors kept")
    normalize_brightness: bool = Field(
        True, description="scale every image to mean 0.5 before PCA (lighting changes)")


class LearningStrategyConfig(BaseModel):
    """The learning strategy of §4.2: add learning points to the grid until a robot is
    localized within ``n_observations`` with probability >= ``target_probability``."""

    model_config = ConfigDict(extra="forbid")
    target_probability: float = Field(0.9, gt=0.0, le=1.0,
                                      description="P(Z) to reach (eq. 7 model)")
    n_observations: int = Field(5, ge=1, le=50, description="within this many stops")
    candidate_spacing_m: float = Field(0.5, gt=0.01, le=10.0,
                                       description="grid of candidate learning points")
    area_cell_m: float = Field(0.2, gt=0.01, le=10.0,
                               description="raster on which the localizable area is counted")
    max_additions: int = Field(30, ge=0, le=200,
                               description="learning points added at most (a twin counts "
                                           "with its point); the target usually ends it first")
    circle_points: int = Field(16, ge=4, le=360,
                               description="step 2's circle around tied candidates")
    learn_twins: bool = Field(
        True, description="in a room the learned turns show to be symmetric, learn each "
                          "added point's twin place too (numeric.eigenspace.twins), so "
                          "§3.3's candidate-multiple sets can form")


@dataclass
class EigenspaceModel:
    """Learned eigenspace: points ``(Nw, 2)`` [m], directions ``(Nt,)`` [rad],
    ``mean (N,)``, basis ``P (N, K)`` and projections ``(Nw, Nt, K)``."""

    points: np.ndarray
    directions: np.ndarray
    mean: np.ndarray
    basis: np.ndarray
    projections: np.ndarray
    image_shape: tuple[int, int]
    normalize_brightness: bool = True

    @property
    def n_pixels(self) -> int:
        return int(self.image_shape[0] * self.image_shape[1])

    @property
    def k(self) -> int:
        return int(self.basis.shape[1])

    def check_images(self, images: np.ndarray, field: str = "images") -> np.ndarray:
        """Validate ``(M, H, W)`` images against the model; returns them as float."""
        a = np.asarray(images, dtype=float)
        h, w = self.image_shape
        if a.ndim != 3:
            raise InvalidInput(f"images must have shape (n, {h}, {w}), got {a.shape}",
                               field=field)
        if a.shape[1:] != (h, w):
            raise InvalidInput(f"images are {a.shape[2]} x {a.shape[1]} px; the eigenspace "
                               f"was learned at {w} x {h} (resize them first)", field=field)
        if not np.isfinite(a).all():
            raise InvalidInput("images contain NaN or infinity", field=field)
        if a.min() < 0.0 or a.max() > 1.0:
            raise InvalidInput("pixel values must lie in [0, 1]", field=field)
        return a

    def project(self, images: np.ndarray) -> np.ndarray:
        """Eq. 1: projections ``(M, K)`` of images ``(M, H, W)``."""
        x = prepare(images, self.normalize_brightness)
        return (x - self.mean) @ self.basis

    def difference(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Eq. 2: f_d between projections (broadcast over leading axes)."""
        return f_d(a, b, self.n_pixels)

    def with_points(self, points: np.ndarray, projections: np.ndarray) -> EigenspaceModel:
        return EigenspaceModel(points=points, directions=self.directions, mean=self.mean,
                               basis=self.basis, projections=projections,
                               image_shape=self.image_shape,
                               normalize_brightness=self.normalize_brightness)


def f_d(a: np.ndarray, b: np.ndarray, n_pixels: int) -> np.ndarray:
    """Eq. 2: ``||x'1 - x'2|| / (B sqrt(N))`` over the last axis."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1) / (
        DYNAMIC_RANGE * np.sqrt(n_pixels))


def prepare(images: np.ndarray, normalize_brightness: bool) -> np.ndarray:
    """Image vectors ``(M, N)``: pixels in a fixed order, optionally brightness-normalised."""
    a = np.asarray(images, dtype=float)
    x = a.reshape(len(a), -1)
    if normalize_brightness:
        m = x.mean(axis=1, keepdims=True)
        x = x * (0.5 / np.maximum(m, 1e-6))
    return x


def learning_grid(world: World, spacing_m: float, margin_m: float) -> np.ndarray:
    """Learning points ``(Nw, 2)`` on a square grid inside the walls' bounding box.

    Points closer than 0.3 m to a surface are dropped (the robot cannot stand there).
    A 10 m room with 2 m spacing and a 1 m margin gives the paper's 25 points.
    """
    lo, hi = world.bounds
    lo, hi = lo + margin_m, hi - margin_m
    if np.any(hi < lo):
        raise InvalidInput("margin_m leaves no room inside the walls", field="margin_m")
    xs = np.arange(lo[0], hi[0] + 1e-9, spacing_m)
    ys = np.arange(lo[1], hi[1] + 1e-9, spacing_m)
    grid = np.array([(x, y) for y in ys for x in xs], dtype=float)
    return grid[world.is_free(grid)]


def render_learning_images(camera: Camera, points: np.ndarray, n_directions: int,
                           done: Callable[[float], None] | None = None) -> np.ndarray:
    """Images ``(Nw, Nt, H, W)``: a full turn at every learning point, theta_j = 2 pi j / Nt.
    ``done(fraction)`` after each point (a job's progress; it may raise to stop)."""
    turns = []
    for i, p in enumerate(points):
        turns.append(camera.render_turn(p, 0.0, n_directions))
        if done is not None:
            done((i + 1) / len(points))
    return np.stack(turns)


def learn(camera: Camera, points: np.ndarray, config: LearningConfig) -> EigenspaceModel:
    """Learning of §2.1 in the simulator: render a turn at every point, then
    :func:`learn_images`."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(points) < 3:
        raise InvalidInput("at least 3 learning points are needed", field="points")
    return learn_images(render_learning_images(camera, points, config.n_directions), points,
                        config)


def learn_images(images: np.ndarray, points: np.ndarray,
                 config: LearningConfig) -> EigenspaceModel:
    """Learning of §2.1 from images ``(Nw, Nt, H, W)`` taken at ``points (Nw, 2)`` in the
    directions 2 pi j / Nt (a simulator's or a user's camera): PCA of the mean-centred
    image vectors (SVD) and the projections of eq. 1."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    images = np.asarray(images, dtype=float)
    if len(points) < 3:
        raise InvalidInput("at least 3 learning points are needed", field="points")
    if images.ndim != 4 or images.shape[0] != len(points):
        raise InvalidInput(f"images must be (points, directions, H, W) with {len(points)} "
                           f"points, got {images.shape}", field="images")
    nw, nt, h, w = images.shape
    x = prepare(images.reshape(nw * nt, h, w), config.normalize_brightness)
    mean = x.mean(axis=0)
    basis = principal_axes(x - mean, config.k)
    proj = ((x - mean) @ basis).reshape(nw, nt, basis.shape[1])
    directions = wrap_angle(2.0 * np.pi * np.arange(nt) / nt)
    return EigenspaceModel(points=points, directions=directions, mean=mean, basis=basis,
                           projections=proj, image_shape=(h, w),
                           normalize_brightness=config.normalize_brightness)


def principal_axes(xc: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` leading eigenvectors ``(N, k)`` of the covariance of centred rows ``xc``
    (the eigenspace of §2.1), largest first, each signed so its largest entry is positive.

    Only K of up to N_w N_theta axes are kept, so a truncated SVD (ARPACK, fixed start
    vector) replaces the full one: 25 x 72 images of 64 x 32 px, 0.28 s instead of 1.7 s,
    the same axes to 1e-14."""
    r = min(xc.shape)
    k = min(k, r)
    if k < r - 1 and r > 50:
        _, s, vt = svds(xc, k=k, v0=np.ones(r), solver="arpack")
        vt = vt[np.argsort(s)[::-1]]
    else:
        _, _, vt = linalg.svd(xc, full_matrices=False, check_finite=False)
        vt = vt[:k]
    big = np.argmax(np.abs(vt), axis=1)
    vt = vt * np.sign(vt[np.arange(k), big])[:, None]
    return np.ascontiguousarray(vt.T)


def add_learning_point(model: EigenspaceModel, camera: Camera,
                       point: np.ndarray) -> EigenspaceModel:
    """Learn one more point in the existing eigenspace (the basis is kept: §4.2 adds
    points without recomputing P, which stays a good basis for the same room)."""
    imgs = camera.render_turn(np.asarray(point, dtype=float), 0.0, len(model.directions))
    proj = model.project(imgs)[None]
    return model.with_points(np.vstack([model.points, np.asarray(point, dtype=float)[None]]),
                             np.concatenate([model.projections, proj], axis=0))
