"""Localization with several stops (paper §2.5, §3.4) and candidate-multiple sets (§3.3).

At every stop the robot takes one full turn of images (relative headings
``2 pi j / n``); each image's region hits (eq. 6) give candidate start-of-turn poses.
Odometry between stops normalises every candidate to the pose of the first stop;
candidates that agree within the tolerances are identified and vote for each other
with weight ``1 - D_err / D_thd`` (smaller d, more votes).  The stop is *unique* when
the winner's group has at least ``min_votes`` and no candidate disagrees with it or it
leads every rival by the vote ratio ``vote_margin``.  Which X / Y^(m) / Z state
follows is decided by the Fig. 4 rules in ``prolog/eigenspace.pl`` from the outcome
this module reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.eigenspace.learning import DYNAMIC_RANGE, EigenspaceModel
from chizu.numeric.eigenspace.regions import (
    RegionConfig,
    agrees,
    near_plane,
    region_candidates,
)
from chizu.numeric.eigenspace.triplets import Triplets, triangle_area
from chizu.numeric.geometry import compose, free_distance, invert, wrap_angle


class LocalizationConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    same_position_m: float = Field(1.0, gt=0.0, le=100.0,
                                   description="candidates closer than this are identified")
    same_heading_rad: float = Field(float(np.deg2rad(15.0)), gt=0.0, le=np.pi)
    odometry_slack_ratio: float = Field(0.05, ge=0.0, le=1.0,
                                        description="extra position tolerance per metre driven")
    vote_margin: float = Field(2.0, ge=1.0, le=1000.0,
                               description="winner/rival vote ratio that makes a stop unique")
    min_votes: float = Field(1.0, ge=0.0, le=1000.0,
                             description="votes the winning group needs to be unique (a "
                                         "lone weak hit is not a localization)")
    turn_min_range_m: float | None = Field(
        5.0, gt=0.0, le=1000.0,
        description="the estimate also interpolates the latest whole turn "
                    "(whole_turn_fit) over the images whose wall lies at least this far, "
                    "and averages it with eq. 5's; None: eq. 5 alone (the paper)")
    turn_near_range_m: float | None = Field(
        4.0, gt=0.0, le=1000.0,
        description="where too few of a turn's walls lie turn_min_range_m away for the "
                    "whole-turn fit (a small room), it uses those at least this far; "
                    "None: turn_min_range_m everywhere")
    turn_check_fd: float | None = Field(
        0.04, gt=0.0, le=10.0,
        description="a stop is also answered by the whole-turn check "
                    "(whole_turn_check): a place eq. 6 admits on d alone whose whole-turn "
                    "fit leaves a residual below this (eq. 2's f_d per image, root mean "
                    "square), when no place elsewhere passes; needs turn_min_range_m. "
                    "None: the vote alone (the paper)")


@dataclass
class RegionModel:
    """What localization needs from the analysis: the eigenspace, the triplets and the
    eq.-6 constants."""

    model: EigenspaceModel
    triplets: Triplets
    c_a: float
    d_thd_m: float
    plane_thd_m: float | None = None

    @staticmethod
    def of(model: EigenspaceModel, triplets: Triplets, c_a: float,
           config: RegionConfig) -> RegionModel:
        """The region model with ``config``'s thresholds (D_thd and the plane test)."""
        return RegionModel(model, triplets, c_a, config.d_thd_m, config.plane_thd_m)


@dataclass
class TurnCandidates:
    """Region hits of one turn: triplet ``t``, eq.-6 ``d_err`` and the estimated pose at
    the start of the turn ``start_pose (n, 3)``."""

    t: np.ndarray
    d_err: np.ndarray
    start_pose: np.ndarray
    image: np.ndarray
    #: :func:`turn_appearance` of a turn without hits ``(Nw, n)``; None for a turn with
    #: hits or of another length
    appearance: np.ndarray | None = None
    #: the turn's projections ``(n, K)`` (eq. 1), for :func:`whole_turn_fit`
    projections: np.ndarray | None = None
    #: the start-of-turn pose ``(3,)`` the whole-turn check found
    #: (:func:`whole_turn_check`); None when it found none or did not run
    checked: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)


