"""The camera of the one simulator: pinhole, small grey images.

Every image column is a ray cast (:func:`chizu.numeric.geometry.ray_cast`) against the
world's vertical surfaces (walls and object faces); the hit surface's texture is
sampled with perspective -- the wall height covered by a pixel grows with the
distance -- from the mip level whose texel matches the pixel's footprint.  Above
the walls is the ceiling, below them the floor.  Objects are as tall as their
``size_m[2]``; what lies behind and above them stays visible.

Image convention: ``(H, W)`` floats in [0, 1]; column 0 is the robot's left edge
of view, row 0 the top.  A *turn* is ``n`` images at headings
``theta0 + 2*pi*j/n`` (counter-clockwise), the way a robot turning in place
would take them.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from chizu.numeric.geometry import ray_cast
from chizu.numeric.textures import BASE_TEXELS, LEVELS, pyramid
from chizu.numeric.world import World


class CameraConfig(BaseModel):
    """Pinhole camera; sizes in pixels, angles in rad, lengths in m."""

    model_config = ConfigDict(extra="forbid")
    width_px: int = Field(64, ge=4, le=256)
    height_px: int = Field(32, ge=4, le=256)
    hfov_rad: float = Field(float(np.deg2rad(60.0)), gt=0.05, lt=np.pi - 0.05)
    camera_height_m: float = Field(1.0, gt=0.0, le=10.0)
    wall_height_m: float = Field(2.5, gt=0.0, le=20.0)
    texture_tile_m: float = Field(5.0, gt=0.0, le=100.0,
                                  description="wall length one texture tile spans")
    floor_level: float = Field(0.3, ge=0.0, le=1.0)
    ceiling_level: float = Field(0.85, ge=0.0, le=1.0)
    noise_sigma: float = Field(0.0, ge=0.0, le=1.0, description="Gaussian pixel noise")
    supersample: int = Field(2, ge=1, le=4)

    @property
    def focal_px(self) -> float:
        return 0.5 * self.width_px / float(np.tan(0.5 * self.hfov_rad))

    @property
    def pixels(self) -> int:
        return self.width_px * self.height_px


class Camera:
    """Renders images of ``world`` (see the module docstring for the conventions)."""

    def __init__(self, world: World, config: CameraConfig | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.world = world
        self.config = config or CameraConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        c = self.config
        ss = c.supersample
        f = c.focal_px
        # sub-pixel column offsets (right positive) -> ray angle offsets (left positive)
        xc = (np.arange(c.width_px * ss) + 0.5) / ss - 0.5 * c.width_px
        self._phi = -np.arctan2(xc, f)
        yc = 0.5 * c.height_px - (np.arange(c.height_px * ss) + 0.5) / ss
        self._tan_elev = yc / f  # (Hs,) up positive
        names = world.surfaces.texture
        self._tex_names = sorted(set(names))
        self._tex_id = np.array([self._tex_names.index(n) for n in names], dtype=int)

    # -- public ---------------------------------------------------------------------
    def render(self, pose: np.ndarray) -> np.ndarray:
        """One image ``(H, W)`` at pose (x, y, theta)."""
        p = np.asarray(pose, dtype=float)
        return self.render_headings(p[:2], np.array([p[2]]))[0]

    def render_turn(self, xy: np.ndarray, theta0: float, n: int) -> np.ndarray:
        """A full turn: ``n`` images ``(n, H, W)`` at ``theta0 + 2*pi*j/n``."""
        return self.render_headings(np.asarray(xy, dtype=float),
                                    theta0 + 2.0 * np.pi * np.arange(n) / n)

    def render_many(self, poses: np.ndarray) -> np.ndarray:
        """Images ``(M, H, W)`` for poses ``(M, 3)`` (grouped by position internally)."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        out = np.empty((len(poses), self.config.height_px, self.config.width_px))
        groups: dict[tuple[float, float], list[int]] = defaultdict(list)
        for i, p in enumerate(poses):
            groups[(float(p[0]), float(p[1]))].append(i)
        for (x, y), idx in groups.items():
            out[idx] = self.render_headings(np.array([x, y]), poses[idx, 2])
        return out

    def render_headings(self, xy: np.ndarray, headings: np.ndarray) -> np.ndarray:
        """Images ``(M, H, W)`` from position ``xy`` at each heading in ``headings``."""
        c = self.config
        ss = c.supersample
        m = len(headings)
        angles = (np.asarray(headings, dtype=float)[:, None] + self._phi[None, :]).ravel()
        phi = np.tile(self._phi, m)
        img = self._render_columns(xy, angles, phi)  # (Hs, M*Ws)
        img = img.reshape(c.height_px * ss, m, c.width_px * ss).transpose(1, 0, 2)
        img = img.reshape(m, c.height_px, ss, c.width_px, ss).mean(axis=(2, 4))
        if c.noise_sigma > 0:
            img = img + self.rng.normal(0.0, c.noise_sigma, img.shape)
        return np.clip(img, 0.0, 1.0)

    # -- internals --------------------------------------------------------------------
    def _render_columns(self, xy: np.ndarray, angles: np.ndarray,
                        phi: np.ndarray) -> np.ndarray:
        """Sub-pixel columns ``(Hs, R)`` for rays at world ``angles`` (R,)."""
        c = self.config
        surf = self.world.surfaces
        hs = len(self._tan_elev)
        r = len(angles)
        is_wall = ~np.isfinite(surf.top_m)
        img = np.where(self._tan_elev[:, None] > 0, c.ceiling_level, c.floor_level)
        img = np.broadcast_to(img, (hs, r)).copy()
        depth_drawn = np.full((hs, r), np.inf)
        # walls first, then objects drawn over them where they are nearer
        for mask in (is_wall, ~is_wall):
            if not mask.any():
                continue
            sel = np.flatnonzero(mask)
            t, k = ray_cast(xy, angles, surf.a[sel], surf.b[sel])
            k = np.where(k >= 0, sel[np.maximum(k, 0)], -1)
            hit = k >= 0
            if not hit.any():
                continue
            z = t * np.cos(phi)  # perpendicular depth
            h = c.camera_height_m + z[None, :] * self._tan_elev[:, None]  # (Hs, R)
            top = np.minimum(surf.top_m[np.maximum(k, 0)], c.wall_height_m)
            on = hit[None, :] & (h >= 0.0) & (h <= top[None, :]) & (t[None, :] < depth_drawn)
            kk = np.maximum(k, 0)
            a = surf.a[kk]
            d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
            hitp = xy[None, :] + np.where(hit, t, 0.0)[:, None] * d
            along = np.linalg.norm(hitp - a, axis=1)  # metres from the surface start
            # a texture spans texture_tile_m along the wall and the full wall height
            texels_per_m = BASE_TEXELS / c.texture_tile_m
            texels_per_m_v = BASE_TEXELS / c.wall_height_m
            u0 = along * texels_per_m  # (R,)
            footprint = z / (c.focal_px * c.supersample) * max(texels_per_m, texels_per_m_v)
            level = np.clip(np.floor(np.log2(np.maximum(footprint, 1.0))), 0, LEVELS - 1)
            level = level.astype(int)
            v0 = (c.wall_height_m - h) * texels_per_m_v  # (Hs, R)
            # one map_coordinates call per (texture, mip level) among the columns
            key = np.where(hit, self._tex_id[kk] * LEVELS + level, -1)
            gain = surf.brightness[kk]
            for kv in np.unique(key[key >= 0]):
                cm = np.flatnonzero(key == kv)
                rows, cl = np.nonzero(on[:, cm])
                if len(rows) == 0:
                    continue
                cols = cm[cl]
                lv = int(kv % LEVELS)
                lvl_img = pyramid(self._tex_names[int(kv // LEVELS)])[lv]
                scale = 2.0 ** lv
                yy = (v0[rows, cols] + 0.5) / scale - 0.5
                xx = (u0[cols] + 0.5) / scale - 0.5
                img[rows, cols] = gain[cols] * ndimage.map_coordinates(
                    lvl_img, [yy, xx], order=1, mode="grid-wrap")
                depth_drawn[rows, cols] = t[cols]
        return img

