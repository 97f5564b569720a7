"""Localizable triplets (paper §2.3).

Only triples of nearby learning points are searched (condition C: all mutual
distances <= ``neighbour_max_m``).  For each direction theta_1 at w_1, the direction
theta_2 at w_2 is the one that minimises ||x'_1 - x'_2|| subject to
``k_alpha < l1/l2 < 1/k_alpha`` and ``|theta_1 - theta_2| < theta_alpha``, where the
rays w_1 + t theta_1 and w_2 + t theta_2 meet at w_12 (l_i = |w_i - w_12|); the same
for w_3 gives w_13; the triplet is accepted when ``|w_12 - w_13| <= D_alpha``.
Every point of a triple takes the role of w_1 in turn; duplicates are merged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import permutations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from chizu.numeric.eigenspace.learning import EigenspaceModel
from chizu.numeric.geometry import wrap_angle


class TripletConfig(BaseModel):
    """Thresholds of §2.3 in SI units (paper: k_alpha 0.8, theta_alpha 30 deg, D_alpha 50 mm)."""

    model_config = ConfigDict(extra="forbid")
    k_alpha: float = Field(0.8, gt=0.0, lt=1.0)
    theta_alpha_rad: float = Field(float(np.deg2rad(30.0)), gt=0.0, le=np.pi)
    d_alpha_m: float = Field(0.05, gt=0.0, le=10.0)
    neighbour_max_m: float = Field(2.9, gt=0.0, le=100.0,
                                   description="condition C: max mutual distance in a triple")
    min_area_m2: float = Field(0.05, ge=0.0, description="skip (near) collinear triples")


@dataclass
class Triplets:
    """T localizable triplets: learning-point indices ``point_idx (T, 3)``, direction
    indices ``dir_idx (T, 3)``, the common target ``target (T, 2)`` [m] (midpoint of
    w_12 and w_13) and the triangle area ``area (T,)`` [m^2]."""

    point_idx: np.ndarray
    dir_idx: np.ndarray
    target: np.ndarray
    area: np.ndarray

    def __len__(self) -> int:
        return len(self.point_idx)

    @staticmethod
    def empty() -> Triplets:
        return Triplets(np.zeros((0, 3), int), np.zeros((0, 3), int), np.zeros((0, 2)),
                        np.zeros(0))

    def poses(self, model: EigenspaceModel) -> np.ndarray:
        """s_ti as ``(T, 3, 3)``."""
        s = np.empty((len(self), 3, 3))
        s[..., :2] = model.points[self.point_idx]
        s[..., 2] = model.directions[self.dir_idx]
        return s

    def projections(self, model: EigenspaceModel) -> np.ndarray:
        """x'(s_ti) as ``(T, 3, K)``."""
        return model.projections[self.point_idx, self.dir_idx]

    def membership(self, n_points: int) -> np.ndarray:
        """``(n_points, T)``: whether learning point w is one of triplet t's three."""
        return np.asarray((self.point_idx[None] == np.arange(n_points)[:, None, None])
                          .any(axis=2))

    def subset(self, idx: np.ndarray) -> Triplets:
        return Triplets(self.point_idx[idx], self.dir_idx[idx], self.target[idx], self.area[idx])


MemberKey = tuple[tuple[int, int], ...]


def member_key(points: Sequence[int] | np.ndarray, dirs: Sequence[int] | np.ndarray
               ) -> MemberKey:
    """Order-free identity of a triplet: its sorted (point, direction) members."""
    return tuple(sorted(zip((int(p) for p in points), (int(d) for d in dirs), strict=True)))


def neighbour_triples(points: np.ndarray, max_dist: float, min_area: float) -> np.ndarray:
    """Triples ``(n, 3)`` (i < j < k) whose mutual distances are all <= ``max_dist``."""
    tree = cKDTree(points)
    pairs = tree.query_pairs(max_dist, output_type="ndarray")
    adj: dict[int, set[int]] = {}
    for i, j in pairs:
        adj.setdefault(int(i), set()).add(int(j))
        adj.setdefault(int(j), set()).add(int(i))
    out = []
    for i, j in pairs:
        i, j = sorted((int(i), int(j)))
        for k in adj[i] & adj[j]:
            if k > j and triangle_area(points[[i, j, k]]) >= min_area:
                out.append((i, j, k))
    return np.array(sorted(out), dtype=int).reshape(-1, 3)


def triangle_area(p3: np.ndarray) -> float:
    a, b, c = np.asarray(p3, dtype=float)
    return 0.5 * abs(float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])))


