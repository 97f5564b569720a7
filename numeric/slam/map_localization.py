"""Localization only, on a saved map: where the robot is in a map it does not change.

A robot that already has a map (:mod:`chizu.numeric.slam.saved_map`) needs its pose in it,
from an unknown start and again after it was carried away, not a new map. The steps
are Cartographer's pure localization (Hess et al. 2016, §V) on a likelihood field as
AMCL reads a map (Thrun, Burgard, Fox, *Probabilistic Robotics*, §6.4):

1. **The map's likelihood field** (:func:`likelihood_grid`): each cell ``exp(-d² /
   2σ²)`` of its distance d to the nearest occupied cell of the saved map's occupancy
   grid -- a scan that lies a little off the walls still scores, and the score rises
   smoothly towards them for the refinement; cells the map never saw score 0.
2. **Global localization** (:class:`GlobalSearch`): branch and bound (Hess et al.
   Algorithms 2-3) over the whole map and every heading, on the field coarsened to
   ``global_resolution_m``, of the places within ``global_free_m`` of a cell the map
   saw free (as AMCL draws its global particles from free cells), of the returns of
   the last ``context_m`` of travel placed by the odometry around the current scan
   (one scan of a corridor fits many corridors; a few metres of it, far fewer). A fix
   is taken only when it scores at least ``global_min_score`` and no pose farther than
   ``unique_m`` from it scores within ``unique_ratio`` of it (Olson 2009, §IV): a
   corridor that fits two places says nothing about which. It is then refined (step
   3), tracked ``confirm_scans`` scans, and taken only when a second global search, on
   that later scan, finds the same pose uniquely. A second search with no unique answer
   is neither for nor against the fix: it is tried again (``confirm_tries``); a unique
   answer elsewhere drops the fix.
3. **Tracking**: each scan is predicted by the odometry since the last one and refined
   by Gauss-Newton on the field (:func:`~chizu.numeric.slam.matching.correlative.refine`);
   when the refined score is poor, a correlative search of a small window first; then
   point-to-line ICP against the returns of the nearest keyframes, finer than the
   grid's cells. A match that moves the pose far from the prediction (``trust_m``,
   ``trust_rad``) is taken only when it scores ``trust_score``: a mediocre one is the
   scan's walls sliding along the map's. The score counts only the points on cells the
   map observed: a scan reaching into parts of the building the map never saw is
   neither for nor against a pose, and one mostly off the map is carried by odometry.
4. **Recovery**: a scan after a gap in the log longer than ``gap_s`` that does not
   fit the map where the wheel odometry over the gap puts it (the robot was carried), or
   ``lost_scans`` scans in a row scoring below ``lost_score``, and the robot is lost:
   global localization again, at most every ``search_every_s`` of log time and only
   once the robot has moved ``search_moved_m`` (``search_moved_full_m`` once a whole
   context has failed) or turned ``search_moved_rad``, until a new fix holds.
5. **Alignment**, when a whole log is localized (:func:`localize_log`): the scans the
   localizer could not place (off the map, or lost) placed by the motion estimate
   between the placed ones around them (:func:`bridged`), then graph SLAM's global
   scan alignment (Lu & Milios 1997) of every scan with the map's keyframes held
   (:func:`align_on_map`).

The map is never changed; the poses are in the map's frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, invert, place, relative, wrap_angle
from chizu.numeric.occupancy import FREE, OCCUPIED, UNKNOWN, build_occupancy_fitting
from chizu.numeric.probability_grid import GridConfig, ProbabilityGrid, no_stamps
from chizu.numeric.scan import LaserLog, Scan
from chizu.numeric.slam.alignment import (
    AlignmentConfig,
    align_globally,
    match_pair,
    pairwise_matches,
)
from chizu.numeric.slam.graph.loop_closure import adaptive_voxel
from chizu.numeric.slam.graph.scan_odometry import ScanOdometry
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.matching.correlative import (
    Match,
    PrecomputedGrid,
    correlative_search,
    offset_mask,
    refine,
    window_cells,
)
from chizu.numeric.slam.matching.intensity_icp import IcpConfig, Reference, intensity_icp
from chizu.numeric.slam.saved_map import Laser, SavedMap
from chizu.numeric.threads import default_threads, thread_map

State = Literal["searching", "confirming", "tracking"]


#: step 5's alignment: graph SLAM's, but its scans are matched to earlier ones (and to the
#: keyframes) facing within 1 rad of them only: with the map's keyframes held, scans
#: matched facing apart pull the robot's path off the map's (docs/notes/map-localization.md)
ON_MAP_ALIGNMENT = AlignmentConfig(revisit_max_turn_rad=1.0)


class MapLocalizationConfig(BaseModel):
    """The steps' parameters (m, rad, s); one set for every map."""

    model_config = ConfigDict(extra="forbid")
    resolution_m: float = Field(0.05, gt=0.0, le=0.5, description="tracking field's cells")
    sigma_m: float = Field(0.1, gt=0.0, le=2.0, description="the field's width (step 1)")
    global_resolution_m: float = Field(0.1, gt=0.0, le=1.0,
                                       description="cells of the global search")
    global_depth: int = Field(7, ge=1, le=10, description="branch-and-bound levels")
    global_points: int = Field(120, ge=10, le=2000,
                               description="a scan's points in the global search, at most")
    global_range_m: float = Field(20.0, gt=0.0,
                                  description="points of the global search lie this near")
    global_step_rad: float = Field(float(np.deg2rad(1.0)), gt=0.0, le=0.2,
                                   description="the global search's angular step")
    context_m: float = Field(10.0, ge=0.0, le=50.0,
                             description="a global search matches the scans of this much "
                                         "recent travel together (odometry)")
    search_every_s: float = Field(1.0, ge=0.0,
                                  description="while lost, a global search at most this "
                                              "often (log time) ...")
    search_moved_m: float = Field(0.5, ge=0.0, description="... and only once the robot "
                                  "has moved this far since the last one (while the "
                                  "context fills; once it holds ``context_m`` of travel "
                                  "since the robot was lost, ...")
    search_moved_full_m: float = Field(2.0, ge=0.0, description="... this far) ...")
    search_moved_rad: float = Field(0.5, ge=0.0, description="... or turned this far: "
                                    "else its scans are mostly the last search's, and so "
                                    "is the answer")
    global_free_m: float = Field(1.0, ge=0.0, description="a global search places the "
                                 "robot only this near a cell the map saw free")
    global_min_score: float = Field(0.55, gt=0.0, lt=1.0)
    unique_m: float = Field(3.0, gt=0.0, description="a rival fix must lie this far ...")
    unique_rad: float = Field(0.5, gt=0.0, le=np.pi, description="... or be turned this "
                              "far (a symmetric room or corridor seen the other way round)")
    unique_ratio: float = Field(0.9, gt=0.0, le=1.0,
                                description="a rival scoring this share of the fix "
                                            "makes it ambiguous")
    confirm_scans: int = Field(5, ge=1, le=100,
                               description="a fix is tracked this many scans, then a "
                                           "second global search must find it again")
    confirm_tries: int = Field(3, ge=1, le=100, description="a second search with no "
                               "unique answer (nothing scores ``confirm_min_score``, or "
                               "a rival as good as the best) says nothing against the "
                               "fix: it is tried again ``confirm_scans`` scans later, "
                               "this many times in all; only a unique answer elsewhere, "
                               "or the last try, drops the fix (a pose held across a gap "
                               "in the log, found by no global search, gets one try)")
    confirm_rad: float = Field(0.1, gt=0.0, le=np.pi)
    confirm_min_score: float = Field(0.4, gt=0.0, lt=1.0, description="the second "
                                     "search's best pose scores at least this: it must "
                                     "agree with the first, so it need not score as a "
                                     "fix alone must")
    track_points: int = Field(400, ge=10, le=5000)
    track_min_score: float = Field(0.5, gt=0.0, lt=1.0,
                                   description="below it the scan is searched in a window")
    track_window_m: float = Field(0.3, gt=0.0, le=5.0)
    track_window_rad: float = Field(0.15, gt=0.0, le=np.pi)
    icp_keyframes: int = Field(4, ge=0, le=50,
                               description="the scan is finally aligned to this many "
                                           "nearest keyframes' returns (0: not at all)")
    icp_radius_m: float = Field(4.0, gt=0.0)
    icp_max_shift_m: float = Field(0.2, gt=0.0)
    lost_score: float = Field(0.35, gt=0.0, lt=1.0,
                              description="mean field value of the points on observed "
                                          "cells below which a scan does not fit")
    trust_m: float = Field(0.08, gt=0.0, description="a match that moves the pose farther "
                           "than this from local SLAM's prediction ...")
    trust_rad: float = Field(0.05, gt=0.0, le=np.pi, description="... or turns it more "
                             "than this ...")
    trust_score: float = Field(0.55, gt=0.0, lt=1.0, description="... is taken only when "
                               "it scores at least this; else the prediction is kept")
    off_map_m: float = Field(60.0, gt=0.0, description="travel off the map after which "
                             "the pose (carried by local SLAM) is given up")
    min_on_map: float = Field(0.3, ge=0.0, le=1.0,
                              description="share of a scan's points on observed cells "
                                          "below which it is off the map")
    lost_scans: int = Field(10, ge=1, le=10_000)
    gap_s: float = Field(2.0, gt=0.0, description="after a longer gap in the log the robot "
                         "may have been carried: its pose is held only where the wheels put "
                         "it and a global search confirms it")
    bridge_m: float = Field(1.0, ge=0.0, description="scans between two placed ones are "
                            "bridged (step 5) when local SLAM's path between them meets "
                            "the second within this ...")
    bridge_per_m: float = Field(0.05, ge=0.0, description="... plus this times the path's "
                                "length ...")
    bridge_rad: float = Field(0.2, ge=0.0, le=np.pi, description="... and this turn: else "
                              "one of the two is in the wrong place and neither is trusted "
                              "with the scans between")


