"""The paper's filter (Hara et al. §7, eqs. 6-9): a particle set whose step is
predict → weigh → maybe resample → update the maps.

Eq. 6 factors the posterior into the trajectory (particles) and the map given the
trajectory (one map per particle). Per matched scan (§7.3):

1. prediction, eq. 7: ``x_t = x_{t-1} (+) (u_t + w)``, w ~ N(0, Σ_w) with Σ_w growing
   with the odometry increment u_t (:meth:`RbpfSlam.predict`);
2. likelihood, eqs. 8-9: ``d_t`` = mean over the scan's beams of the capped augmented
   squared residual ``||s_m - T s_z||^2 + alpha (l_m - l_z)^2`` to the particle's own
   map, and ``p(z|x, m) ∝ exp(-d_t^2 / (2 sigma_z^2))`` exactly as eq. 8 writes it
   (:meth:`RbpfSlam.likelihood`);
3. resampling with a constant particle count (systematic), every step as in the paper
   or only when the effective sample size drops below ``ess_threshold`` x N
   (:meth:`RbpfSlam.maybe_resample`);
4. map update: a keyframe is added when the robot has moved far enough; every particle
   stores its own pose for it (:meth:`RbpfSlam.update_maps`).

``proposal="improved"`` (the default) replaces steps 1-2 by Grisetti et al.'s improved
proposal (:mod:`chizu.numeric.slam.rbpf.improved`).

Maps are never copied: the keyframe scans are shared and each particle's map is its
keyframe poses, kept as one pose array per keyframe plus a lineage matrix of indices
that resampling permutes. The trajectory is a tree of (pose, parent) arrays, walked back
from the particle with the highest accumulated likelihood (§7.4) at the end.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from chizu.numeric.geometry import compose, relative
from chizu.numeric.scan import Scan
from chizu.numeric.slam.alignment import (
    AlignedOutputs,
    AlignmentConfig,
    ScanStore,
    estimate_closures,
)
from chizu.numeric.slam.gated import inside_gate
from chizu.numeric.slam.keyframes import FieldCache, Keyframes, moved, voxel_downsample
from chizu.numeric.slam.matching.intensity_icp import Reference, intensity_icp
from chizu.numeric.slam.matching.likelihood_field import Beams, FieldArena, FieldPack
from chizu.numeric.slam.pose_graph import GraphConfig
from chizu.numeric.slam.rbpf.config import RbpfConfig
from chizu.numeric.slam.rbpf.improved import improved_update, robust_start
from chizu.numeric.slam.rbpf.loop_start import LoopStart
from chizu.numeric.slam.rbpf.odometry import HeadingCalibration
from chizu.numeric.slam.rbpf.relocalisation import Relocalisation


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(N,)`` of a systematic resample of normalised ``weights``."""
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.asarray(np.searchsorted(c, (rng.random() + np.arange(n)) / n), dtype=np.intp)


@dataclass(frozen=True)
class RbpfStep:
    """What one scan did to the filter (:meth:`RbpfSlam.step`): ``kind`` "first" (the
    map's first keyframe), "between" (no filter update yet: the scan's pose follows
    the odometry, or the best particle's map when ``track_scans``) or "update" (§7.3's
    four steps); for an update, the effective sample size after weighing, whether the
    particles were resampled and whether a keyframe joined the maps."""

    t: float
    kind: Literal["first", "between", "update"]
    ess: float | None = None
    resampled: bool = False
    keyframe: bool = False


