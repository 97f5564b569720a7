"""Simulated laser range finder with received-light intensity (Hara et al. §3).

The default is the paper's URG-04LX with the intensity firmware (Table 1): 0.02-5.6 m,
240 degrees in 360/512-degree steps, intensity 0-40 000. Every beam is ray-cast against
the shared world model (:attr:`chizu.numeric.world.World.surfaces`); the intensity of a return
is :func:`intensity_model` of the surface's reflectivity, the range and the incidence
angle, plus noise.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, Field

from chizu.numeric.geometry import ray_cast
from chizu.numeric.scan import LaserLog, Scan, beam_angles
from chizu.numeric.world import World


class LaserConfig(BaseModel):
    """A planar range finder; defaults = URG-04LX (intensity version), Table 1."""

    min_range_m: float = Field(0.02, ge=0)
    max_range_m: float = Field(5.6, gt=0)
    fov_rad: float = Field(float(np.radians(240.0)), gt=0, le=2 * np.pi)
    step_rad: float = Field(2 * np.pi / 512, gt=0)
    range_noise_m: float = Field(0.01, ge=0, description="1-sigma range noise")
    intensity_max: float = Field(40000.0, gt=0)
    intensity_noise: float = Field(400.0, ge=0, description="1-sigma intensity noise")
    intensity_range_half_m: float = Field(
        8.0, gt=0, description="range at which the intensity of a surface halves")
    laser_height_m: float = Field(0.3, ge=0, description="objects lower than this are unseen")
    scan_period_s: float = Field(0.1, gt=0)

    @property
    def angles(self) -> np.ndarray:
        n = int(np.floor(self.fov_rad / self.step_rad + 1e-9)) + 1
        return beam_angles(n, -0.5 * (n - 1) * self.step_rad, self.step_rad)


def intensity_model(reflectivity: np.ndarray, range_m: np.ndarray, cos_incidence: np.ndarray,
                    config: LaserConfig) -> np.ndarray:
    """Noise-free received intensity: ``I_max * rho * (1 + cos phi) / 2 / (1 + r / r_half)``
    -- proportional to the reflectivity, falling with range and with the incidence angle
    (a sensor with automatic gain does not fall as 1/r^2)."""
    return np.asarray(config.intensity_max * reflectivity * 0.5 * (1 + cos_incidence)
                      / (1 + range_m / config.intensity_range_half_m))


class Laser:
    """Scans of the world from a pose: ranges, intensities; no-returns = ``max_range_m``."""

    def __init__(self, world: World, config: LaserConfig | None = None) -> None:
        self.world = world
        self.config = config or LaserConfig()
        surf = world.surfaces
        tall = surf.top_m >= self.config.laser_height_m
        self._a, self._b = surf.a[tall], surf.b[tall]
        self._refl = surf.reflectivity[tall]
        d = self._b - self._a
        self._dir = d / np.linalg.norm(d, axis=1, keepdims=True)

    def measure(self, pose: np.ndarray, rng: np.random.Generator | None = None,
                ) -> tuple[np.ndarray, np.ndarray]:
        """Ranges and intensities ``(n,)`` at ``pose``; noise-free without ``rng``."""
        cfg = self.config
        local = cfg.angles
        world_ang = pose[2] + local
        dist, idx = ray_cast(pose[:2], world_ang, self._a, self._b, cfg.max_range_m)
        hit = idx >= 0
        ray = np.stack([np.cos(world_ang), np.sin(world_ang)], axis=1)
        seg = self._dir[np.maximum(idx, 0)]
        cos_inc = np.abs(ray[:, 0] * seg[:, 1] - ray[:, 1] * seg[:, 0])
        r = np.where(hit, dist, cfg.max_range_m)
        inten = np.where(hit, intensity_model(self._refl[np.maximum(idx, 0)], r, cos_inc, cfg),
                         0.0)
        if rng is not None:
            r = r + np.where(hit, rng.normal(0, cfg.range_noise_m, len(r)), 0.0)
            inten = inten + np.where(hit, rng.normal(0, cfg.intensity_noise, len(r)), 0.0)
        r = np.where(hit & (r < cfg.max_range_m), np.maximum(r, cfg.min_range_m),
                     cfg.max_range_m)
        return r, np.clip(inten, 0.0, cfg.intensity_max)

    def scan(self, t: float, pose: np.ndarray, odom: np.ndarray,
             rng: np.random.Generator | None = None) -> Scan:
        r, i = self.measure(pose, rng)
        cfg = self.config
        return Scan(t=t, ranges=r, angles=cfg.angles, odom=odom, intensities=i,
                    min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m)


def record_log(world: World, truth: np.ndarray, odom: np.ndarray, laser: Laser,
               rng: np.random.Generator, name: str = "sim") -> LaserLog:
    """A simulated :class:`LaserLog`: one noisy scan per true pose, stamped every
    ``scan_period_s``."""
    dt = laser.config.scan_period_s
    scans = [laser.scan(k * dt, truth[k], odom[k], rng) for k in range(len(truth))]
    return LaserLog(name, scans, truth.copy())