def best_partner_directions(model: EigenspaceModel, w1: int, w2: int,
                            config: TripletConfig) -> tuple[np.ndarray, np.ndarray]:
    """Step 1(a)i for every theta_1 at once: for each direction index at ``w1`` the best
    direction index at ``w2`` (-1 when none is admissible) and the meeting point w_12
    ``(Nt, 2)`` (NaN when none)."""
    th = model.directions
    p1, p2 = model.points[w1], model.points[w2]
    u = np.stack([np.cos(th), np.sin(th)], axis=1)  # (Nt, 2)
    u1, u2 = u[:, None, :], u[None, :, :]
    # w1 + t1 u1 = w2 + t2 u2  ->  t1 u1 - t2 u2 = (w2 - w1)
    det = -(u1[..., 0] * u2[..., 1] - u1[..., 1] * u2[..., 0])  # (Nt, Nt)
    r = p2 - p1
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (r[0] * (-u2[..., 1]) - r[1] * (-u2[..., 0])) / det
        t2 = (u1[..., 0] * r[1] - u1[..., 1] * r[0]) / det
        ratio = t1 / t2
    dth = np.abs(wrap_angle(th[:, None] - th[None, :]))
    ok = ((np.abs(det) > 1e-9) & (t1 > 0) & (t2 > 0) & (ratio > config.k_alpha)
          & (ratio < 1.0 / config.k_alpha) & (dth < config.theta_alpha_rad))
    dist = np.linalg.norm(model.projections[w1][:, None, :] - model.projections[w2][None, :, :],
                          axis=-1)
    dist = np.where(ok, dist, np.inf)
    best = np.argmin(dist, axis=1)
    has = np.isfinite(dist[np.arange(len(th)), best])
    best = np.where(has, best, -1)
    meet = p1 + np.where(has, t1[np.arange(len(th)), np.maximum(best, 0)], np.nan)[:, None] * u
    return best, meet


def find_localizable_triplets(model: EigenspaceModel, config: TripletConfig,
                              only_with: set[int] | None = None) -> Triplets:
    """The §2.3 search over all nearby triples (those containing a point of
    ``only_with`` when given, to update after adding learning points)."""
    triples = neighbour_triples(model.points, config.neighbour_max_m, config.min_area_m2)
    if only_with is not None:
        keep = [i for i, t in enumerate(triples) if set(t.tolist()) & only_with]
        triples = triples[keep]
    cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def partner(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        if (a, b) not in cache:
            cache[(a, b)] = best_partner_directions(model, a, b, config)
        return cache[(a, b)]

    seen: set[MemberKey] = set()
    pidx, didx, target, area = [], [], [], []
    for tri in triples:
        a_m2 = triangle_area(model.points[tri])
        for w1, w2, w3 in permutations(tri.tolist()):
            if w2 > w3:
                continue  # (w2, w3) and (w3, w2) are the same search
            b2, m12 = partner(w1, w2)
            b3, m13 = partner(w1, w3)
            ok = (b2 >= 0) & (b3 >= 0)
            close = np.zeros_like(ok)
            close[ok] = np.linalg.norm(m12[ok] - m13[ok], axis=1) <= config.d_alpha_m
            # w_12 = w_13 says nothing when the rays from w_2 and w_3 are one line
            u2 = np.stack([np.cos(model.directions[b2]), np.sin(model.directions[b2])], axis=1)
            off = model.points[w3] - model.points[w2]
            same_line = np.abs(u2[:, 0] * off[1] - u2[:, 1] * off[0]) <= config.d_alpha_m
            close &= ~(same_line & (b2 == b3))
            for j1 in np.flatnonzero(close):
                members = ((w1, int(j1)), (w2, int(b2[j1])), (w3, int(b3[j1])))
                key = member_key([m[0] for m in members], [m[1] for m in members])
                if key in seen:
                    continue
                seen.add(key)
                pidx.append([m[0] for m in members])
                didx.append([m[1] for m in members])
                target.append(0.5 * (m12[j1] + m13[j1]))
                area.append(a_m2)
    if not pidx:
        return Triplets.empty()
    return Triplets(np.array(pidx, dtype=int), np.array(didx, dtype=int),
                    np.array(target, dtype=float), np.array(area, dtype=float))


def merge(a: Triplets, b: Triplets) -> Triplets:
    """Union of two triplet sets (duplicates dropped, ``a``'s order kept first)."""
    seen = {member_key(p, d) for p, d in zip(a.point_idx, a.dir_idx, strict=True)}
    keep = [i for i, (p, d) in enumerate(zip(b.point_idx, b.dir_idx, strict=True))
            if member_key(p, d) not in seen]
    bb = b.subset(np.array(keep, dtype=int))
    return Triplets(np.vstack([a.point_idx, bb.point_idx]), np.vstack([a.dir_idx, bb.dir_idx]),
                    np.vstack([a.target, bb.target]), np.concatenate([a.area, bb.area]))
