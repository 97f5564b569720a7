"""Relocalisation against the whole old map: a return from a loop so long that the
estimate drifted beyond the loop start's window.

Every ``every`` updates, the keyframes at least ``min_age_s`` old that the best particle
placed within ``radius_m`` of its estimate are ray-cast into one probability grid
(:func:`~chizu.numeric.occupancy.build_probability_grid`), and the scan is matched in it by
branch and bound (Hess et al. 2016, §V, Algorithms 2-3:
:class:`~chizu.numeric.slam.matching.correlative.PrecomputedGrid`) within ``window_m`` /
``angle_rad``. The score is the mean probability of the cells the returns fall in, so
free space the old map saw counts against a pose. A match is taken when it is unique
(no pose ``unique_m`` away scores ``unique_ratio`` of it: a corridor's repeated
doors), the scan matcher refines it against the old keyframes nearest it to a
well-constrained pose, the shift is within the drift the robot can have gathered since
it was last there, the old free space contradicts the current estimate (or the
estimate is where the old map never was, and the agreeing searches span
``unseen_travel_m`` of path), and ``persistence`` consecutive searches agree. Why
each test is there: ``docs/notes/slam-rbpf.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, relative
from chizu.numeric.occupancy import build_probability_grid
from chizu.numeric.slam.matching.correlative import Match, PrecomputedGrid
from chizu.numeric.slam.matching.likelihood_field import Beams, LoopGrid, loop_search
from chizu.numeric.slam.rbpf.config import LoopStartConfig, RelocalisationConfig
from chizu.numeric.slam.rbpf.loop_start import Persistence, free_space_share, world_shift

if TYPE_CHECKING:
    from chizu.numeric.slam.rbpf.filter import RbpfSlam


@dataclass
class Relocalisation:
    """The relocalisation's state: its persistence, the updates since its last search,
    the relocalisations taken (time, shift (m), turn (rad), the grid scores at the
    current estimate and at the match) and those refused by the drift bound (time,
    shift (m), the bound (m))."""

    config: RelocalisationConfig
    loop: LoopStartConfig
    agree: Persistence = field(init=False)
    tick: int = 0
    taken: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    refused: list[tuple[float, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.agree = Persistence(self.config.persistence, self.loop.min_sep_m)

    def search(self, slam: RbpfSlam, u_start: np.ndarray, beams: Beams) -> np.ndarray | None:
        """A relocalising increment for every particle from the best one's pose, or
        None (also between two searches)."""
        self.tick += 1
        if self.tick < self.config.every:
            return None
        self.tick = 0
        x0 = slam.x[slam.best]
        cur = compose(x0, u_start)
        found = self._candidate(slam, cur, beams)
        if found is None:
            self.agree.reset()
            return None
        m, s_cur, old, aged = found
        refined = self._refine(slam, m, beams, aged)
        if refined is None:
            self.agree.reset()
            return None
        alt, ref = refined
        travel = self._evidence(slam, cur, alt, beams, old, ref)
        if travel is None:
            self.agree.reset()
            return None
        if not self.agree.confirm(cur, alt, travel):
            return None
        shift = world_shift(cur, alt)
        self.taken.append((slam.times[-1], float(np.hypot(shift[0], shift[1])),
                           float(shift[2]), s_cur, m.score))
        return np.asarray(relative(x0, alt))

    def _candidate(self, slam: RbpfSlam, cur: np.ndarray, beams: Beams,
                   ) -> tuple[Match, float, np.ndarray, np.ndarray] | None:
        """Branch and bound of the scan in the old map's probability grid around
        ``cur``: the match, the grid's score at ``cur``, the keyframes of the grid and
        the mask of the keyframes old enough -- or None when there is no old map, no
        match, a shift the loop start's window covers, too little gain or a second pose
        as good."""
        cfg = self.config
        kfp = slam._kf_poses_of(slam.best)
        frames = slam.keyframes.frames
        age = slam.times[-1] - np.asarray(slam.times)[[f.scan_index for f in frames]]
        aged = age >= cfg.min_age_s
        near = np.hypot(kfp[:, 0] - cur[0], kfp[:, 1] - cur[1]) <= cfg.radius_m
        old = np.flatnonzero(near & aged)
        if len(old) < self.loop.min_old:
            return None
        old = old[np.unique(np.linspace(0, len(old) - 1,
                                        min(len(old), cfg.max_keyframes)).astype(int))]
        grid, _ = build_probability_grid([frames[int(k)] for k in old], kfp[old],
                                         resolution_m=cfg.resolution_m, margin_m=0.5)
        pre = PrecomputedGrid(grid, depth=6)
        xy = beams.pts
        m = pre.match(xy, cur, cfg.window_m, cfg.angle_rad, cfg.min_score)
        if m is None:
            return None
        shift = world_shift(cur, m.pose)
        if (np.hypot(shift[0], shift[1]) <= self.loop.radius_m
                and abs(shift[2]) <= self.loop.angle_rad):
            return None  # the loop start's window covers it
        s_cur = pre.score(xy, cur)
        if (m.score - s_cur < cfg.min_gain
                or pre.second_score(xy, cur, cfg.window_m, cfg.angle_rad, m, cfg.unique_m,
                                    cfg.unique_ratio) > 0):
            return None
        return m, s_cur, old, aged

    def _refine(self, slam: RbpfSlam, m: Match, beams: Beams, aged: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray] | None:
        """The match refined by the scan matcher against the old keyframes nearest it
        (all those old enough, not only the ones picked for the grid, which are sparser
        far from the estimate): the refined pose and those keyframes, or None when it
        explains fewer than ``min_fraction`` of the beams or is not well constrained."""
        loop = self.loop
        kfp = slam._kf_poses_of(slam.best)
        cand = np.flatnonzero(aged)
        d = np.hypot(kfp[cand, 0] - m.pose[0], kfp[cand, 1] - m.pose[1])
        ref = cand[np.argsort(d)[:max(slam.config.map.nearby_keyframes, loop.min_old)]]
        fp = slam.field_pack(ref, beams.alpha > 0)
        kf_ref = np.ascontiguousarray(kfp[ref][:, None, :])
        step = self.config.resolution_m
        grid = LoopGrid(float(step), float(step), float(loop.angle_step_rad),
                        float(loop.angle_step_rad), float(loop.coarse_cutoff_m ** 2), 1,
                        float(loop.min_sep_m), float(loop.inlier_m ** 2))
        poses, inl, eig = loop_search(m.pose, beams, fp, kf_ref, slam.model, grid)
        r = int(np.argmax(inl))
        if inl[r] < self.config.min_fraction * len(beams.pts) or eig[r] < loop.min_eig:
            return None
        return poses[r], ref

    def _evidence(self, slam: RbpfSlam, cur: np.ndarray, alt: np.ndarray, beams: Beams,
                  old: np.ndarray, ref: np.ndarray) -> float | None:
        """Whether the old map supports moving ``cur`` to ``alt``: within the drift
        bound (``drift_m`` + ``drift_per_m`` per m of odometry path since the robot was
        last at the keyframes ``ref``), and either the old free space contradicts
        ``cur`` or ``cur`` lies where the old map never was. Returns the path the
        agreeing searches must span (0 when contradicted), or None."""
        cfg = self.config
        frames = slam.keyframes.frames
        last_seen = max(frames[int(k)].scan_index for k in ref)
        since = slam._odom_path[-1] - slam._odom_path[last_seen]
        shift = world_shift(cur, alt)
        dist = float(np.hypot(shift[0], shift[1]))
        bound = cfg.drift_m + cfg.drift_per_m * since
        if dist > bound:
            self.refused.append((slam.times[-1], dist, bound))
            return None
        kfp = slam._kf_poses_of(slam.best)
        (free_cur, free), (seen_cur, _) = free_space_share(
            [frames[int(k)] for k in old], kfp[old], np.stack([cur, alt]), beams.pts,
            self.loop.free_cell_m, self.loop.free_margin_m)
        contradicted = free_cur - free >= self.loop.min_free_drop
        unseen = (cfg.max_seen is not None and seen_cur <= cfg.max_seen
                  and free < self.loop.min_free_drop)
        if not (contradicted or unseen):
            return None
        return 0.0 if contradicted else cfg.unseen_travel_m