def turn_candidates(regions: RegionModel, images: np.ndarray,
                    walls: tuple[np.ndarray, np.ndarray] | None = None,
                    config: LocalizationConfig | None = None) -> TurnCandidates:
    """Region hits of a full turn ``(n, H, W)`` (relative headings 2 pi j / n).

    With the world's ``walls`` and a ``config`` whose ``turn_check_fd`` is set, the
    whole-turn check (:func:`whole_turn_check`) also runs on the hits eq. 6 admits on d
    alone: the hits of the place it finds join those that pass the plane test."""
    imgs = regions.model.check_images(images)
    q = regions.model.project(imgs)
    c = region_candidates(regions.model, regions.triplets, q, regions.c_a, regions.d_thd_m)
    start = c.pose.copy()
    start[:, 2] = wrap_angle(c.pose[:, 2] - 2.0 * np.pi * c.m / len(imgs))
    keep = np.ones(len(c), dtype=bool)
    if regions.plane_thd_m is not None and len(c):
        keep = near_plane(regions.model, regions.triplets, q[c.m], c.t, regions.c_a,
                          regions.plane_thd_m)
    checked = None
    if (walls is not None and config is not None and config.turn_check_fd is not None
            and config.turn_min_range_m is not None and len(c)):
        found = whole_turn_check(regions.model, q, start, c.d_err, walls, config)
        if found is not None:
            checked, members = found
            keep |= members
    t, d_err, start, m = c.t[keep], c.d_err[keep], start[keep], c.m[keep]
    # the appearance serves the movement strategy while no region has been entered
    # (state X): a turn with hits leaves X, so only a turn without any pays for it
    return TurnCandidates(t=t, d_err=d_err, start_pose=start, image=m,
                          appearance=None if len(t) else turn_appearance(regions.model, q),
                          projections=q, checked=checked)


#: places (groups of agreeing hits, best D_err first) the whole-turn check fits at most
CHECK_PLACES = 8


