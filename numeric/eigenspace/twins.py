"""Look-alike places that the learning set must keep in pairs (Maeda & Shirai §3.3-§4.2).

§3.3 finds candidate-multiple sets among the learned triplets: places whose images
cannot be told apart, so that a session hitting only one set stays in state Y. That
works only when both look-alike places were learned. On the 2 m grid of a room that is
symmetric (a half turn maps walls and photographs onto themselves) every grid point has
a twin on the grid, and §3.3 groups their triplets. The learning strategy (§4.2) then
adds single points, whose twins are not learned: their triplets form no set, and a
robot at the twin place gets a confident answer on the wrong side (chizu's twin
hexagon: the only wrong answers left were of such triplets).

:func:`twin_transform` reads the room's symmetry off the learned turns: a grid point
whose whole turn is matched by a far learning point's turn (at some cyclic shift) much
better than by any near one has a twin there, and when many such pairs agree on one
rigid motion, that motion is the symmetry. The learning strategy then learns each added
point's image under it as well (:func:`chizu.numeric.eigenspace.learning_strategy.
learning_strategy`), so §3.3 sees both places and decides from the images whether they
can be told apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chizu.numeric.eigenspace.learning import EigenspaceModel
from chizu.numeric.eigenspace.localization import turn_appearance
from chizu.numeric.geometry import wrap_angle

#: a learning point farther than this is "far" (beyond a grid neighbour's reach)
FAR_M = 3.0
#: a far turn this much closer than the nearest near one (as a share) is a twin; in
#: chizu's rooms twins come at 0-0.16 (the half-turn-symmetric hexagon and hall), the
#: closest far look-alike of other grid points at 0.76 or more
TWIN_RATIO = 0.3
#: pairs agreeing on the motion within this (m, the grid makes twins approximate)
AGREE_M = 0.75


@dataclass(frozen=True)
class TwinTransform:
    """A rigid motion ``x -> R(phi) x + t`` that maps the room onto itself, read off
    ``pairs`` twin learning points."""

    phi: float
    t: np.ndarray
    pairs: int

    def apply(self, xy: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.phi), np.sin(self.phi)
        xy = np.asarray(xy, dtype=float)
        return np.stack([c * xy[..., 0] - s * xy[..., 1] + self.t[0],
                         s * xy[..., 0] + c * xy[..., 1] + self.t[1]], axis=-1)


def twin_pairs(model: EigenspaceModel, points: int | None = None
               ) -> list[tuple[int, int, float]]:
    """``(q, i, phi)`` for each of the first ``points`` learning points ``q`` whose
    whole turn differs from the far point ``i``'s turn, turned by ``phi``, by at most
    :data:`TWIN_RATIO` times its difference from the nearest-looking near point's
    (:func:`turn_appearance`: what ``q`` sees in direction a, ``i`` sees in direction
    a + phi)."""
    n_pts = len(model.points) if points is None else points
    n_dir = model.projections.shape[1]
    out = []
    for q in range(n_pts):
        a = turn_appearance(model, model.projections[q])
        if a is None:
            return []
        d = np.linalg.norm(model.points - model.points[q], axis=1)
        best = a.min(axis=1)
        near = (d > 0) & (d <= FAR_M)
        far = d > FAR_M
        if not near.any() or not far.any():
            continue
        i = int(np.flatnonzero(far)[np.argmin(best[far])])
        if best[i] <= TWIN_RATIO * best[near].min():
            out.append((q, i, float(2 * np.pi * int(np.argmin(a[i])) / n_dir)))
    return out


def twin_transform(model: EigenspaceModel, points: int | None = None,
                   min_pairs: int = 4) -> TwinTransform | None:
    """The room's symmetry as the learned turns show it, or None: the largest group of
    :func:`twin_pairs` that agree on one rotation (within one learned direction) and
    translation (within :data:`AGREE_M`), when it holds at least ``min_pairs`` pairs
    and half of all twin pairs."""
    pairs = twin_pairs(model, points)
    if len(pairs) < min_pairs:
        return None
    step = 2 * np.pi / model.projections.shape[1]
    p = model.points
    best: TwinTransform | None = None
    best_n = 0
    for _, _, phi in pairs:
        same = [(q, i) for q, i, f in pairs if abs(wrap_angle(f - phi)) <= step + 1e-9]
        c, s = np.cos(phi), np.sin(phi)
        rot = np.array([[c, -s], [s, c]])
        ts = np.array([p[i] - rot @ p[q] for q, i in same])
        t = np.median(ts, axis=0)
        ok = np.linalg.norm(ts - t, axis=1) <= AGREE_M
        if ok.sum() > best_n:
            best_n = int(ok.sum())
            best = TwinTransform(phi, np.mean(ts[ok], axis=0), best_n)
    if best is None or best_n < min_pairs or 2 * best_n < len(pairs):
        return None
    return best