@dataclass
class RbpfSlam(AlignedOutputs):
    """Feed scans with :meth:`process`; read :meth:`trajectory` and :meth:`map_poses`."""

    config: RbpfConfig = field(default_factory=RbpfConfig)
    keyframes: Keyframes = field(init=False)
    fields: FieldCache = field(init=False)
    matched: int = 0
    resamples: int = 0
    improved_failures: int = 0  # particle updates that fell back to the motion model

    def __post_init__(self) -> None:
        cfg = self.config
        self.rng = np.random.default_rng(cfg.seed)
        self.keyframes = Keyframes(cfg.map)
        edges = None
        if cfg.alpha > 0 and cfg.field.intensity_bands > 1:
            edges = np.linspace(0.0, cfg.intensity_max, cfg.field.intensity_bands + 1)
            edges[-1] = np.inf
            edges[0] = -np.inf
        self.fields = FieldCache(self.keyframes, cfg.field, edges)
        #: the scan matcher's constants, derived once
        self.model = cfg.improved.model(cfg.field.cutoff_m)
        self._kept_pack: tuple[tuple[tuple[int, ...], bool], FieldPack] | None = None
        self._arenas = {w: FieldArena(w) for w in (False, True)}  # for the kept packs
        p = cfg.particles
        self.x = np.zeros((p, 3))
        self.logw = np.zeros(p)
        self.loglik = np.zeros(p)  # accumulated likelihood, inherited on resampling
        self._kf_pose = np.zeros((16, p, 3))  # per keyframe: (P, 3) poses at insertion
        self._n_kf = 0
        self._lineage_buf = np.zeros((16, p), dtype=np.int32)  # per keyframe: which column
        self._hist_pose: list[np.ndarray] = []  # per matched step: (P, 3) float32
        self._hist_parent: list[np.ndarray] = []  # per matched step: (P,) int32
        self._scan_step: list[int] = []  # per scan: its matched step
        self._scan_delta: list[np.ndarray] = []  # per scan: odometry since that step
        self.times: list[float] = []
        self._odom_path: list[float] = []  # per scan: the odometry's path length so far
        self._last_odom: np.ndarray | None = None
        self._anchor_odom: np.ndarray | None = None
        self._last_kf_odom: np.ndarray | None = None
        imp = cfg.improved
        self.loop = LoopStart(imp.loop)
        self.reloc = None if imp.reloc is None else Relocalisation(imp.reloc, imp.loop)
        self.calibration = HeadingCalibration(imp.odometry)
        self.scans = ScanStore()

    @property
    def odometry(self):  # type: ignore[no-untyped-def]
        """The learned heading sigma
        (:class:`~chizu.numeric.slam.pose_graph.OdometryCalibration`)."""
        return self.calibration.learned

    def sigmas(self, u: np.ndarray) -> np.ndarray:
        """Σ_w of eq. 7 for the increment ``u``, its heading sigma scaled by what the
        odometry calibration has learned (1 while it has not)."""
        sig = self.config.motion.sigmas(u)
        sig[2] *= self.odometry.scale
        return sig

    # -- the four steps of §7.3 (driven by step) -------------------------------------------
    def predict(self, u: np.ndarray, scale: float = 1.0) -> None:
        """Eq. 7."""
        w = self.rng.normal(size=self.x.shape) * (scale * self.sigmas(u))
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
        return np.asarray(-(d_t**2) / (2 * cfg.sigma_z**2))  # eq. 8

    def predict_and_weigh(self, u: np.ndarray, xy: np.ndarray,
                          inten: np.ndarray | None) -> np.ndarray:
        """Steps 1-2: move the particles by the proposal and return their log weight
        increments -- the improved proposal's η (:func:`improved_update`), or eq. 7's
        prediction (on the odometry, or on the gated Intensity-ICP increment) weighed by
        eqs. 8-9 (:meth:`likelihood`)."""
        cfg = self.config
        improved = cfg.proposal == "improved"
        pick = self._beams(xy, improved)
        xs, its = xy[pick], None if inten is None else inten[pick]
        if improved:
            return improved_update(self, u, xs, its)
        um = self.matched_increment(u, xy, inten) if cfg.proposal == "gated-icp" else None
        if um is None:
            self.predict(u)
        else:
            self.predict(um, cfg.proposal_noise_scale)
        return self.likelihood(xs, its)

    def effective_sample_size(self) -> float:
        """N_eff = 1 / Σ w² of the normalised weights."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        return 1.0 / float(np.sum(w * w))

    def maybe_resample(self, ess: float) -> np.ndarray | None:
        """Step 3: systematic resampling, every update (the paper) or only when
        ``ess`` < ``ess_threshold`` x N (Grisetti et al.'s selective resampling);
        returns the drawn indices, or None. Maps follow their particles through the
        lineage matrix: nothing is copied."""
        if self.config.resample == "ess" and ess >= self.config.ess_threshold * len(self.x):
            return None
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        idx = systematic_resample(w, self.rng)
        self.x = self.x[idx]
        self.loglik = self.loglik[idx]
        self.logw = np.zeros(len(w))
        if self._n_kf:
            self._lineage_buf[:self._n_kf] = self._lineage[:, idx]
        self.resamples += 1
        return idx

    def update_maps(self, scan: Scan, xy: np.ndarray, inten: np.ndarray | None,
                    idx: np.ndarray | None) -> bool:
        """Step 4: record the update in the trajectory tree and, once the robot has moved
        ``keyframe_linear_m`` / ``keyframe_angular_rad`` since the last keyframe, add
        the scan as a keyframe every particle places at its own pose. Returns whether
        one was added."""
        cfg = self.config
        self.matched += 1
        self._store_step(idx)
        self._scan_delta.append(np.zeros(3))
        self._anchor_odom = scan.odom.copy()
        assert self._last_kf_odom is not None
        if not moved(self._last_kf_odom, scan.odom, cfg.map.keyframe_linear_m,
                     cfg.map.keyframe_angular_rad):
            return False
        self.add_keyframe(len(self.times) - 1, xy, inten)
        self._last_kf_odom = scan.odom.copy()
        return True

    def add_keyframe(self, scan_index: int, xy: np.ndarray, inten: np.ndarray | None) -> None:
        self.keyframes.add(scan_index, xy, inten)
        if self._n_kf == len(self._kf_pose):  # grow by doubling: amortised O(1)
            self._kf_pose = np.concatenate([self._kf_pose, np.zeros_like(self._kf_pose)])
        if self._n_kf == len(self._lineage_buf):
            self._lineage_buf = np.concatenate([self._lineage_buf,
                                                np.zeros_like(self._lineage_buf)])
        self._kf_pose[self._n_kf] = self.x
        self.calibration.keyframe_added(self._last_odom,
                                        self._odom_path[-1] if self._odom_path else 0.0)
        self._lineage_buf[self._n_kf] = np.arange(len(self.x), dtype=np.int32)
        self._n_kf += 1

    # -- driver -------------------------------------------------------------------------
    def process(self, scan: Scan) -> RbpfStep:
        """:meth:`step` (the name every estimator shares)."""
        return self.step(scan)

    def step(self, scan: Scan) -> RbpfStep:
        """One scan through §7.3: the first starts the map; between two updates (less
        than the update distance or turn of odometry) the scan's pose is refined but
        the particles stay; else predict and weigh (eqs. 7-9, or the improved
        proposal), maybe resample, update the maps."""
        xy, inten = scan.points()
        self.times.append(scan.t)
        self._odom_path.append(0.0 if self._last_odom is None else self._odom_path[-1] + float(
            np.hypot(*(scan.odom[:2] - self._last_odom[:2]))))
        self._last_odom = scan.odom.copy()
        self.scans.aligned = None  # a new scan: the filter's estimate is current again
        if self.config.alignment is not None:
            pts, pin = voxel_downsample(xy, inten, self.config.map.voxel_m)
            self.scans.add(pts, pin)
        if self._anchor_odom is None:
            self._first(scan, xy, inten)
            return RbpfStep(scan.t, "first", keyframe=True)
        u = relative(self._anchor_odom, scan.odom)
        lin, ang = self.config.update_distances()
        if not moved(self._anchor_odom, scan.odom, lin, ang) or len(xy) < 8:
            self._between(u, xy, inten)
            return RbpfStep(scan.t, "between")
        ll = self.predict_and_weigh(u, xy, inten)
        self.logw += ll
        self.loglik += ll
        ess = self.effective_sample_size()
        idx = self.maybe_resample(ess)
        keyframe = self.update_maps(scan, xy, inten, idx)
        return RbpfStep(scan.t, "update", ess, idx is not None, keyframe)

    def _first(self, scan: Scan, xy: np.ndarray, inten: np.ndarray | None) -> None:
        self.x[:] = scan.odom
        self._anchor_odom = scan.odom.copy()
        self._last_kf_odom = scan.odom.copy()
        self._store_step(None)
        self._scan_delta.append(np.zeros(3))
        self.add_keyframe(0, xy, inten)

    def _between(self, u: np.ndarray, xy: np.ndarray, inten: np.ndarray | None) -> None:
        """A scan between two updates: its pose is the last update's best particle (+)
        ``u`` (the odometry since), or (+) the increment :meth:`track` matches."""
        cfg = self.config
        self._scan_step.append(len(self._hist_pose) - 1)
        if cfg.proposal == "improved" and cfg.track_scans and len(xy) >= 8:
            pick = self._beams(xy, True)
            u = self.track(u, xy[pick], None if inten is None else inten[pick])
        self._scan_delta.append(u)

    def track(self, u: np.ndarray, xy: np.ndarray, inten: np.ndarray | None) -> np.ndarray:
        """A scan between two updates: its increment from the last update, found as each
        update finds its start (:func:`~chizu.numeric.slam.rbpf.improved.robust_start`: the
        best particle's map, the odometry prediction turned and shifted). Only the
        scan's own pose uses it -- the filter's updates stay every ``update_linear_m``,
        and the particles are not touched."""
        best = self.best
        chosen, fp, alpha = self.best_map(u, inten)
        kf_pose = self._kf_pose[chosen, self._lineage[chosen, best]][:, None, :]
        return robust_start(self, u, Beams.of(xy, inten, alpha), fp, kf_pose)[0]

    def _beams(self, xy: np.ndarray, improved: bool) -> np.ndarray:
        """The ``beams`` a match uses, evenly picked; with the improved proposal among
        the returns within the keyframes' reach only (:meth:`Keyframes.reach`:
        ``max_points_m``, or ``open_points_m`` for an open scan; beyond it they never
        find a map point)."""
        cfg = self.config
        cand = np.arange(len(xy))
        if improved:
            near = np.flatnonzero(self.keyframes.in_reach(xy))
            if len(near) >= 8:
                cand = near
        return cand[np.linspace(0, len(cand) - 1, min(cfg.beams, len(cand))).astype(int)]

    # -- the maps ---------------------------------------------------------------------------
    def field_pack(self, ids: Iterable[int], with_intensity: bool,
                   keep: bool = False) -> FieldPack:
        """:meth:`FieldPack.of` the keyframes ``ids``; with ``keep`` the pack is kept for
        the next call with ``keep`` (one pack: the best particle's reference, asked for
        on every scan and mostly the same keyframes from one scan to the next) and made
        by a :class:`FieldArena`, which copies only the fields the last packs lacked. A
        keyframe's field never changes, so a kept pack reads what :meth:`FieldPack.of`
        would build; its fields are still asked of the field cache, which keeps them as
        recently used as before."""
        key = (tuple(int(k) for k in ids), with_intensity)
        fields = [self.fields.get(k) for k in key[0]]
        if not keep:
            return FieldPack.of(fields, with_intensity)
        if self._kept_pack is None or self._kept_pack[0] != key:
            self._kept_pack = (key, self._arenas[with_intensity].pack(fields))
        return self._kept_pack[1]

    def finish(self) -> int:
        """:meth:`AlignedOutputs.finish`, the kept reference's buffers let go first: the
        end-of-run alignment and the map built after it need the memory, and a scan
        that comes later packs its reference anew (the same values)."""
        self._kept_pack = None
        self._arenas = {w: FieldArena(w) for w in (False, True)}
        return super().finish()

    def best_map(self, u: np.ndarray, inten: np.ndarray | None,
                 ) -> tuple[np.ndarray, FieldPack, float]:
        """The keyframes the best particle's reference is made of at ``x_best (+) u``
        (:meth:`Keyframes.select`), their likelihood fields, and the intensity weight."""
        cfg = self.config
        best = self.best
        chosen = self.keyframes.select(compose(self.x[best], u), self._kf_poses_of(best)[:, :2])
        alpha = cfg.alpha if inten is not None else 0.0
        return chosen, self.field_pack(chosen, alpha > 0, keep=True), alpha

    def _store_step(self, idx: np.ndarray | None) -> None:
        p = len(self.x)
        self._hist_pose.append(self.x.astype(np.float32))
        self._hist_parent.append((np.arange(p) if idx is None else idx).astype(np.int32))
        self._scan_step.append(len(self._hist_pose) - 1)

    @property
    def _lineage(self) -> np.ndarray:
        """``(K, P)``: for each keyframe, which of its stored poses each particle owns."""
        return self._lineage_buf[:self._n_kf]

    def _kf_poses_of(self, particle: int) -> np.ndarray:
        """The keyframe poses ``(K, 3)`` of one particle: its map."""
        k = self._n_kf
        return np.asarray(self._kf_pose[np.arange(k), self._lineage[:k, particle]])

    # -- outputs ------------------------------------------------------------------------
    @property
    def updates(self) -> int:
        """Filter updates so far (the first scan counts as one)."""
        return len(self._hist_pose)

    @property
    def best(self) -> int:
        """The particle with the highest accumulated likelihood (§7.4)."""
        return int(np.argmax(self.loglik))

    @property
    def loop_starts(self) -> list[tuple[float, float, int, int, float, float]]:
        return self.loop.taken

    @property
    def relocalisations(self) -> list[tuple[float, float, float, float, float]]:
        return [] if self.reloc is None else self.reloc.taken

    @property
    def reloc_refused(self) -> list[tuple[float, float, float]]:
        return [] if self.reloc is None else self.reloc.refused

    def _online_pose(self) -> np.ndarray:
        """The best particle's pose, with the odometry since its last update."""
        if not self._scan_delta:
            return np.zeros(3)
        return compose(self.x[self.best], self._scan_delta[-1])

    def _online_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Every scan along the best particle's history."""
        steps = len(self._hist_pose)
        path = np.zeros((steps, 3))
        i = self.best
        for s in range(steps - 1, -1, -1):
            path[s] = self._hist_pose[s][i]
            i = int(self._hist_parent[s][i])
        poses = compose(path[np.array(self._scan_step)], np.array(self._scan_delta))
        return np.array(self.times), poses

    def _online_map_poses(self) -> np.ndarray:
        """The best particle's keyframe poses: its map."""
        return self._kf_poses_of(self.best)

    def _map_scans(self) -> np.ndarray:
        return np.array([kf.scan_index for kf in self.keyframes.frames])

    def _alignment(self) -> tuple[AlignmentConfig | None, float]:
        return self.config.alignment, self.config.alpha

    def _alignment_inputs(self, poses: np.ndarray,
                          ) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray]],
                                     GraphConfig]:
        """The filter's own increments are the chain between consecutive scans, and the
        pairs of scans it placed close together facing away from each other keep their
        relative pose as closures (:func:`estimate_closures`)."""
        assert self.config.alignment is not None
        return poses, estimate_closures(poses, self.config.alignment), GraphConfig()
