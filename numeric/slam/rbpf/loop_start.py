"""The loop-aware start of the improved proposal: a loop closed by moving every
particle's start, when the place seen before is farther off than the matcher's basin.

Grisetti et al.'s proposal (§IV) only refines a pose inside the matcher's basin: after
a long loop the place seen before can be farther off than the likelihood field's
cutoff, and then no particle is pulled back (the paper relies on enough particles
having drifted the right way). When the best particle's reference holds old keyframes
(not among the recent ones), the scan is searched for against them alone
(:func:`~chizu.numeric.slam.matching.likelihood_field.loop_search`) and a clearly better,
well-constrained, persistent alignment becomes every particle's start and motion prior.
Why each test is there: ``docs/notes/slam-rbpf.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from chizu.numeric.geometry import compose, invert, place, relative, wrap_angle
from chizu.numeric.occupancy import FREE, UNKNOWN, build_occupancy
from chizu.numeric.slam.keyframes import Keyframe
from chizu.numeric.slam.matching.likelihood_field import Beams, count_inliers, loop_search
from chizu.numeric.slam.rbpf.config import LoopStartConfig

if TYPE_CHECKING:
    from chizu.numeric.slam.rbpf.filter import RbpfSlam


def world_shift(frm: np.ndarray, to: np.ndarray) -> np.ndarray:
    """``to`` minus ``frm`` in the world frame, the heading wrapped: the correction a
    loop start or relocalisation makes (what the size limits of both are set in)."""
    return np.array([to[0] - frm[0], to[1] - frm[1], wrap_angle(to[2] - frm[2])])


@dataclass
class Persistence:
    """How many consecutive searches agreed on a correction: a loop start or
    relocalisation is taken only after ``need`` in a row, each of whose alternatives
    lies within ``sep_m`` of where the previous correction puts the current estimate,
    and, when asked, over at least ``travel_m`` of the estimate's path.

    A correction is the rigid transform ``H = alt (+) cur^-1`` that moves the estimate
    onto the alternative, not the difference of the two: with a heading error the
    difference changes as the robot drives on (by 2 sin(dθ/2) per metre), while the
    transform stays the same."""

    need: int
    sep_m: float
    streak: int = 0
    travel: float = 0.0
    correction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    last: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def reset(self) -> None:
        self.streak = 0

    def confirm(self, cur: np.ndarray, alt: np.ndarray, travel_m: float = 0.0) -> bool:
        """Count the correction from ``cur`` to ``alt``; True (and start over) once
        ``need`` in a row agree over at least ``travel_m`` of path."""
        moved = compose(self.correction, cur)
        agree = self.streak > 0 and np.hypot(moved[0] - alt[0], moved[1] - alt[1]) < self.sep_m
        if agree:
            self.streak += 1
            self.travel += float(np.hypot(cur[0] - self.last[0], cur[1] - self.last[1]))
        else:
            self.streak, self.travel = 1, 0.0
        self.correction = compose(alt, invert(cur))
        self.last = np.asarray(cur, dtype=float).copy()
        if self.streak < self.need or self.travel < travel_m:
            return False
        self.streak = 0
        return True


def free_space_share(frames: list[Keyframe], kf_poses: np.ndarray, poses: np.ndarray,
                     xy: np.ndarray, cell_m: float, margin_m: float) -> np.ndarray:
    """For each of ``poses`` (M, 3): row 0, the share of the scan's returns ``xy`` that
    land where the keyframes ``frames`` (at ``kf_poses`` (K, 3)) saw free space -- row
    1, the share that land in cells they saw at all (free or hit). Free: cells their
    beams passed through, at least ``margin_m`` from any cell they did not see as free
    (on a grid of ``cell_m``) -- the negative evidence of an occupancy map, which inlier
    counts lack (Hess et al. 2016 score closures on a probability grid, free cells
    included). A robot in the room next to one it mapped explains the mapped room's
    walls well metres off; there the current estimate puts no return in the old free
    space and the false alternative does."""
    occ = build_occupancy(frames, kf_poses, resolution_m=cell_m, margin_m=0.0)
    steps = int(round(margin_m / cell_m))
    free = occ.state == FREE
    if steps > 0:  # (iterations=0 would erode until nothing changes)
        free = ndimage.binary_erosion(free, structure=np.ones((3, 3)), iterations=steps)
    out = np.zeros((2, len(poses)))
    for m, pose in enumerate(poses):
        i, j, on = occ.cells(place(xy, pose))
        out[0, m] = float((free[i, j] & on).sum()) / max(len(xy), 1)
        out[1, m] = float((on & (occ.state[i, j] != UNKNOWN)).sum()) / max(len(xy), 1)
    return out


@dataclass
class LoopStart:
    """The loop start's state: its persistence, the starts taken (time, shift (m), beams
    explained by the old keyframes at the current estimate and at the alternative, and
    the share of the beams each puts in the old keyframes' free space) and the
    candidates refused for the free space alone (time, shift, the two shares)."""

    config: LoopStartConfig
    agree: Persistence = field(init=False)
    taken: list[tuple[float, float, int, int, float, float]] = field(default_factory=list)
    refused: list[tuple[float, float, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.agree = Persistence(self.config.persistence, self.config.min_sep_m)

    def search(self, slam: RbpfSlam, u_start: np.ndarray, chosen: np.ndarray, beams: Beams,
               kf_best: np.ndarray) -> np.ndarray | None:
        """A loop-closing increment for every particle from the best one's pose, or
        None. The best alternative of the search is taken only on strong evidence: it
        explains at least ``min_fraction`` of the beams within ``inlier_m`` of the old
        map, ``min_gain`` more than the current estimate (the better of it as it is and
        refined against the old map) and ``ambiguity`` more than any other mode, its
        position is well constrained (``min_eig``), it lowers the share of beams in the
        old map's free space by ``min_free_drop`` (:func:`free_space_share`) and
        ``persistence`` consecutive updates agree. Every particle then starts at, and
        is drawn around, its pose (+) the increment: the shift is common, so the relative
        weights hold."""
        cfg = self.config
        old = np.flatnonzero(chosen < slam._n_kf - slam.config.map.recent_keyframes)
        if len(old) < cfg.min_old:
            self.agree.reset()
            return None
        fp = slam.field_pack(chosen[old], beams.alpha > 0)
        kf_old = np.ascontiguousarray(kf_best[old])
        x0 = slam.x[slam.best]
        cur = compose(x0, u_start)
        n_b = len(beams.pts)
        n_cur = int(count_inliers(cur, beams, fp, kf_old, cfg.inlier_m ** 2))
        if n_cur + cfg.min_gain * n_b > n_b:  # cannot gain enough
            self.agree.reset()
            return None
        poses, inl, eig = loop_search(cur, beams, fp, kf_old, slam.model, cfg.grid,
                                      slam.config.threads)
        # the current estimate refined against the old map is the first rival: the
        # alternatives are refined, and the unrefined estimate's count would understate it
        n_cur = max(n_cur, int(inl[0]))
        r = int(np.argmax(inl))
        alt = poses[r]
        if not self._good(cur, alt, poses, inl, eig, r, n_cur, n_b):
            self.agree.reset()
            return None
        shift = float(np.hypot(*world_shift(cur, alt)[:2]))
        free_cur, free = free_space_share([slam.keyframes.frames[int(k)] for k in chosen[old]],
                                          kf_old[:, 0], np.stack([cur, alt]), beams.pts,
                                          cfg.free_cell_m, cfg.free_margin_m)[0]
        if free_cur - free < cfg.min_free_drop:
            self.refused.append((slam.times[-1], shift, free_cur, free))
            self.agree.reset()
            return None
        if not self.agree.confirm(cur, alt):
            return None
        self.taken.append((slam.times[-1], shift, n_cur, int(inl[r]), float(free_cur),
                           float(free)))
        return np.asarray(relative(x0, alt))

    def _good(self, cur: np.ndarray, alt: np.ndarray, poses: np.ndarray, inl: np.ndarray,
              eig: np.ndarray, r: int, n_cur: int, n_b: int) -> bool:
        """The single-search tests of :meth:`search`: enough beams explained, enough
        more than the current estimate and than any other mode, well constrained, and a
        shift the scan matcher could not make itself."""
        cfg = self.config
        apart = np.hypot(poses[:, 0] - alt[0], poses[:, 1] - alt[1]) >= cfg.min_sep_m
        second = int(inl[apart].max()) if np.any(apart) else 0
        shift = world_shift(cur, alt)
        return bool(inl[r] >= cfg.min_fraction * n_b
                    and inl[r] - n_cur >= cfg.min_gain * n_b
                    and inl[r] - second >= cfg.ambiguity * n_b
                    and eig[r] >= cfg.min_eig
                    and np.hypot(shift[0], shift[1]) >= cfg.min_shift_m)