def whole_turn_check(model: EigenspaceModel, q: np.ndarray, start: np.ndarray,
                     d_err: np.ndarray, walls: tuple[np.ndarray, np.ndarray],
                     config: LocalizationConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """The whole-turn check: where a turn ``q (n, K)`` was taken, judged by all its
    images at once, or None.

    Eq. 6 on d alone admits a turn's images at the right place and, as d is the
    smallest of three differences, at look-alike places too; the plane test (eq. 4)
    keeps eq. 5's accuracy but refuses most right admissions with the wrong ones. Here
    every place those admissions name (hits with start-of-turn poses ``start (M, 3)``
    grouped within the identification tolerances, best ``d_err`` first, at most
    :data:`CHECK_PLACES`) is fitted by :func:`whole_turn_fit`, which asks the n images
    of the turn to be one interpolation of the learning turns around that place. At
    the right place the fit explains the images; at a look-alike place a few images
    agree and the rest do not. A place passes when the fit's residual lies below
    ``config.turn_check_fd`` (eq. 2's f_d per image); the turn is localized when every
    place that passes agrees with the best one (docs/notes/eigenspace.md, "Why a turn
    is also checked whole").

    Returns ``(pose (3,), members (M,))``: the best fit's start-of-turn pose and the
    hits of the places that passed."""
    assert config.turn_check_fd is not None and config.turn_min_range_m is not None
    pos, head = config.same_position_m, config.same_heading_rad
    left = np.ones(len(start), dtype=bool)
    passed: list[tuple[TurnFit, np.ndarray]] = []
    places = 0
    for i in np.argsort(d_err):
        if not left[i]:
            continue
        if places == CHECK_PLACES:
            break
        places += 1
        same = agrees(start, start[i], pos, head) & left
        left[same] = False
        fit = whole_turn_fit(model, q, start[i], walls, config.turn_min_range_m,
                             config.turn_near_range_m)
        if fit is not None and fit.residual < config.turn_check_fd:
            passed.append((fit, same))
    if not passed:
        return None
    best = min(passed, key=lambda p: p[0].residual)[0]
    if not all(agrees(f.pose, best.pose, pos, head) for f, _ in passed):
        return None
    return best.pose, np.logical_or.reduce([m for _, m in passed])


def turn_appearance(model: EigenspaceModel, q: np.ndarray) -> np.ndarray | None:
    """How well each learning point's turn explains an observed turn, at every heading:
    ``A[i, m]`` = mean over the turn's images j of eq. 2's f_d between image j and
    learning image ``(j + m) mod n`` of point i, for projections ``q (n, K)`` at relative
    headings 2 pi j / n. A small ``A[i, m]`` says the turn started near point i facing
    direction 2 pi m / n: the nearest-learning-image estimate of Maeda & Shirai's Table 2
    baseline, kept for every point and heading. The movement strategy weighs where the
    robot may be with it while no region has been entered (see
    :func:`chizu.numeric.eigenspace.movement_strategy.appearance_scores`). None when the
    turn does not have one image per learned direction."""
    p = model.projections  # (Nw, n, K)
    n = p.shape[1]
    if len(q) != n or n == 0:
        return None
    flat = p.reshape(-1, p.shape[2])
    d2 = (np.einsum("ik,ik->i", flat, flat)[:, None] + np.einsum("jk,jk->j", q, q)[None, :]
          - 2.0 * flat @ q.T)
    d = np.sqrt(np.clip(d2, 0.0, None))  # (Nw * n learned j', n seen j)
    shifted = np.take(d.reshape(len(p), n * n), _shift_index(n), axis=1)  # (Nw, m * n + j)
    return np.asarray(shifted.reshape(len(p), n, n).sum(axis=2)
                      / (n * DYNAMIC_RANGE * np.sqrt(model.n_pixels)), dtype=np.float32)


@dataclass(frozen=True)
class TurnFit:
    """:func:`whole_turn_fit`'s answer: the start-of-turn pose ``(3,)`` and how far the
    turn's images lie from their interpolation (eq. 2's f_d per image, root mean
    square over the images that took part)."""

    pose: np.ndarray
    residual: float


def whole_turn_fit(model: EigenspaceModel, q: np.ndarray, pose: np.ndarray,
                   walls: tuple[np.ndarray, np.ndarray], min_range_m: float,
                   near_range_m: float | None = None, iterations: int = 3,
                   max_shift_m: float = 1.0, min_images: int = 8, n_points: int = 5,
                   heading_span_rad: float = float(np.deg2rad(10.0)),
                   heading_step_rad: float = float(np.deg2rad(1.0))) -> TurnFit | None:
    """Eqs. 4-5 over a whole turn: the pose of a turn ``q (n, K)`` (relative headings
    2 pi j / n) that starts near ``pose``, and the fit's residual; or None.

    Eq. 5 interpolates one image per triplet, the three learning images that look at a
    common target (§2.3). A turn at a known place holds n such images: from the current
    estimate, image j's ray meets the wall at a target T_j (the world's ``walls``), and
    each of the ``n_points`` learning points nearest the estimate has an image toward
    T_j (between two learned directions, linearly). One set of affine weights k (eq. 4
    with more than three points, sum k_i = 1) is fitted by least squares to all those
    images at once, and the position is ``sum k_i w_i`` (eq. 5); the targets move with
    the estimate, so this is repeated ``iterations`` times. The first three points are
    the nearest two and the nearest one off their line (a triangle of area at least
    d12² / 4), so the fit is never degenerate. Only images whose target lies at least
    ``min_range_m`` away and is in sight of every point take part: near walls change
    with the viewpoint far from linearly. Where too few of them do at every heading (a
    small room, or a door hiding the far walls from some of the points), the fit is
    tried again with the images whose target lies at least ``near_range_m`` away.

    Which learned direction each image is compared with follows from the heading, and
    eq. 5's heading is a few degrees off. The fit is therefore repeated at headings
    within ``heading_span_rad`` of ``pose``'s, ``heading_step_rad`` apart, and the one
    whose images the fit explains best (smallest residual) is kept: the answer's
    heading is that one.

    Chizu's addition to §2.2: many images average out what one image's interpolation
    gets wrong (docs/notes/eigenspace.md, "Why the pose also uses the whole turn").

    None when fewer than ``min_images`` images qualify at every heading, there are not
    three learning points off one line, or every answer lies more than ``max_shift_m``
    from ``pose``."""
    q = np.asarray(q, dtype=float)
    n = len(q)
    pts = model.points
    if n == 0 or len(pts) < 3:
        return None
    order = np.argsort(np.hypot(*(pts - pose[:2]).T))
    d12 = float(np.linalg.norm(pts[order[0]] - pts[order[1]]))
    third = [i for i in order[2:]
             if triangle_area(pts[[order[0], order[1], i]]) >= 0.25 * d12 ** 2]
    if not third:
        return None
    first = [int(order[0]), int(order[1]), int(third[0])]
    more = [int(i) for i in order[2:] if i != third[0]][:max(n_points - 3, 0)]
    idx = np.array(first + more)
    corners = pts[idx]
    rel = 2.0 * np.pi * np.arange(n) / n
    steps = int(round(heading_span_rad / heading_step_rad)) if heading_step_rad > 0 else 0
    best: TurnFit | None = None
    for bound in (min_range_m,) if near_range_m is None else (min_range_m, near_range_m):
        for dh in heading_step_rad * np.arange(-steps, steps + 1):
            heading = float(pose[2] + dh)
            fit = _fit_turn(model, q, idx, corners, np.asarray(pose[:2], dtype=float),
                            heading + rel, walls, bound, iterations, min_images)
            if fit is None or np.hypot(*(fit[0] - pose[:2])) > max_shift_m:
                continue
            if best is None or fit[1] < best.residual:
                best = TurnFit(np.array([fit[0][0], fit[0][1], wrap_angle(heading)]),
                               fit[1])
        if best is not None:
            break
    return best


def _fit_turn(model: EigenspaceModel, q: np.ndarray, idx: np.ndarray, corners: np.ndarray,
              xy: np.ndarray, heads: np.ndarray, walls: tuple[np.ndarray, np.ndarray],
              min_range_m: float, iterations: int, min_images: int
              ) -> tuple[np.ndarray, float] | None:
    """One heading of :func:`whole_turn_fit`: the position and the fit's residual (eq.
    2's f_d per image, root mean square), or None."""
    n, c = len(q), len(idx)
    n_dir = len(model.directions)
    step = 2.0 * np.pi / n_dir
    residual = np.inf
    for _ in range(iterations):
        r = free_distance(np.repeat(xy[None], n, axis=0), heads, *walls)
        use = np.flatnonzero(np.isfinite(r) & (r >= min_range_m))
        if len(use) < min_images:
            return None
        target = xy + r[use, None] * np.column_stack([np.cos(heads[use]), np.sin(heads[use])])
        to = target[None] - corners[:, None]                                 # (c, m, 2)
        dist = np.hypot(to[..., 0], to[..., 1])
        ang = np.arctan2(to[..., 1], to[..., 0])
        # the target is in sight of every learning point (one ray cast for them all)
        seen = free_distance(np.repeat(corners, len(use), axis=0), ang.reshape(-1), *walls)
        sight = (seen.reshape(c, -1) >= dist - 0.1).all(axis=0)
        use, ang = use[sight], ang[:, sight]
        if len(use) < min_images:
            return None
        u = (wrap_angle(ang - model.directions[0]) / step) % n_dir
        j0 = np.floor(u).astype(int) % n_dir
        f = (u - np.floor(u))[..., None]
        xc = ((1.0 - f) * model.projections[idx[:, None], j0]
              + f * model.projections[idx[:, None], (j0 + 1) % n_dir]).transpose(1, 0, 2)
        # eq. 4 with sum k = 1: q - x_c = sum_{i<c} k_i (x_i - x_c), all images stacked
        a = (xc[:, :-1] - xc[:, -1:]).transpose(0, 2, 1).reshape(-1, c - 1)
        b = (q[use] - xc[:, -1]).reshape(-1)
        k = np.linalg.lstsq(a, b, rcond=None)[0]
        residual = float(np.sqrt(np.sum((a @ k - b) ** 2) / len(use))
                         / (DYNAMIC_RANGE * np.sqrt(model.n_pixels)))
        xy = np.append(k, 1.0 - k.sum()) @ corners
    return xy, residual


@lru_cache(maxsize=8)
def _shift_index(n: int) -> np.ndarray:
    """Flat indices ``((j + m) mod n) * n + j`` in row-major ``(m, j)`` order."""
    j = np.arange(n)
    return (((j[None, :] + j[:, None]) % n) * n + j[None, :]).ravel()


@dataclass
class Vote:
    """Result of voting over all stops so far."""

    unique: bool
    winner: int | None  # index into the pooled candidates
    votes: np.ndarray
    clusters: list[list[int]]  # pooled candidate indices per identified group
    #: what kept a vote over candidates from being unique: "vote_threshold",
    #: "vote_margin" or "candidate_set" (None when unique or without any candidate)
    refused: str | None = None
    #: the strongest group that disagrees with the winner (None: no such group)
    rival_votes: float | None = None
    #: the winner is the place the latest stop's whole-turn check found
    checked: bool = False


@dataclass
class Session:
    """A localization run: stops, odometry and the pooled candidates (pure numeric).

    ``odometry[k]`` is the pose of stop k's start in stop 0's frame (stop 0 is the origin).
    """

    config: LocalizationConfig
    odometry: list[np.ndarray] = field(default_factory=list)
    travelled_m: float = 0.0
    stop_of: list[int] = field(default_factory=list)
    triplet: list[int] = field(default_factory=list)
    weight: list[float] = field(default_factory=list)
    pose0: list[np.ndarray] = field(default_factory=list)
    own_pose: list[np.ndarray] = field(default_factory=list)
    #: each stop's :func:`turn_appearance` (None where unknown)
    appearance: list[np.ndarray | None] = field(default_factory=list)
    #: the latest stop's projections ``(n, K)`` (None where unknown)
    last_turn: np.ndarray | None = None
    #: each stop's whole-turn check: the start-of-turn pose it found, in that stop's
    #: frame (None where it found none)
    checked: list[np.ndarray | None] = field(default_factory=list)

    @property
    def stops(self) -> int:
        return len(self.odometry)

    def add_stop(self, cands: TurnCandidates, d_thd_m: float,
                 motion: np.ndarray | None = None) -> TurnCandidates:
        """Record a stop; ``motion`` is (dx, dy, dtheta) from the previous stop's start in
        its frame (ignored for the first stop)."""
        if not self.odometry:
            self.odometry.append(np.zeros(3))
        else:
            mv = np.zeros(3) if motion is None else np.asarray(motion, dtype=float)
            self.odometry.append(compose(self.odometry[-1], mv))
            self.travelled_m += float(np.hypot(mv[0], mv[1]))
        self.appearance.extend([None] * (self.stops - 1 - len(self.appearance)))
        self.appearance.append(cands.appearance)
        self.checked.extend([None] * (self.stops - 1 - len(self.checked)))
        self.checked.append(None if cands.checked is None
                            else np.asarray(cands.checked, dtype=float))
        self.last_turn = cands.projections
        o = self.odometry[-1]
        inv = invert(o)
        self.stop_of.extend([self.stops - 1] * len(cands))
        self.triplet.extend(np.asarray(cands.t, dtype=int).tolist())
        self.weight.extend(np.maximum(1e-3, 1.0 - np.asarray(cands.d_err) / d_thd_m).tolist())
        self.pose0.extend(compose(cands.start_pose, inv).reshape(-1, 3))
        self.own_pose.extend(np.asarray(cands.start_pose, dtype=float).reshape(-1, 3))
        return cands

    def same(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Whether candidates at stop-0 poses ``p (..., 3)`` and ``q (..., 3)`` are
        identified (broadcast over the leading axes)."""
        tol = self.config.same_position_m + self.config.odometry_slack_ratio * self.travelled_m
        return agrees(p, q, tol, self.config.same_heading_rad)

    def vote(self, set_of: np.ndarray | None = None) -> Vote:
        """Mutual voting of §2.5 over every candidate so far.

        With ``set_of`` (each triplet's candidate-multiple set, -1 for none), the vote
        is never unique while every triplet hit so far lies in one set: its members
        are places the images cannot tell apart (§3.3), so a lead among them is noise
        (a half-turn-symmetric room gave confident answers on the wrong side). The
        state stays Y until a hit outside the set lets odometry decide.

        When the latest stop's whole-turn check found a place
        (:func:`whole_turn_check`), that place wins: the strongest of the stop's hits
        there, whatever the votes of single images elsewhere (the check weighs every
        image of the turn at once) -- unless one of those hits lies in a
        candidate-multiple set: a look-alike place explains the turn as well, and the
        place it names may be the wrong one of the two."""
        n = len(self.pose0)
        if n == 0:
            return Vote(False, None, np.zeros(0), [])
        p = np.array(self.pose0)
        w = np.array(self.weight)
        same = self.same(p[None, :], p[:, None])  # (n, n): i identified with j
        votes = same.astype(float) @ w
        win = int(np.argmax(votes))
        checked = self.checked[-1] if len(self.checked) == self.stops else None
        at = np.zeros(n, dtype=bool)
        if checked is not None:
            at = ((np.array(self.stop_of) == self.stops - 1)
                  & agrees(np.array(self.own_pose), checked, self.config.same_position_m,
                           self.config.same_heading_rad))
            if set_of is not None and (set_of[np.array(self.triplet)[at]] >= 0).any():
                at[:] = False
        if at.any():
            win = int(np.flatnonzero(at)[np.argmax(votes[at])])
        rivals = ~same[win]
        # §2.5: unique when the winner leads every group it cannot be identified with by
        # enough; with no rival the lead is its own votes, which must reach min_votes
        # (room A, 100 single turns: a lone hit with weight 0.05 was 1.2 m off; at 1.0
        # the unique answers fell from 84 to 36, the wrong ones from 9 to 0)
        rival = float(votes[rivals].max()) if rivals.any() else None
        refused = None
        if not at.any() and votes[win] < self.config.min_votes:
            refused = "vote_threshold"
        elif not at.any() and rival is not None and votes[win] < self.config.vote_margin * rival:
            refused = "vote_margin"
        elif set_of is not None:
            sets = {int(set_of[t]) for t in self.triplet}
            if len(sets) == 1 and min(sets) >= 0:
                refused = "candidate_set"
        clusters: list[list[int]] = []
        left = np.ones(n, dtype=bool)
        for i in np.argsort(-votes):
            if left[i]:
                members = np.flatnonzero(same[i] & left)
                clusters.append(members.tolist())
                left[members] = False
        return Vote(refused is None, win, votes, clusters, refused, rival, bool(at.any()))

    def representatives(self, vote: Vote) -> list[int]:
        """The strongest candidate (largest weight) of each identified group."""
        return [max(cluster, key=lambda i: self.weight[i]) for cluster in vote.clusters]

    def current_pose(self, candidate: int) -> np.ndarray:
        """Pose at the start of the latest stop implied by a pooled candidate."""
        if self.stop_of[candidate] == self.stops - 1:
            return np.asarray(self.own_pose[candidate])
        return compose(self.pose0[candidate], self.odometry[-1])

    def estimate(self, vote: Vote, model: EigenspaceModel | None = None,
                 walls: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """The pose at the start of the latest stop: the weighted mean (weights ``1 -
        D_err/D_thd``, θ on the circle) of the candidates identified with the winner,
        each carried to the latest stop. A full turn enters the right region through
        several images; each gives eq. 5's pose with its own error, and their mean is
        steadier than the winner's alone (room A, 60 random single turns: mean error of
        the unique answers 0.46 -> 0.43 m). Chizu's addition to §2.5, which takes the
        most-voted candidate.

        With the eigenspace ``model`` and the world's ``walls`` (and
        ``turn_min_range_m`` set), the position is the mean of that and
        :func:`whole_turn_fit` of the latest turn around it, and the heading is the
        whole turn's."""
        p = self._eq5_estimate(vote)
        rng = self.config.turn_min_range_m
        if model is None or walls is None or rng is None or self.last_turn is None:
            return p
        fit = whole_turn_fit(model, self.last_turn, p, walls, rng,
                             self.config.turn_near_range_m)
        if fit is not None:
            turn = fit.pose
            p = np.array([(p[0] + turn[0]) / 2, (p[1] + turn[1]) / 2, turn[2]])
        return p

    def _eq5_estimate(self, vote: Vote) -> np.ndarray:
        if vote.winner is None:
            raise ValueError("no candidates to estimate from")
        same = self.same(np.array(self.pose0), self.pose0[vote.winner])
        idx = np.flatnonzero(same)
        poses = np.array([self.current_pose(int(i)) for i in idx])
        w = np.array(self.weight)[idx]
        xy = np.average(poses[:, :2], axis=0, weights=w)
        th = float(np.arctan2(np.average(np.sin(poses[:, 2]), weights=w),
                              np.average(np.cos(poses[:, 2]), weights=w)))
        return np.array([xy[0], xy[1], th])

    def stop_triplets(self, k: int) -> list[int]:
        """Distinct triplets hit at stop ``k``."""
        return sorted({t for s, t in zip(self.stop_of, self.triplet, strict=True) if s == k})


def candidate_multiple_sets(regions: RegionModel) -> list[list[int]]:
    """§3.3: groups of triplets that a robot standing at their learning points cannot
    tell apart.

    Each learning point's own full turn of learning images is treated as an observation
    and yields the set S_w of triplets it enters.  For every pair of triplets the
    closest pair of their images (in the eigenspace) names two learning points w_a,
    w_b; if S_wa == S_wb the two triplets join the same set (union-find).
    """
    m, tr = regions.model, regions.triplets
    n_t = len(tr)
    if n_t < 2:
        return []
    entered: list[frozenset[int]] = []
    for w in range(len(m.points)):
        c = region_candidates(m, tr, m.projections[w], regions.c_a, regions.d_thd_m,
                              regions.plane_thd_m)
        entered.append(frozenset(c.t.tolist()))
    x3 = tr.projections(m)  # (T, 3, K)
    parent = list(range(n_t))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for t1 in range(n_t - 1):
        d = np.linalg.norm(x3[t1][None, :, None, :] - x3[t1 + 1:, None, :, :], axis=-1)
        flat = d.reshape(len(d), -1).argmin(axis=1)  # (T - t1 - 1,)
        i1, i2 = np.unravel_index(flat, (3, 3))
        for off, (a, b) in enumerate(zip(i1, i2, strict=True)):
            t2 = t1 + 1 + off
            wa, wb = tr.point_idx[t1, a], tr.point_idx[t2, b]
            # a shared learning point is the same place, not a confusion of places
            if wa != wb and entered[wa] == entered[wb]:
                parent[find(t2)] = find(t1)
    groups: dict[int, list[int]] = {}
    for t in range(n_t):
        groups.setdefault(find(t), []).append(t)
    return sorted((g for g in groups.values() if len(g) > 1), key=lambda g: g[0])


def session_to_dict(s: Session) -> dict[str, object]:
    """JSON-safe form of a session (for the store)."""
    return {"config": s.config.model_dump(mode="json"),
            "odometry": [o.tolist() for o in s.odometry], "travelled_m": s.travelled_m,
            "stop_of": s.stop_of, "triplet": s.triplet, "weight": s.weight,
            "pose0": [p.tolist() for p in s.pose0], "own_pose": [p.tolist() for p in s.own_pose],
            "appearance": [None if a is None else np.round(a, 5).tolist()
                           for a in s.appearance],
            "last_turn": None if s.last_turn is None else np.round(s.last_turn, 6).tolist(),
            "checked": [None if c is None else c.tolist() for c in s.checked]}


def session_from_dict(d: dict[str, object]) -> Session:
    def arrs(key: str) -> list[np.ndarray]:
        return [np.asarray(v, dtype=float) for v in d[key]]  # type: ignore[attr-defined]

    return Session(config=LocalizationConfig.model_validate(d["config"]),
                   odometry=arrs("odometry"), travelled_m=float(d["travelled_m"]),  # type: ignore[arg-type]
                   stop_of=list(d["stop_of"]), triplet=list(d["triplet"]),  # type: ignore[call-overload]
                   weight=list(d["weight"]), pose0=arrs("pose0"),  # type: ignore[call-overload]
                   own_pose=arrs("own_pose"),
                   # sessions stored before the appearance was kept have none
                   appearance=[None if a is None else np.asarray(a, dtype=np.float32)
                               for a in d.get("appearance", [])],  # type: ignore[attr-defined]
                   # sessions stored before the latest turn was kept have none
                   last_turn=None if d.get("last_turn") is None
                   else np.asarray(d["last_turn"], dtype=float),
                   # sessions stored before the whole-turn check have no checks
                   checked=[None if c is None else np.asarray(c, dtype=float)
                            for c in d.get("checked", [])])  # type: ignore[attr-defined]
