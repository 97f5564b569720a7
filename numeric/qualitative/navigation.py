"""Step 4 of the paper (§6) in the simulator: executing a DRM path, and the
quantitative baseline the paper's §7 asks to compare against.

Qualitative execution steers only by what the robot sees now (bearing and
recognition of landmarks), one method per DRM arc:

- ``move1``: home on the target's bearing until it is within the arrival radius;
- ``move2``: head between the two via landmarks (circular mean of their
  bearings) until the target is recognised, then home on it;
- ``move3``: home on the via landmark, then home on the target;
- ``retrace``: home on the target (the route back is known to be free).

The quantitative baseline estimates landmark coordinates from the same noisy
bearings and distances (nonlinear least squares, scipy), plans the shortest
route over co-observed pairs (networkx) and drives straight legs by odometry
between estimated positions, re-localising its heading at each landmark.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import networkx as nx
import numpy as np
from pydantic import BaseModel, Field
from scipy.optimize import least_squares

from chizu.numeric.geometry import circular_mean, wrap_angle
from chizu.numeric.observation import Observation
from chizu.numeric.qualitative.drm import DrmEdge
from chizu.numeric.simulator import LandmarkObserver, Robot


class NavConfig(BaseModel):
    step_m: float = Field(0.25, gt=0)
    arrival_radius_m: float = Field(0.6, gt=0)
    max_steps_per_leg: int = Field(400, gt=0)


@dataclass
class NavResult:
    success: bool
    travelled_m: float
    failed_step: int | None = None
    reason: str = ""


def _arrived(robot: Robot, observer: LandmarkObserver, target: str, cfg: NavConfig) -> bool:
    true_d = np.linalg.norm(robot.pose[:2] - observer.world.landmark_position(target))
    return bool(true_d <= cfg.arrival_radius_m)


def home_on(robot: Robot, observer: LandmarkObserver, target: str, cfg: NavConfig) -> bool:
    """move1: steer by the target's measured bearing until the measured range is short."""
    for _ in range(cfg.max_steps_per_leg):
        m = observer.measure(robot.pose, target)
        if m is None:
            return False
        b, d = m
        if d <= cfg.arrival_radius_m * 0.5:
            return _arrived(robot, observer, target, cfg)
        robot.turn(b)
        if not robot.forward(min(cfg.step_m, max(d - cfg.arrival_radius_m * 0.25, 0.05))):
            return False
    return False


def pass_between(robot: Robot, observer: LandmarkObserver, via: Sequence[str], target: str,
                 cfg: NavConfig, between_rad: float = np.deg2rad(150)) -> bool:
    """move2: head for the gap between the two via landmarks (the circular mean of their
    bearings) until they are seen on opposite sides (angle > ``between_rad``), then keep
    straight on; as soon as the target is recognised, home on it."""
    heading_locked: float | None = None
    for _ in range(cfg.max_steps_per_leg):
        if observer.measure(robot.pose, target) is not None:
            return home_on(robot, observer, target, cfg)
        if heading_locked is None:
            ms = [observer.measure(robot.pose, v) for v in via]
            if any(m is None for m in ms):
                return False
            bs = [m[0] for m in ms if m is not None]
            if abs(float(wrap_angle(bs[0] - bs[1]))) >= between_rad:
                heading_locked = float(robot.odom_pose[2])  # in the gap: straight on
                turn = 0.0
            else:
                turn = circular_mean(bs)
        else:
            turn = float(wrap_angle(heading_locked - robot.odom_pose[2]))
        robot.turn(turn)
        if not robot.forward(cfg.step_m):
            return False
    return False


def reach_any_landmark(robot: Robot, observer: LandmarkObserver, cfg: NavConfig,
                       rng: np.random.Generator, max_steps: int = 2000) -> str | None:
    """From an unknown pose, reach some landmark first (paper §6).

    Look around; if a landmark is recognised, home on the nearest one.  If
    none is, wander: drive straight, and turn a random angle on bumping into a
    wall.  Returns the landmark reached, or None.
    """
    for _ in range(max_steps):
        xy = robot.pose[:2]
        visible = observer.visible(xy)
        if len(visible):
            ids = [observer.world.landmark_ids[i] for i in visible]
            dists = [m[1] for m in (observer.measure(robot.pose, i) for i in ids)
                     if m is not None]
            nearest = ids[int(np.argmin(dists))]
            if home_on(robot, observer, nearest, cfg):
                return nearest
            robot.collided = False
        if not robot.forward(cfg.step_m):
            robot.collided = False
            robot.turn(float(rng.uniform(np.pi / 2, 3 * np.pi / 2)))
    return None