def likelihood_grid(saved: SavedMap, resolution_m: float, sigma_m: float
                    ) -> tuple[ProbabilityGrid, np.ndarray]:
    """Step 1: the map's likelihood field as a probability grid, and its cells' states
    in the map's occupancy grid (``UNKNOWN``, ``FREE``, ``OCCUPIED``)."""
    # a map too large at this resolution is read at a coarser one
    occ = build_occupancy_fitting(saved.frames(), saved.kf_pose, resolution_m)
    resolution_m = occ.resolution_m
    wall = occ.state == OCCUPIED
    d = ndimage.distance_transform_edt(~wall, sampling=resolution_m) if wall.any() \
        else np.full(wall.shape, np.inf)
    prob = np.exp(-0.5 * (d / sigma_m) ** 2).astype(np.float32)
    prob[(occ.state == UNKNOWN) & ~wall] = 0.0
    cfg = GridConfig(resolution_m=resolution_m)
    return (ProbabilityGrid(cfg, np.asarray(occ.origin, dtype=float), prob,
                            no_stamps(prob.shape), len(saved)),
            occ.state)


@dataclass
class GlobalSearch:
    """Step 2 over one map's field."""

    grid: ProbabilityGrid
    free: np.ndarray
    config: MapLocalizationConfig

    def __post_init__(self) -> None:
        cfg = self.config
        factor = max(1, int(round(cfg.global_resolution_m / self.grid.resolution_m)))
        self.search = PrecomputedGrid(self.grid.coarsened(factor), cfg.global_depth)
        g = self.search.grid
        size = np.array(g.shape) * g.resolution_m
        self.centre = np.array([*(g.origin + size / 2), 0.0])
        self.window_m = float(np.max(size) / 2)
        self.allowed = offset_mask(self._where_robot_stands(), cfg.global_depth)
        #: the window's centre facing either half of the headings (step 2's two parts)
        self.halves = [np.array([*self.centre[:2], h]) for h in (-np.pi / 2, np.pi / 2)]

    def _where_robot_stands(self) -> np.ndarray:
        """The offsets of the search window at which the robot stands within
        ``global_free_m`` of a cell the map saw free: a robot whose scans fit the map
        stands where a laser could see, not inside a wall or beyond the map's edge (as
        AMCL draws its global particles from the map's free cells). The window is a
        square over the map's longer side, and most of a building's plan is walls,
        rooms never entered and the space around it: the branch and bound prunes those
        offsets before scoring them."""
        near = ndimage.distance_transform_edt(~self.free, sampling=self.grid.resolution_m)
        near = near <= self.config.global_free_m
        res = self.search.grid.resolution_m
        w = window_cells(self.window_m, res)
        d = (np.arange(2 * w + 1) - w) * res
        cells = np.floor(self.grid.to_cells(self.centre[:2] + d[:, None])).astype(np.int64)
        ix, iy = cells[:, 0], cells[:, 1]
        okx = (ix >= 0) & (ix < near.shape[0])
        oky = (iy >= 0) & (iy < near.shape[1])
        out = np.zeros((len(ix), len(iy)), dtype=bool)
        out[np.ix_(okx, oky)] = near[np.ix_(ix[okx], iy[oky])]
        return out

    def fix(self, xy: np.ndarray, min_score: float | None = None) -> Match | None:
        """The best pose of robot-frame points ``xy`` anywhere in the map, or None when
        it scores below ``min_score`` (``global_min_score`` unless given) or is not
        unique."""
        answer = self.search_all(xy, min_score)
        return answer.best if answer.unique else None

    def search_all(self, xy: np.ndarray, min_score: float | None = None) -> GlobalAnswer:
        """The best pose of robot-frame points ``xy`` anywhere in the map scoring at
        least ``min_score`` (``global_min_score`` unless given), and whether it is
        unique. The headings are searched in two halves, on two threads when there are
        two cores (the same halves either way: the answer does not depend on it)."""
        cfg = self.config
        near = xy[np.hypot(xy[:, 0], xy[:, 1]) <= cfg.global_range_m]
        pts = adaptive_voxel(near, cfg.global_points, self.search.grid.resolution_m)
        if len(pts) < 8:
            return GlobalAnswer(None, False)
        floor = cfg.global_min_score if min_score is None else min_score
        shared = np.full(1, -1.0)  # the best either half has found: both prune with it
        found = [m for m in thread_map(
            lambda c: self.search.match(pts, c, self.window_m, np.pi / 2, floor,
                                        cfg.global_step_rad, self.allowed, shared),
            self.halves, default_threads()) if m is not None]
        if not found:
            return GlobalAnswer(None, False)
        best = max(found, key=lambda m: m.score)  # the first half's on a tie
        shared = np.full(1, -1.0)
        rivals = thread_map(
            lambda c: self.search.second_score(pts, c, self.window_m, np.pi / 2, best,
                                               cfg.unique_m, cfg.unique_ratio,
                                               cfg.global_step_rad, cfg.unique_rad,
                                               self.allowed, shared),
            self.halves, default_threads())
        return GlobalAnswer(best, max(rivals) == 0.0)


