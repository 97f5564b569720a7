"""The viewpoints of verification (Masuzawa & Miura, §5.1, Fig. 7-8; §5.2, Fig. 9(b)).

S_obs (§5.1, Fig. 7): 24 candidates on 3 circles around the object -- r_min (recognisable
from any side), r_max (one face only) and their mean -- 8 directions each, 45 degrees
apart. Viewpoints on occupied or unknown cells, too close to an obstacle, or without a
clear line to the object are removed (:func:`usable_viewpoints`); the outermost usable ones
are the group's entry points (§6.3).

The patterns of eq. 6 (Fig. 8): the surroundings of an object are approximated by one of
five viewpoint patterns (directions free around it) rotated in 45-degree steps, tried
from the most open one (:func:`fitting_pattern`). Fig. 8 is not in the text; the five
patterns are chizu's reading of it: open (8 directions), three-quarter (6), wall (5),
corner (3), front (1).

S_par (§5.2, Fig. 9(b)): the free cells from which every object of a group is
recognisable, where eq. 8's joint observation can be made (:func:`joint_points`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from chizu.numeric.viewpoint.appearance import AppearanceModel
from chizu.numeric.viewpoint.grid import PlanningGrid

if TYPE_CHECKING:
    from chizu.numeric.viewpoint.single import VerificationTable

DIRECTIONS = 8
RINGS = 3
#: Fig. 8 as chizu reads it: the free directions (multiples of 45 degrees) of each pattern,
#: most open first.
PATTERNS: dict[str, tuple[int, ...]] = {
    "open": tuple(range(8)),
    "three_quarter": tuple(range(6)),
    "wall": tuple(range(5)),
    "corner": (0, 1, 2),
    "front": (0,),
}
#: S_par holds at most this many points (evenly thinned)
MAX_PAR_POINTS = 400
#: a line of sight ends this far before the object (its own faces do not block it)
STOP_SHORT_M = 0.35


@dataclass(frozen=True)
class Candidate:
    """A candidate object to verify: id, type, position, its appearance model and the
    current orientation belief (uniform when nothing was observed yet)."""

    id: str
    type: str
    xy: np.ndarray
    model: AppearanceModel
    belief: np.ndarray | None = None

    def prior(self) -> np.ndarray:
        return self.model.uniform_prior() if self.belief is None else self.belief


def viewpoint_circles(obj_xy: np.ndarray, radii: Sequence[float]) -> np.ndarray:
    """The 24 viewpoint candidates (§5.1): index ``ring * 8 + k`` at direction
    ``k * 45 deg`` on ring ``ring`` (0 = r_min, 1 = mid, 2 = r_max)."""
    ang = np.arange(DIRECTIONS) * (2 * np.pi / DIRECTIONS)
    r = np.repeat(np.asarray(radii, dtype=float), DIRECTIONS)
    a = np.tile(ang, len(radii))
    return np.asarray(np.asarray(obj_xy, float) + r[:, None] * np.stack([np.cos(a), np.sin(a)], 1))


def pattern_indices(pattern: str, rotation: int) -> np.ndarray:
    """Viewpoint indices (all three rings) of ``pattern`` rotated by ``rotation * 45 deg``."""
    dirs = (np.array(PATTERNS[pattern]) + rotation) % DIRECTIONS
    return np.asarray((np.arange(RINGS)[:, None] * DIRECTIONS + dirs[None, :]).ravel())


#: every (pattern, rotation) in the order they are tried -- most open first, the open
#: pattern once (it is rotation invariant) -- and which of the 24 viewpoints each needs
_PATTERN_KEYS = [(name, rot) for name in PATTERNS
                 for rot in (range(1) if name == "open" else range(DIRECTIONS))]
_PATTERN_MASKS = np.zeros((len(_PATTERN_KEYS), RINGS * DIRECTIONS), dtype=bool)
for _k, (_name, _rot) in enumerate(_PATTERN_KEYS):
    _PATTERN_MASKS[_k, pattern_indices(_name, _rot)] = True


@dataclass
class ViewpointSet:
    """The viewpoints the planner may use for one candidate."""

    points: np.ndarray          # (V, 2) absolute positions
    recog: NDArray[np.bool_]    # (V, N_theta)
    pattern: str | None         # the Fig. 8 pattern (table mode)
    rotation: int
    entries: np.ndarray         # outermost usable viewpoints: the group's entry points
    usable: np.ndarray          # (U, 2) every usable viewpoint (for executing a plan)
    table: VerificationTable | None = None


def usable_viewpoints(points: np.ndarray, obj_xy: np.ndarray, grid: PlanningGrid | None,
                      clearance_m: float) -> NDArray[np.bool_]:
    """Which of ``points (V, 2)`` the robot may observe ``obj_xy`` from (§5.1): on a known
    free cell at least ``clearance_m`` from every obstacle, with a clear line to the
    object; every one when there is no grid."""
    if grid is None:
        return np.ones(len(points), dtype=bool)
    return np.asarray(grid.free(points, clearance_m) & grid.clear_lines(
        points, np.broadcast_to(obj_xy, points.shape), stop_short_m=STOP_SHORT_M))


def entry_points(points: np.ndarray, usable: NDArray[np.bool_]) -> np.ndarray:
    """The group's entry points (§6.3) among the 24 viewpoints: the usable ones on the
    outer ring (r_max), else every usable one."""
    outer = usable & (np.arange(len(points)) >= (RINGS - 1) * DIRECTIONS)
    return np.asarray(points[outer] if outer.any() else points[usable])


def fitting_pattern(usable: NDArray[np.bool_]) -> tuple[str, int] | None:
    """The first Fig. 8 pattern (most open first) and rotation whose viewpoints are all
    usable, or None."""
    fits = np.nonzero((usable[None, :] | ~_PATTERN_MASKS).all(axis=1))[0]
    return _PATTERN_KEYS[int(fits[0])] if len(fits) else None


def joint_points(cands: Sequence[Candidate], reach: np.ndarray, grid: PlanningGrid | None,
                 clearance_m: float) -> np.ndarray:
    """S_par: free cells from which every candidate of the group has P_recog > 0 (the
    overlap of their observable regions, Fig. 9(b)), at most MAX_PAR_POINTS; ``reach``
    is each candidate's outer verification radius."""
    step = grid.resolution if grid is not None else 0.1
    pts = _overlap_lattice(cands, reach, step)
    # the cheap tests first: free cells, then recognition, then lines of sight
    if grid is not None and len(pts):
        pts = pts[grid.free(pts, clearance_m)]
    for c in cands:
        if len(pts):
            pts = pts[c.model.p_recog(pts, c.xy, c.prior()) > 0]
    if grid is not None:
        for c in cands:
            if len(pts):
                pts = pts[grid.clear_lines(pts, np.broadcast_to(c.xy, pts.shape),
                                           STOP_SHORT_M)]
    if len(pts) > MAX_PAR_POINTS:
        pts = pts[np.linspace(0, len(pts) - 1, MAX_PAR_POINTS).astype(int)]
    return np.asarray(pts)