def execute_step(robot: Robot, observer: LandmarkObserver, step: DrmEdge,
                 cfg: NavConfig) -> bool:
    if step.method == "move2":
        return pass_between(robot, observer, step.via, step.target, cfg)
    if step.method == "move3":
        return (home_on(robot, observer, step.via[0], cfg)
                and home_on(robot, observer, step.target, cfg))
    return home_on(robot, observer, step.target, cfg)  # move1, retrace


def execute_drm_path(robot: Robot, observer: LandmarkObserver, steps: Sequence[DrmEdge],
                     cfg: NavConfig) -> NavResult:
    """Run the methods of a DRM path one after another (paper §6)."""
    start = robot.travelled_m
    for i, s in enumerate(steps):
        if not execute_step(robot, observer, s, cfg):
            reason = "collision" if robot.collided else f"{s.method} to {s.target} failed"
            return NavResult(False, robot.travelled_m - start, i, reason)
    return NavResult(True, robot.travelled_m - start)


# -- quantitative baseline ---------------------------------------------------------------

def map_heading(at: str, obs: Observation, pos: dict[str, np.ndarray]) -> float | None:
    """Robot heading in the map frame, standing at ``at``: the circular mean of
    (map direction to each seen landmark) - (its observed bearing); None if no
    seen landmark is in ``pos``."""
    hs = [float(np.arctan2(*(pos[s.landmark] - pos[at])[::-1]) - s.bearing_rad)
          for s in obs.seen if s.landmark in pos and s.landmark != at]
    return circular_mean(hs) if hs else None


def estimate_landmark_positions(observations: Sequence[Observation],
                                bearing_sigma: float, distance_sigma: float
                                ) -> dict[str, np.ndarray]:
    """Least-squares landmark map from panoramic range-bearing observations.

    Unknowns: (x, y) of every landmark and the heading of every station; the
    first station is fixed at the origin with heading 0 (gauge).  Residuals
    are bearing and range errors divided by their sigmas.
    """
    stations = [o for o in observations if o.seen]
    if not stations:
        return {}
    g = nx.Graph()
    for o in stations:
        for s in o.seen:
            g.add_edge(o.at, s.landmark)
    root = stations[0].at
    comp = nx.node_connected_component(g, root)
    stations = [o for o in stations if o.at in comp]
    ids = sorted(comp)
    idx = {k: i for i, k in enumerate(ids)}
    # initial guess by chaining relative vectors breadth-first
    pos = {root: np.zeros(2)}
    head = {root: 0.0}
    by_at = {o.at: o for o in stations}
    for a, b in nx.bfs_edges(g, root):
        if a in by_at and a in head:
            for s in by_at[a].seen:
                if s.landmark == b:
                    ang = head[a] + s.bearing_rad
                    pos[b] = pos[a] + s.distance_m * np.array([np.cos(ang), np.sin(ang)])
        elif b in by_at:
            pos.setdefault(b, pos[a])
        if b in by_at and b not in head:
            head[b] = map_heading(b, by_at[b], pos) or 0.0
    st_idx = {o.at: i for i, o in enumerate(stations)}
    x0 = np.concatenate([np.concatenate([pos.get(k, np.zeros(2)) for k in ids]),
                         np.array([head.get(o.at, 0.0) for o in stations])])
    n = len(ids)
    rows = [(st_idx[o.at], idx[o.at], idx[s.landmark], s.bearing_rad, s.distance_m)
            for o in stations for s in o.seen]
    si, ai, bi, bz, dz = (np.array(c) for c in zip(*rows, strict=True))
    r0 = idx[root]

    def residuals(x: np.ndarray) -> np.ndarray:
        p = x[:2 * n].reshape(n, 2)
        h = x[2 * n:]
        d = p[bi] - p[ai]
        pb = np.arctan2(d[:, 1], d[:, 0]) - h[si]
        rb = wrap_angle(pb - bz) / max(bearing_sigma, 1e-3)
        rd = (np.hypot(d[:, 0], d[:, 1]) - dz) / max(distance_sigma, 1e-3)
        gauge = np.concatenate([p[r0] * 1e3, [h[st_idx[root]] * 1e3]])
        return np.concatenate([rb, rd, gauge])

    sol = least_squares(residuals, x0, method="trf", loss="soft_l1", max_nfev=200)
    p = sol.x[:2 * n].reshape(n, 2)
    return {k: p[i] for k, i in idx.items()}