@dataclass(frozen=True)
class GlobalAnswer:
    """A global search's best pose (None: nothing scored the minimum) and whether no
    pose farther than ``unique_m`` (or turned ``unique_rad``) scores within
    ``unique_ratio`` of it."""

    best: Match | None
    unique: bool


def _near(pose: np.ndarray, other: np.ndarray, m: float, rad: float) -> bool:
    """Whether ``other`` lies within ``m`` of ``pose`` and is turned at most ``rad``."""
    d = relative(pose, other)
    return bool(np.hypot(d[0], d[1]) <= m and abs(d[2]) <= rad)


@dataclass
class Step:
    """One scan's outcome: its pose in the map (None while not localized), the state
    after it and the score of its match."""

    pose: np.ndarray | None
    state: State
    score: float


@dataclass
class PreparedMap:
    """What steps 1-2 precompute from a map (the field, its observed cells, the global
    search's pyramid): built once, read by every robot localizing on the map."""

    saved: SavedMap
    config: MapLocalizationConfig
    grid: ProbabilityGrid
    known: np.ndarray
    globally: GlobalSearch

    @staticmethod
    def of(saved: SavedMap, config: MapLocalizationConfig) -> PreparedMap:
        grid, state = likelihood_grid(saved, config.resolution_m, config.sigma_m)
        return PreparedMap(saved, config, grid, state != UNKNOWN,
                           GlobalSearch(grid, state == FREE, config))

    def on_map(self, pts: np.ndarray, pose: np.ndarray) -> tuple[float, float]:
        """The mean field value over robot-frame points ``pts`` at ``pose`` that fall on
        cells the map observed, and their share: points in parts of the building the map
        never saw say nothing about the pose, neither for nor against it."""
        g = self.grid
        c = np.floor(g.to_cells(place(pts, pose))).astype(np.int64)
        nx, ny = g.shape
        inside = (c[:, 0] >= 0) & (c[:, 0] < nx) & (c[:, 1] >= 0) & (c[:, 1] < ny)
        seen = np.zeros(len(pts), dtype=bool)
        seen[inside] = self.known[c[inside, 0], c[inside, 1]]
        if not seen.any():
            return 0.0, 0.0
        return float(g.prob[c[seen, 0], c[seen, 1]].mean()), float(seen.mean())


