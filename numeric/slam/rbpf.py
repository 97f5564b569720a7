"""Rao-Blackwellized particle-filter SLAM with intensity (§7, eqs. 6-9).

Eq. 6 factors the posterior into the trajectory (particles) and the map given the
trajectory (one map per particle). Per matched scan (§7.3):

1. prediction, eq. 7: ``x_t = x_{t-1} (+) (u_t + w)``, w ~ N(0, Σ_w) with Σ_w growing
   with the odometry increment u_t;
2. likelihood, eqs. 8-9: ``d_t`` = mean over the scan's beams of the capped augmented
   squared residual ``||s_m - T s_z||^2 + alpha (l_m - l_z)^2`` to the particle's own
   map (nearest point in the sense of eq. 1, looked up in per-keyframe
   :class:`~numeric.slam.keyframes.LikelihoodField` grids), and
   ``p(z|x, m) ∝ exp(-d_t^2 / (2 sigma_z^2))`` exactly as eq. 8 writes it;
3. resampling with a constant particle count (systematic), every step as in the paper
   or only when the effective sample size drops below ``ess_threshold`` x N;
4. map update: a keyframe is added when the robot has moved far enough; every particle
   stores its own pose for it.

Maps are never copied: the keyframe scans are shared and each particle's map is its
keyframe poses, kept as one pose array per keyframe plus a lineage matrix of indices
that resampling permutes. The trajectory is a tree of (pose, parent) arrays, walked back
from the particle with the highest accumulated likelihood (§7.4) at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from numeric.geometry import compose, relative
from numeric.slam.gated import GateConfig, inside_gate
from numeric.slam.intensity_icp import IcpConfig, Reference, intensity_icp
from numeric.slam.keyframes import FieldCache, FieldConfig, Keyframes, MapConfig, moved
from numeric.slam.scan import Scan


class MotionNoise(BaseModel):
    """Σ_w of eq. 7, one sigma per component, growing with the increment."""

    xy_m: float = Field(0.01, ge=0)
    xy_per_m: float = Field(0.1, ge=0)
    xy_per_rad: float = Field(0.02, ge=0)
    theta_rad: float = Field(0.005, ge=0)
    theta_per_rad: float = Field(0.1, ge=0)
    theta_per_m: float = Field(0.05, ge=0)

    def sigmas(self, u: np.ndarray) -> np.ndarray:
        d, a = float(np.hypot(u[0], u[1])), abs(float(u[2]))
        sxy = self.xy_m + self.xy_per_m * d + self.xy_per_rad * a
        return np.array([sxy, sxy, self.theta_rad + self.theta_per_rad * a + self.theta_per_m * d])


class RbpfConfig(BaseModel):
    """Parameters of the RBPF (paper: 512 particles, σ_z and alpha set empirically)."""

    particles: int = Field(512, ge=1, le=10000)
    alpha: float = Field(0.0, ge=0, description="intensity weight of eq. 9 (as in eq. 1)")
    sigma_z: float = Field(0.0005, gt=0, description="sigma of eq. 8, in the units of d_t (m²)")
    likelihood: Literal["eq8", "linear"] = Field(
        "eq8", description="eq8: exp(-d_t^2 / 2 sigma_z^2) as printed; linear: "
                           "exp(-d_t / 2 sigma_z^2), a Gaussian on the residual with sigma_z in m")
    beams: int = Field(90, ge=8, le=2000, description="beams used in eq. 9 (evenly picked)")
    proposal: Literal["odometry", "gated-icp"] = Field(
        "odometry", description="odometry: eq. 7 on the odometry increment (the paper); "
        "gated-icp: eq. 7 on the increment Intensity-ICP finds for the best particle when "
        "eq. 5 accepts it, with noise scaled by proposal_noise_scale")
    proposal_noise_scale: float = Field(0.3, gt=0)
    icp: IcpConfig = Field(default_factory=IcpConfig)
    gate: GateConfig = Field(default_factory=GateConfig)
    resample: Literal["always", "ess"] = "ess"
    ess_threshold: float = Field(0.5, gt=0, le=1)
    intensity_max: float = Field(40000.0, gt=0, description="top of the intensity bands")
    motion: MotionNoise = Field(default_factory=MotionNoise)
    map: MapConfig = Field(default_factory=lambda: MapConfig(recent_keyframes=8,
                                                             nearby_keyframes=8))
    field: FieldConfig = Field(default_factory=FieldConfig)
    seed: int = 0


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(N,)`` of a systematic resample of normalised ``weights``."""
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.asarray(np.searchsorted(c, (rng.random() + np.arange(n)) / n), dtype=np.intp)