def quantitative_route(observations: Sequence[Observation], est: dict[str, np.ndarray],
                       source: str, target: str) -> list[str] | None:
    """Shortest route (estimated metres) over pairs that were seen from one another."""
    g = nx.Graph()
    for o in observations:
        for s in o.seen:
            if o.at in est and s.landmark in est:
                g.add_edge(o.at, s.landmark,
                           w=float(np.linalg.norm(est[o.at] - est[s.landmark])))
    try:
        return list(nx.dijkstra_path(g, source, target, weight="w"))
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        return None


def execute_quantitative(robot: Robot, observer: LandmarkObserver, route: Sequence[str],
                         est: dict[str, np.ndarray], cfg: NavConfig) -> NavResult:
    """Drive straight legs by odometry between estimated positions.

    At each landmark the robot knows where it is (it recognises the landmark)
    and estimates its map heading from the bearings of visible landmarks.
    """
    start = robot.travelled_m
    for i, (a, b) in enumerate(zip(route, route[1:], strict=False)):
        heading = map_heading(a, observer.observe(robot.pose, at=a), est)
        if heading is None:
            return NavResult(False, robot.travelled_m - start, i, "lost: no landmark in view")
        delta = est[b] - est[a]
        robot.turn(float(wrap_angle(np.arctan2(delta[1], delta[0]) - heading)))
        dist = float(np.linalg.norm(delta))
        while dist > 1e-9:
            leg = min(cfg.step_m, dist)
            if not robot.forward(leg):
                return NavResult(False, robot.travelled_m - start, i, "collision")
            dist -= leg
        if not _arrived(robot, observer, b, cfg):
            return NavResult(False, robot.travelled_m - start, i, f"missed {b}")
    return NavResult(True, robot.travelled_m - start)


def localise(observer: LandmarkObserver, pose: np.ndarray, est: dict[str, np.ndarray],
             guess: np.ndarray, bearing_sigma: float, distance_sigma: float) -> np.ndarray:
    """Pose (x, y, theta) in the estimated map from the landmarks in view (least squares);
    the odometry-predicted ``guess`` if none of the mapped landmarks is in view."""
    seen = [(est[lid], b, d) for lid, b, d in observer.scan(pose) if lid in est]
    if not seen:
        return guess
    xy = np.array([s[0] for s in seen])
    bz = np.array([s[1] for s in seen])
    dz = np.array([s[2] for s in seen])

    def residuals(x: np.ndarray) -> np.ndarray:
        d = xy - x[:2]
        rb = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - x[2] - bz) / max(bearing_sigma, 1e-3)
        rd = (np.hypot(d[:, 0], d[:, 1]) - dz) / max(distance_sigma, 1e-2)
        return np.concatenate([rb, rd])

    sol = least_squares(residuals, guess, method="lm" if 2 * len(seen) >= 3 else "trf")
    out = sol.x.copy()
    out[2] = float(wrap_angle(out[2]))
    return out


def execute_quantitative_tracked(robot: Robot, observer: LandmarkObserver,
                                 route: Sequence[str], est: dict[str, np.ndarray],
                                 cfg: NavConfig, bearing_sigma: float,
                                 distance_sigma: float) -> NavResult:
    """Metric baseline with continuous localisation: at every step the robot fixes its
    pose in the estimated map from the landmarks in view, then steers straight for the
    next waypoint's estimated position."""
    start = robot.travelled_m
    pose_est = localise(observer, robot.pose, est, np.array([*est[route[0]], 0.0]),
                        bearing_sigma, distance_sigma)
    for i, b in enumerate(route[1:]):
        for _ in range(cfg.max_steps_per_leg):
            delta = est[b] - pose_est[:2]
            dist = float(np.hypot(*delta))
            if dist <= cfg.arrival_radius_m * 0.5:
                break
            turn = float(wrap_angle(np.arctan2(delta[1], delta[0]) - pose_est[2]))
            robot.turn(turn)
            step = min(cfg.step_m, dist)
            if not robot.forward(step):
                return NavResult(False, robot.travelled_m - start, i, "collision")
            h = pose_est[2] + turn
            guess = np.array([pose_est[0] + step * np.cos(h), pose_est[1] + step * np.sin(h), h])
            pose_est = localise(observer, robot.pose, est, guess, bearing_sigma, distance_sigma)
        if not _arrived(robot, observer, b, cfg):
            return NavResult(False, robot.travelled_m - start, i, f"missed {b}")
    return NavResult(True, robot.travelled_m - start)