@dataclass
class MapLocalizer:
    """Feed scans in time order with :meth:`process`. Several localizers may share one
    :class:`PreparedMap` (``prepared``; built here if not given)."""

    saved: SavedMap
    config: MapLocalizationConfig = field(default_factory=MapLocalizationConfig)
    prepared: PreparedMap | None = None

    def __post_init__(self) -> None:
        cfg = self.config
        if self.prepared is None or self.prepared.config != cfg:
            self.prepared = PreparedMap.of(self.saved, cfg)
        self._map: PreparedMap = self.prepared
        self.grid = self.prepared.grid
        self.globally = self.prepared.globally
        self.state: State = "searching"
        self.pose: np.ndarray | None = None
        self._odom: np.ndarray | None = None
        self._wheels: np.ndarray | None = None  # the last scan's wheel odometry
        self._t: float | None = None
        self._low = 0
        self._confirmed = 0
        #: the stamp of the gap across which a tracked pose is held, until confirmed
        self._held_from: float | None = None
        self._searched: float | None = None
        self._searched_at: np.ndarray | None = None
        self._lost_m = 0.0
        self._history: list[tuple[np.ndarray, np.ndarray]] = []
        self._off_m = 0.0
        self._clouds = KeyframeClouds(self.saved, cfg.icp_keyframes, cfg.icp_radius_m)
        self._scan_odometry: ScanOdometry | None = None
        self._icp = IcpConfig(metric="line", max_correspondence_m=0.3)
        #: stamps of every fix taken, and of each time the robot was lost after one
        self.fixes: list[float] = []
        self.losses: list[float] = []

    @property
    def odom(self) -> np.ndarray | None:
        """The last scan's pose by local SLAM alone (the motion estimate; its frame
        starts again after a gap in the log)."""
        return self._odom

    def check_laser(self, laser: Laser) -> str | None:
        """What keeps this laser's scans from matching the map (None: nothing)."""
        return self.saved.laser.compatible(laser)

    def process(self, scan: Scan) -> Step:
        xy, _ = scan.points()
        gap = self._t is not None and scan.t - self._t > self.config.gap_s
        if self._scan_odometry is None:
            self._scan_odometry = ScanOdometry()
        elif gap:  # the robot may have been carried: a new local map
            self._scan_odometry.restart()
        odom = self._scan_odometry(scan)
        wheels, self._wheels = self._wheels, scan.odom.copy()
        prev_odom, self._odom, self._t = self._odom, odom.copy(), scan.t
        kept = None
        if gap:
            assert wheels is not None and prev_odom is not None
            kept = self._across_gap(scan.t, xy, prev_odom, odom, relative(wheels, scan.odom))
            if kept is None:  # lost, or still searching with what it saw before the gap
                self._lose(scan.t)
        self._remember(odom, xy)
        if kept is not None:
            return kept
        if self.state == "searching":
            return self._search(scan.t, odom, xy)
        assert self.pose is not None and prev_odom is not None
        predicted = compose(self.pose, relative(prev_odom, odom))
        pose, score, share = self.fit(xy, predicted)
        if share < self.config.min_on_map:
            # off the map: local SLAM carries the pose until the scans see the map
            # again, for ``off_map_m`` of travel; beyond, it may have drifted too far to
            # pick up the right walls on the way back, and a global search must find them
            self._off_m += float(np.hypot(*relative(prev_odom, odom)[:2]))
            if self._off_m > self.config.off_map_m:
                self._lose(scan.t)
                return Step(None, self.state, score)
            self.pose = predicted
            return Step(predicted.copy(), self.state, score)
        self._off_m = 0.0
        if score < self.config.lost_score:
            self._low += 1
            if self._low >= self.config.lost_scans or self.state == "confirming":
                self._lose(scan.t)
                return Step(None, self.state, score)
            self.pose = predicted  # a poor match is not trusted: dead reckoning
            return Step(predicted.copy(), self.state, score)
        self._low = 0
        if score < self.config.trust_score and self._moves_far(predicted, pose):
            pose = predicted
        self.pose = pose
        if self.state == "confirming":
            self._confirmed += 1
            cfg = self.config
            if self._confirmed % cfg.confirm_scans == 0:
                second = self.globally.search_all(self._context(odom), cfg.confirm_min_score)
                # a pose held across a gap has no global search behind it yet: its
                # confirming search is its only evidence, and it is not tried again
                tries = cfg.confirm_tries if self._held_from is None else 1
                if self._agrees(second, pose):
                    self.state = "tracking"
                    if self._held_from is None:
                        self.fixes.append(scan.t)
                    self._held_from = None
                elif second.unique or self._confirmed >= cfg.confirm_scans * tries:
                    self._lose(scan.t)
                    return Step(None, self.state, score)
        return Step(pose.copy(), self.state, score)

    def _across_gap(self, t: float, xy: np.ndarray, prev_odom: np.ndarray, odom: np.ndarray,
                    wheels: np.ndarray) -> Step | None:
        """The first scan after a gap in the log: the robot may have been carried while
        nothing was logged, or the log only dropped records while it drove on. The
        wheels tell the second from the first: a robot carried off does not turn its
        wheels, and its scan does not fit where their odometry over the gap
        (``wheels``, the motion it read) puts it. Where it fits as a global fix must
        (``global_min_score``, ``min_on_map``; the refinement's window is step 3's),
        the pose is held and confirmed as a new fix is (step 2: ``confirm_scans`` scans
        on, a global search must find it), on the scans from before the gap too, joined
        to the new local map by the wheels (a carried robot's are joined wrongly, and
        the search finds another pose or none); it is a fix kept, not a new one. Else
        (None) the robot is lost, as after a kidnapping (step 4); so is a fix not yet
        confirmed. ``prev_odom`` and ``odom``: local SLAM's poses of the scans before
        and after the gap, each in its own local map."""
        if self.state != "tracking":
            return None
        assert self.pose is not None
        predicted = compose(self.pose, wheels)
        pose, score, share = self.fit(xy, predicted)
        cfg = self.config
        if (score < cfg.global_min_score or share < cfg.min_on_map
                or not _near(predicted, pose, cfg.track_window_m, cfg.track_window_rad)):
            return None
        self.pose, self._low, self._off_m, self._confirmed = pose, 0, 0.0, 0
        self.state, self._held_from = "confirming", t
        to_new = compose(odom, compose(invert(wheels), invert(prev_odom)))
        self._history = [(compose(to_new, o), h) for o, h in self._history]
        return Step(pose.copy(), self.state, score)

    def _moves_far(self, predicted: np.ndarray, pose: np.ndarray) -> bool:
        """Whether the map's answer moves the pose farther from local SLAM's prediction
        than one scan's motion estimate errs (``trust_m``, ``trust_rad``). Taken from a
        mediocre match, such a move is the scan's walls sliding along the map's (a
        corridor, a room the map saw only from afar), step by step away from where the
        robot is; local SLAM's prediction is the better answer (the gate of Hara et
        al. §6, eq. 5, with the map's match in the place of the scan matcher's)."""
        return not _near(predicted, pose, self.config.trust_m, self.config.trust_rad)

    def _agrees(self, second: GlobalAnswer, tracked: np.ndarray) -> bool:
        """Whether a second global search, on a later scan, finds the pose the first fix
        has been tracked to: two unique fixes, taken apart, agreeing through the
        odometry between them. One scan in a building of look-alike corridors can fit a
        wrong one uniquely enough when the map of the right one is a little off."""
        if second.best is None or not second.unique:
            return False
        return _near(tracked, second.best.pose, self.config.unique_m, self.config.confirm_rad)

    def _search(self, t: float, odom: np.ndarray, xy: np.ndarray) -> Step:
        cfg = self.config
        if self._searched is not None and t - self._searched < cfg.search_every_s:
            return Step(None, "searching", 0.0)
        if self._searched_at is not None:
            d = relative(self._searched_at, odom)
            moved = float(np.hypot(d[0], d[1]))
            need = (cfg.search_moved_m if self._lost_m < cfg.context_m
                    else cfg.search_moved_full_m)
            if moved < need and abs(d[2]) < cfg.search_moved_rad:
                return Step(None, "searching", 0.0)
            self._lost_m += moved
        self._searched, self._searched_at = t, odom.copy()
        m = self.globally.fix(self._context(odom))
        if m is None:
            return Step(None, "searching", 0.0)
        pose, score, share = self.fit(xy, m.pose)
        if score < self.config.lost_score or share < self.config.min_on_map:
            return Step(None, "searching", score)
        self.pose, self._low, self._confirmed = pose, 0, 0
        self.state = "confirming"
        return Step(pose.copy(), self.state, score)

    def fit(self, xy: np.ndarray, predicted: np.ndarray) -> tuple[np.ndarray, float, float]:
        """The refined pose, its score over the points on observed cells, and the share
        of the points on observed cells."""
        cfg = self.config
        pts = adaptive_voxel(xy, cfg.track_points, cfg.resolution_m) if len(xy) else xy
        if len(pts) < 8:
            return predicted, 0.0, 0.0
        r = refine(self.grid, pts, predicted)
        pose = r.pose
        if self._map.on_map(pts, pose)[0] < cfg.track_min_score:
            start, _ = correlative_search(self.grid, pts, predicted, cfg.track_window_m,
                                          cfg.track_window_rad)
            r2 = refine(self.grid, pts, start, prior=start)
            if r2.score > r.score:
                pose = r2.pose
        s, share = self._map.on_map(pts, pose)
        if s >= cfg.lost_score and share >= cfg.min_on_map:
            pose = self._align_to_keyframes(xy, pose)
        return pose, s, share

    def _align_to_keyframes(self, xy: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Step 3's last part: point-to-line ICP of the scan against the returns of the
        ``icp_keyframes`` nearest keyframes, as the map placed them -- the grid holds the
        walls to a cell, the keyframes' own points finer."""
        ref = self._clouds.around(pose)
        if ref is None:
            return pose
        r = intensity_icp(ref, xy, None, pose, self._icp)
        shift = np.hypot(*(r.pose[:2] - pose[:2]))
        if (not r.converged or r.inliers < 0.5 * len(xy)
                or shift > self.config.icp_max_shift_m):
            return pose
        return np.asarray(r.pose)

    def _remember(self, odom: np.ndarray, xy: np.ndarray) -> None:
        """Keep the scans of the last ``context_m`` of travel (odometry) for the global
        search."""
        h = self._history
        if h and np.hypot(*(odom[:2] - h[-1][0][:2])) < 0.5 * self.config.resolution_m \
                and abs(relative(h[-1][0], odom)[2]) < 0.01:
            h[-1] = (odom.copy(), xy)  # standing still: the newest scan says it all
        else:
            h.append((odom.copy(), xy))
        path = 0.0
        for k in range(len(h) - 1, 0, -1):
            path += float(np.hypot(*(h[k][0][:2] - h[k - 1][0][:2])))
            if path > self.config.context_m:
                del h[:k]
                break

    def _context(self, odom: np.ndarray) -> np.ndarray:
        """The remembered scans' returns in the frame of the robot at ``odom``: one scan
        of a corridor fits many corridors; the last few metres of it, far fewer."""
        parts = [place(xy, relative(odom, o)) for o, xy in self._history]
        return np.vstack(parts) if parts else np.zeros((0, 2))

    def _lose(self, t: float) -> None:
        # what was seen before the robot was carried off is not where it is now
        self._history.clear()
        self._searched_at = None  # the next search need not wait for the robot to move
        self._lost_m = 0.0
        if self.state == "tracking" or self._held_from is not None:
            self.losses.append(t if self._held_from is None else self._held_from)
        self.state, self.pose, self._low, self._confirmed = "searching", None, 0, 0
        self._held_from = None
        self._off_m = 0.0


@dataclass
class LocalizationRun:
    """A log localized on a map: per scan its stamp, pose (NaN where not placed, see
    :attr:`placed`) and online state; the stamps of the fixes and losses; seconds taken."""

    times: np.ndarray
    poses: np.ndarray
    states: list[State]
    fixes: list[float]
    losses: list[float]
    seconds: float

    @property
    def localized(self) -> np.ndarray:
        """Per scan: the localizer was tracking it online."""
        return np.asarray([s == "tracking" for s in self.states])

    @property
    def placed(self) -> np.ndarray:
        """Per scan: it has a pose after step 5 (tracked, or bridged between tracked
        scans without a gap in the log)."""
        return np.asarray(np.all(np.isfinite(self.poses), axis=1))

    def first_fix_s(self) -> float | None:
        """Log time from the first scan to the first fix (None: never)."""
        return None if not self.fixes else float(self.fixes[0] - self.times[0])


def localize_log(saved: SavedMap, log: LaserLog,
                 config: MapLocalizationConfig | None = None) -> LocalizationRun:
    """Localize every scan of ``log`` on ``saved``; raises
    :class:`~chizu.numeric.errors.InvalidInput` (field ``map``) when the log's laser is not
    the map's."""
    loc = MapLocalizer(saved, config or MapLocalizationConfig())
    why = loc.check_laser(Laser.of(log))
    if why is not None:
        raise InvalidInput(why, field="map")
    t0 = time.perf_counter()
    poses = np.full((len(log), 3), np.nan)
    odometry = np.empty((len(log), 3))
    states: list[State] = []
    for i, scan in enumerate(log.scans):
        step = loc.process(scan)
        if step.pose is not None and step.state == "tracking":
            poses[i] = step.pose
        assert loc.odom is not None
        odometry[i] = loc.odom
        states.append(step.state)
    c = loc.config
    gaps = np.flatnonzero(np.diff(log.times) > c.gap_s) + 1
    poses = bridged(poses, odometry, gaps, c)
    pts = [voxel_downsample(s.points()[0], None, 0.05)[0] for s in log.scans]
    poses = align_on_map(saved, pts, odometry, poses, ON_MAP_ALIGNMENT, c.icp_keyframes,
                         c.icp_radius_m, starts=gaps)
    return LocalizationRun(log.times, poses, states, loc.fixes, loc.losses,
                           time.perf_counter() - t0)


def bridged(poses: np.ndarray, odometry: np.ndarray, starts: np.ndarray,
            config: MapLocalizationConfig) -> np.ndarray:
    """Step 5's start, in each part of the log between ``starts`` (the first scans after
    gaps in the log: a robot carried away is not bridged) on its own:

    - The tracked stretches (runs of placed scans) must agree with local SLAM's path
      (``odometry``) between them, as closely as its drift allows (``bridge_*``).
      Starting from the longest, each next stretch on either side that does not is
      dropped (its scans unplaced): it was a fix in a look-alike corridor of the map
      while the robot was in a part the map never saw, metres and radians off where the
      path puts it.
    - The scans between two kept stretches follow the path dead-reckoned from both ends
      and blended by the share of the way travelled, so that it meets both; before the
      first kept stretch and after the last, it runs from the one end it has.

    The alignment then places these scans finer by their matches to their neighbours in
    time, as a SLAM run's scans are placed between its loop closures."""
    out = np.full_like(poses, np.nan)
    for lo, hi in zip(np.concatenate([[0], starts]), np.concatenate([starts, [len(poses)]]),
                      strict=True):
        stretches = [(a + lo, b + lo) for a, b in placed_runs(poses[lo:hi])]
        if not stretches:
            continue
        best = max(range(len(stretches)), key=lambda k: stretches[k][1] - stretches[k][0])
        kept = [stretches[best]]
        for k in range(best + 1, len(stretches)):  # onwards from the longest
            a, b = kept[-1][1] - 1, stretches[k][0]
            if _meets(poses[a], poses[b], odometry[a:b + 1], config):
                kept.append(stretches[k])
        for k in range(best - 1, -1, -1):  # and back
            a, b = stretches[k][1] - 1, kept[0][0]
            if _meets(poses[a], poses[b], odometry[a:b + 1], config):
                kept.insert(0, stretches[k])
        for (_, a), (b, _) in pairwise(kept):
            out[a - 1:b + 1] = _blend(poses[a - 1], poses[b], odometry[a - 1:b + 1])
        for a, b in kept:
            out[a:b] = poses[a:b]
        first, last = kept[0][0], kept[-1][1] - 1
        out[lo:first] = compose(poses[first], relative(odometry[first], odometry[lo:first]))
        out[last + 1:hi] = compose(poses[last], relative(odometry[last],
                                                         odometry[last + 1:hi]))
    return out


def placed_runs(poses: np.ndarray) -> list[tuple[int, int]]:
    """The runs of rows of ``poses`` ``(n, 3)`` that are finite, as ``(first, past the
    last)``."""
    ok = np.all(np.isfinite(poses), axis=1).astype(int)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok, [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _meets(start: np.ndarray, end: np.ndarray, odometry: np.ndarray,
           config: MapLocalizationConfig) -> bool:
    """Whether the path ``odometry`` (``(n, 3)``) from ``start`` ends near ``end``."""
    misfit = relative(compose(start, relative(odometry[0], odometry[-1])), end)
    path = float(np.hypot(*np.diff(odometry[:, :2], axis=0).T).sum())
    return bool(np.hypot(misfit[0], misfit[1]) <= config.bridge_m + config.bridge_per_m * path
                and abs(misfit[2]) <= config.bridge_rad)


def _blend(start: np.ndarray, end: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """The poses along ``odometry`` (``(n, 3)``) from ``start`` to ``end``: dead
    reckoned forwards from ``start`` and backwards from ``end``, weighed by the share of
    the odometry's path travelled (by turning, where it does not move)."""
    fwd = compose(start, relative(odometry[0], odometry))
    back = compose(end, relative(odometry[-1], odometry))
    step = np.hypot(*np.diff(odometry[:, :2], axis=0).T)
    if step.sum() < 1e-6:
        step = np.abs(wrap_angle(np.diff(odometry[:, 2])))
    path = np.concatenate([[0.0], np.cumsum(step)])
    w = path / path[-1] if path[-1] > 0 else np.linspace(0.0, 1.0, len(odometry))
    xy = (1 - w)[:, None] * fwd[:, :2] + w[:, None] * back[:, :2]
    th = fwd[:, 2] + w * wrap_angle(back[:, 2] - fwd[:, 2])
    return np.column_stack([xy, wrap_angle(th)])


def align_on_map(saved: SavedMap, points: list[np.ndarray], odometry: np.ndarray,
                 poses: np.ndarray, config: AlignmentConfig, keyframes: int,
                 radius_m: float, starts: np.ndarray | None = None) -> np.ndarray:
    """Graph SLAM's global scan alignment (:mod:`chizu.numeric.slam.alignment`, Lu & Milios
    1997) of each stretch of placed scans (rows of ``poses`` that are finite; robot-frame
    ``points``, ``odometry`` per scan), with the saved map's keyframes among the scans
    and held where the map has them. Online, a scan is placed by matching it to the map
    alone; here each is also matched to its neighbours in time and to the keyframes it
    overlaps as the SLAM run's scans were, and to the returns of its ``keyframes``
    nearest keyframes within ``radius_m`` together (a pose in the map's frame, with the
    match's own covariance: what holds a stretch driven the other way, whose scans
    overlap no single keyframe), and all are solved for at once. A stretch also ends
    before each scan of ``starts`` (after a gap in the log, where the motion estimate
    starts again). Returns the poses."""
    out = poses.copy()
    cuts = np.asarray([] if starts is None else starts, dtype=np.int64)
    stretches = [(int(a), int(b)) for lo, hi in placed_runs(poses)
                 for a, b in pairwise([lo, *cuts[(cuts > lo) & (cuts < hi)], hi])]
    held = len(saved)
    clouds = KeyframeClouds(saved, keyframes, radius_m)
    for lo, hi in stretches:
        if hi - lo < 2:
            continue
        pts = points[lo:hi]
        allp = np.vstack([saved.kf_pose, poses[lo:hi]])
        # the keyframes are held: only the pairs with a scan among them are matched
        matches = pairwise_matches(saved.kf_xy + pts, [None] * (held + hi - lo), allp, config,
                                   first=held)
        priors = []
        for j, xy in enumerate(pts):
            ref = clouds.around(poses[lo + j])
            found = None if ref is None or len(xy) < 10 else match_pair(ref, xy, None,
                                                                        poses[lo + j], config)
            if found is not None:
                priors.append((held + j, found[0], found[1]))
        both = align_globally(allp, np.vstack([saved.kf_odom, odometry[lo:hi]]), matches,
                              [], config, held=held, priors=priors)
        out[lo:hi] = both[held:]
    return out


class KeyframeClouds:
    """The returns of the nearest keyframes around a pose, in the map's frame, as ICP
    references (the last one kept: consecutive scans share it)."""

    def __init__(self, saved: SavedMap, keyframes: int, radius_m: float) -> None:
        self.saved, self.keyframes, self.radius_m = saved, keyframes, radius_m
        # a lifelong run's map holds keyframes whose returns were forgotten
        self._empty = np.array([len(x) == 0 for x in saved.kf_xy], dtype=bool)
        self._key: tuple[int, ...] | None = None
        self._ref: Reference | None = None

    def around(self, pose: np.ndarray) -> Reference | None:
        s = self.saved
        if self.keyframes == 0 or len(s) == 0:
            return None
        d = np.hypot(*(s.kf_pose[:, :2] - pose[:2]).T)
        d[self._empty] = np.inf
        near = tuple(sorted(int(k) for k in np.argsort(d)[:self.keyframes]
                            if d[k] <= self.radius_m))
        if not near:
            return None
        if near != self._key:
            pts = np.vstack([place(s.kf_xy[k], s.kf_pose[k]) for k in near])
            self._key, self._ref = near, Reference(voxel_downsample(pts, None, 0.03)[0],
                                                   None, 0.0)
        return self._ref