@dataclass
class RbpfSlam:
    """Feed scans with :meth:`process`; read :meth:`trajectory` and :meth:`map_poses`."""

    config: RbpfConfig = field(default_factory=RbpfConfig)
    keyframes: Keyframes = field(init=False)
    fields: FieldCache = field(init=False)
    matched: int = 0
    resamples: int = 0

    def __post_init__(self) -> None:
        cfg = self.config
        self.rng = np.random.default_rng(cfg.seed)
        self.keyframes = Keyframes(cfg.map)
        use_i = cfg.alpha > 0 and cfg.field.intensity_bands > 1
        edges = None
        if use_i:
            edges = np.linspace(0.0, cfg.intensity_max, cfg.field.intensity_bands + 1)
            edges[-1] = np.inf
            edges[0] = -np.inf
        self.fields = FieldCache(self.keyframes, cfg.field, edges)
        p = cfg.particles
        self.x = np.zeros((p, 3))
        self.logw = np.zeros(p)
        self.loglik = np.zeros(p)  # accumulated likelihood, inherited on resampling
        self._kf_pose = np.zeros((16, p, 3))  # per keyframe: (P, 3) poses at insertion
        self._n_kf = 0
        self._lineage = np.zeros((0, p), dtype=np.int32)  # per keyframe: which column
        self._hist_pose: list[np.ndarray] = []  # per matched step: (P, 3) float32
        self._hist_parent: list[np.ndarray] = []  # per matched step: (P,) int32
        self._scan_step: list[int] = []  # per scan: its matched step
        self._scan_delta: list[np.ndarray] = []  # per scan: odometry since that step
        self.times: list[float] = []
        self._anchor_odom: np.ndarray | None = None
        self._last_kf_odom: np.ndarray | None = None

    # -- the four steps of §7.3 ---------------------------------------------------------
    def predict(self, u: np.ndarray, scale: float = 1.0) -> None:
        """Eq. 7."""
        w = self.rng.normal(size=self.x.shape) * (scale * self.config.motion.sigmas(u))
        self.x = compose(self.x, u + w)

    def matched_increment(self, u: np.ndarray, xy: np.ndarray,
                          inten: np.ndarray | None) -> np.ndarray | None:
        """The "gated-icp" proposal: the increment Intensity-ICP finds for the best
        particle against its own map, if eq. 5 accepts it."""
        cfg = self.config
        b = self.best
        poses = self._kf_poses_of(b)
        chosen = self.keyframes.select(self.x[b], poses[:, :2])
        ref_xy, ref_i = self.keyframes.reference(chosen, poses)
        if len(ref_xy) < cfg.icp.min_inliers:
            return None
        predicted = compose(self.x[b], u)
        res = intensity_icp(Reference(ref_xy, ref_i, cfg.icp.alpha), xy, inten, predicted,
                            cfg.icp)
        if not res.usable(len(xy), cfg.icp) or not inside_gate(self.x[b], res.pose, u,
                                                                cfg.gate):
            return None
        return relative(self.x[b], res.pose)

    def likelihood(self, xy: np.ndarray, inten: np.ndarray | None) -> np.ndarray:
        """log p(z | x, m) per particle, eqs. 8-9 (up to a constant)."""
        cfg = self.config
        best = self.best
        chosen = self.keyframes.select(self.x[best], self._kf_poses_of(best)[:, :2])
        res = np.full((len(self.x), len(xy)), np.inf)
        for k in chosen:
            kf_pose = self._kf_pose[k][self._lineage[k]]  # (P, 3): each particle's own
            rel = relative(kf_pose, self.x)  # particle pose in the keyframe frame
            c, s = np.cos(rel[:, 2]), np.sin(rel[:, 2])
            px = c[:, None] * xy[None, :, 0] - s[:, None] * xy[None, :, 1] + rel[:, 0:1]
            py = s[:, None] * xy[None, :, 0] + c[:, None] * xy[None, :, 1] + rel[:, 1:2]
            r = self.fields.get(int(k)).residual(np.stack([px, py], axis=-1), inten, cfg.alpha)
            np.minimum(res, r, out=res)
        d_t = res.mean(axis=1)  # eq. 9
        if cfg.likelihood == "linear":
            return np.asarray(-d_t / (2 * cfg.sigma_z**2))
        return np.asarray(-(d_t**2) / (2 * cfg.sigma_z**2))  # eq. 8

    def resample_if_needed(self) -> np.ndarray | None:
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        ess = 1.0 / float(np.sum(w * w))
        if self.config.resample == "ess" and ess >= self.config.ess_threshold * len(w):
            return None
        idx = systematic_resample(w, self.rng)
        self.x = self.x[idx]
        self.loglik = self.loglik[idx]
        self.logw = np.zeros(len(w))
        if len(self._lineage):
            self._lineage = self._lineage[:, idx]
        self.resamples += 1
        return idx

    def add_keyframe(self, scan_index: int, xy: np.ndarray, inten: np.ndarray | None) -> None:
        self.keyframes.add(scan_index, xy, inten)
        if self._n_kf == len(self._kf_pose):  # grow by doubling: amortised O(1)
            self._kf_pose = np.concatenate([self._kf_pose, np.zeros_like(self._kf_pose)])
        self._kf_pose[self._n_kf] = self.x
        self._n_kf += 1
        row = np.arange(len(self.x), dtype=np.int32)[None, :]
        self._lineage = np.vstack([self._lineage, row])

    # -- driver -------------------------------------------------------------------------
    def process(self, scan: Scan) -> None:
        xy, inten = scan.points()
        self.times.append(scan.t)
        if self._anchor_odom is None:
            self.x[:] = scan.odom
            self._anchor_odom = scan.odom.copy()
            self._last_kf_odom = scan.odom.copy()
            self._store_step(None)
            self._scan_delta.append(np.zeros(3))
            self.add_keyframe(0, xy, inten)
            return
        cfg = self.config
        if not moved(self._anchor_odom, scan.odom, cfg.map.update_linear_m,
                     cfg.map.update_angular_rad) or len(xy) < 8:
            self._scan_step.append(len(self._hist_pose) - 1)
            self._scan_delta.append(relative(self._anchor_odom, scan.odom))
            return
        u = relative(self._anchor_odom, scan.odom)
        um = self.matched_increment(u, xy, inten) if cfg.proposal == "gated-icp" else None
        if um is None:
            self.predict(u)
        else:
            self.predict(um, cfg.proposal_noise_scale)
        pick = np.linspace(0, len(xy) - 1, min(cfg.beams, len(xy))).astype(int)
        ll = self.likelihood(xy[pick], None if inten is None else inten[pick])
        self.logw += ll
        self.loglik += ll
        idx = self.resample_if_needed()
        self.matched += 1
        self._store_step(idx)
        self._scan_delta.append(np.zeros(3))
        self._anchor_odom = scan.odom.copy()
        assert self._last_kf_odom is not None
        if moved(self._last_kf_odom, scan.odom, cfg.map.keyframe_linear_m,
                 cfg.map.keyframe_angular_rad):
            self.add_keyframe(len(self.times) - 1, xy, inten)
            self._last_kf_odom = scan.odom.copy()

    def _store_step(self, idx: np.ndarray | None) -> None:
        p = len(self.x)
        self._hist_pose.append(self.x.astype(np.float32))
        self._hist_parent.append((np.arange(p) if idx is None else idx).astype(np.int32))
        self._scan_step.append(len(self._hist_pose) - 1)

    def _kf_poses_of(self, particle: int) -> np.ndarray:
        """The keyframe poses ``(K, 3)`` of one particle: its map."""
        k = self._n_kf
        return np.asarray(self._kf_pose[np.arange(k), self._lineage[:k, particle]])

    # -- outputs ------------------------------------------------------------------------
    @property
    def best(self) -> int:
        """The particle with the highest accumulated likelihood (§7.4)."""
        return int(np.argmax(self.loglik))

    @property
    def pose(self) -> np.ndarray:
        """Current pose of the best particle, with the odometry since its last update."""
        if not self._scan_delta:
            return np.zeros(3)
        return compose(self.x[self.best], self._scan_delta[-1])

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and poses ``(N, 3)`` of every scan along the best particle's history."""
        steps = len(self._hist_pose)
        path = np.zeros((steps, 3))
        i = self.best
        for s in range(steps - 1, -1, -1):
            path[s] = self._hist_pose[s][i]
            i = int(self._hist_parent[s][i])
        poses = compose(path[np.array(self._scan_step)], np.array(self._scan_delta))
        return np.array(self.times), poses

    def map_poses(self) -> np.ndarray:
        """The best particle's keyframe poses ``(K, 3)``: its map."""
        return self._kf_poses_of(self.best)