def _overlap_lattice(cands: Sequence[Candidate], reach: np.ndarray, step: float
                     ) -> np.ndarray:
    """The points of a lattice of spacing ``step`` (from the lower corner of the box
    around every disc) inside every candidate's disc of radius ``reach``; the spacing
    grows by half until at most 4 MAX_PAR_POINTS are left."""
    xy = np.array([c.xy for c in cands])
    r = reach.max()
    lo, hi = xy.min(0) - r, xy.max(0) + r
    # the discs overlap inside the overlap of their boxes: only the lattice points
    # (from lo, as over the whole box) there are tried
    inner_lo = (xy - reach[:, None]).max(0)
    inner_hi = (xy + reach[:, None]).min(0)
    while True:
        first = np.ceil(np.round((inner_lo - lo) / step, 9))
        n = np.floor((np.minimum(hi, inner_hi) - lo) / step - 1e-9) - first + 1
        ax = [lo[d] + step * (first[d] + np.arange(max(int(n[d]), 0)))
              for d in range(2)]
        gx, gy = np.meshgrid(ax[0], ax[1])
        pts = np.stack([gx.ravel(), gy.ravel()], 1)
        ok = np.ones(len(pts), dtype=bool)
        for c, rc in zip(cands, reach, strict=True):
            ok &= np.hypot(*(pts - c.xy).T) <= rc
        pts = pts[ok]
        if len(pts) <= MAX_PAR_POINTS * 4:
            return np.asarray(pts)
        step *= 1.5
