"""Single-hypothesis SLAM (§6) as the paper builds it: odometry alone, Intensity-ICP
alone, and Intensity-ICP gated by the odometry motion model of eq. 5 (``gated-icp``).
The method ``gated`` is the same single hypothesis with the RBPF's scan matcher as its
front end (:meth:`chizu.numeric.slam.rbpf.RbpfConfig.single_hypothesis`); this module keeps
eq. 5's gate for both.

Every scan gets a pose. A scan is matched when the odometry says the robot moved at
least ``update_linear_m`` / ``update_angular_rad`` since the last matched scan; in
between, poses follow odometry from the last matched pose. The reference is the
previous matched scan plus the keyframes selected by :meth:`Keyframes.select` (§4).

Eq. 5 (gated-icp): the Intensity-ICP pose x̂_t is accepted only if it lies in the box
``x_{t-1} + R_{t-1}(u_t ± ε)`` -- in the frame of x_{t-1}, each component of the
matched increment differs from the odometry increment u_t by at most ε -- else the
odometry prediction is kept. ε grows with the motion (``eps_*_ratio``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from chizu.numeric.geometry import compose, place, relative, wrap_angle
from chizu.numeric.scan import Scan
from chizu.numeric.slam.keyframes import Keyframes, MapConfig, moved
from chizu.numeric.slam.matching.intensity_icp import IcpConfig, IcpResult, Reference, intensity_icp

SingleMethod = Literal["odom", "icp", "gated-icp"]


class GateConfig(BaseModel):
    """The odometry tolerance ε of eq. 5 (per component, growing with the motion)."""

    eps_xy_m: float = Field(0.05, ge=0)
    eps_xy_ratio: float = Field(0.3, ge=0, description="extra ε per metre travelled")
    eps_theta_rad: float = Field(0.05, ge=0)
    eps_theta_ratio: float = Field(0.3, ge=0, description="extra ε per radian turned")

    def box(self, u: np.ndarray) -> np.ndarray:
        """ε (3,) for the odometry increment ``u``."""
        d = float(np.hypot(u[0], u[1]))
        exy = self.eps_xy_m + self.eps_xy_ratio * d
        return np.array([exy, exy, self.eps_theta_rad + self.eps_theta_ratio * abs(u[2])])


def inside_gate(prev: np.ndarray, matched: np.ndarray, u: np.ndarray, gate: GateConfig) -> bool:
    """Eq. 5: is the matched pose inside ``prev + R(u ± ε)``?"""
    inc = relative(prev, matched)
    diff = np.array([inc[0] - u[0], inc[1] - u[1], float(wrap_angle(inc[2] - u[2]))])
    return bool(np.all(np.abs(diff) <= gate.box(u)))


@dataclass
class StepInfo:
    """What happened to one scan: ``matched`` (ICP ran), ``accepted`` (its pose used)."""

    matched: bool = False
    accepted: bool = False
    icp: IcpResult | None = None


@dataclass
class SingleHypothesisSlam:
    """``method`` = "odom", "icp" or "gated-icp" (eq. 5); feed scans with :meth:`process`."""

    method: SingleMethod = "gated-icp"
    icp: IcpConfig = field(default_factory=IcpConfig)
    map: MapConfig = field(default_factory=MapConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    keyframes: Keyframes = field(init=False)
    kf_poses: list[np.ndarray] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    matched: int = 0
    accepted: int = 0
    _anchor_pose: np.ndarray | None = None
    _anchor_odom: np.ndarray | None = None
    _prev: tuple[np.ndarray, np.ndarray | None] | None = None

    def __post_init__(self) -> None:
        if self.method not in ("odom", "icp", "gated-icp"):
            raise ValueError(f"unknown single-hypothesis method {self.method!r}")
        self.keyframes = Keyframes(self.map)

    @property
    def pose(self) -> np.ndarray:
        return self.poses[-1] if self.poses else np.zeros(3)

    def process(self, scan: Scan) -> StepInfo:
        xy, inten = scan.points()
        info = StepInfo()
        if self._anchor_pose is None or self._anchor_odom is None:
            pose = scan.odom.copy()
            self._set_anchor(pose, scan, xy, inten)
            self._add_keyframe(len(self.poses), pose, xy, inten)
            self._record(scan.t, pose)
            return info
        u = relative(self._anchor_odom, scan.odom)
        predicted = compose(self._anchor_pose, u)
        due = moved(self._anchor_odom, scan.odom, self.map.update_linear_m,
                    self.map.update_angular_rad)
        if not due:
            self._record(scan.t, predicted)
            return info
        pose = predicted
        if self.method != "odom" and len(xy) >= self.icp.min_inliers:
            res = self._match(predicted, xy, inten)
            info.matched, info.icp = True, res
            self.matched += 1
            if res.usable(len(xy), self.icp) and (self.method == "icp"
                         or inside_gate(self._anchor_pose, res.pose, u, self.gate)):
                pose = res.pose
                info.accepted = True
                self.accepted += 1
        self._set_anchor(pose, scan, xy, inten)
        last_kf = self.kf_poses[-1]
        if moved(last_kf, pose, self.map.keyframe_linear_m, self.map.keyframe_angular_rad):
            self._add_keyframe(len(self.poses), pose, xy, inten)
        self._record(scan.t, pose)
        return info

    def _match(self, predicted: np.ndarray, xy: np.ndarray,
               inten: np.ndarray | None) -> IcpResult:
        kf_xy = np.array(self.kf_poses)[:, :2]
        chosen = self.keyframes.select(predicted, kf_xy)
        assert self._prev is not None
        ref_xy, ref_i = self.keyframes.reference(chosen, self.kf_poses,  # type: ignore[arg-type]
                                                 extra=self._prev)
        return intensity_icp(Reference(ref_xy, ref_i, self.icp.alpha), xy, inten, predicted,
                             self.icp)

    def _set_anchor(self, pose: np.ndarray, scan: Scan, xy: np.ndarray,
                    inten: np.ndarray | None) -> None:
        self._anchor_pose, self._anchor_odom = pose.copy(), scan.odom.copy()
        self._prev = (place(xy, pose), inten)

    def _add_keyframe(self, index: int, pose: np.ndarray, xy: np.ndarray,
                      inten: np.ndarray | None) -> None:
        self.keyframes.add(index, xy, inten)
        self.kf_poses.append(pose.copy())

    def _record(self, t: float, pose: np.ndarray) -> None:
        self.times.append(t)
        self.poses.append(pose.copy())

    def finish(self) -> int:
        """The end of a run: nothing to do (graph SLAM aligns its scans here)."""
        return 0

    @property
    def aligned(self) -> bool:
        return False

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.times), np.array(self.poses).reshape(-1, 3)

    def map_poses(self) -> np.ndarray:
        """Poses ``(K, 3)`` of the keyframes (the map is the keyframes placed there)."""
        return np.array(self.kf_poses).reshape(-1, 3)
