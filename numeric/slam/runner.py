"""One entry point for the methods (odometry, Intensity-ICP, gated and RBPF from the
paper; graph SLAM beyond it): options, a factory, and a run over a whole log with the
outputs the CLI and the service write."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from numeric.errors import InvalidInput
from numeric.occupancy import OccupancyMap, build_occupancy
from numeric.scan import LaserLog, Scan
from numeric.slam.gated import SingleHypothesisSlam
from numeric.slam.graph import GraphSlam, GraphSlamConfig
from numeric.slam.intensity_icp import IcpConfig
from numeric.slam.keyframes import Keyframes
from numeric.slam.rbpf import RbpfConfig, RbpfSlam

Method = Literal["odom", "icp", "gated", "rbpf", "graph"]


class SlamOptions(BaseModel):
    """What a SLAM run is asked to do (CLI flags and the REST body share it)."""

    model_config = ConfigDict(extra="forbid")
    method: Method = "rbpf"
    particles: int = Field(512, ge=1, le=4096)
    alpha: float = Field(0.0, ge=0, le=1.0, allow_inf_nan=False,
                         description="intensity weight of eqs. 1 and 9 (m² per unit²)")
    proposal: Literal["improved", "odometry", "gated-icp"] = Field(
        "improved", description="rbpf: improved (Grisetti et al. 2007, scan-matched Gaussian "
        "per particle), odometry (the paper's eq. 7) or gated-icp")
    resample: Literal["always", "ess"] = "ess"
    sigma_z: float = Field(0.0005, gt=0, le=10, allow_inf_nan=False)
    map_resolution_m: float = Field(0.05, ge=0.01, le=1.0, allow_inf_nan=False)
    seed: int = Field(0, ge=0, le=2**32 - 1)


class Slam(Protocol):
    keyframes: Keyframes

    def process(self, scan: Scan) -> object: ...
    def trajectory(self) -> tuple[np.ndarray, np.ndarray]: ...
    def map_poses(self) -> np.ndarray: ...
    @property
    def pose(self) -> np.ndarray: ...


def create(options: SlamOptions) -> Slam:
    """A fresh estimator for ``options.method``."""
    icp = IcpConfig(alpha=options.alpha)
    if options.method == "graph":
        return GraphSlam(GraphSlamConfig(alpha=options.alpha), seed=options.seed)
    if options.method == "rbpf":
        return RbpfSlam(RbpfConfig(particles=options.particles, alpha=options.alpha,
                                   proposal=options.proposal, resample=options.resample,
                                   sigma_z=options.sigma_z, icp=icp, seed=options.seed))
    return SingleHypothesisSlam(method=options.method, icp=icp)


@dataclass
class SlamResult:
    times: np.ndarray
    poses: np.ndarray
    map: OccupancyMap
    seconds: float


def run_log(log: LaserLog, options: SlamOptions,
            progress: Callable[[int], None] | None = None) -> tuple[Slam, SlamResult]:
    """Run ``options.method`` over every scan of ``log``; ``progress(i)`` after each."""
    import time

    slam = create(options)
    t0 = time.perf_counter()
    for i, scan in enumerate(log.scans):
        slam.process(scan)
        if progress is not None:
            progress(i + 1)
    finish = getattr(slam, "finish", None)
    if finish is not None:  # graph SLAM's global scan alignment, once the log is over
        finish()
    seconds = time.perf_counter() - t0
    times, poses = slam.trajectory()
    return slam, SlamResult(times, poses, whole_map(slam, options.map_resolution_m), seconds)


def whole_map(slam: Slam, resolution_m: float) -> OccupancyMap:
    """The run's map at ``resolution_m``, or at the finest doubling of it that fits the
    grid size limit (a hospital floor at 5 cm does not): a long run is never lost to
    its map."""
    poses = slam.map_poses()
    for _ in range(6):
        try:
            return build_occupancy(slam.keyframes.frames, poses, resolution_m)
        except InvalidInput as e:
            if e.field != "resolution_m":
                raise
            resolution_m *= 2
    return build_occupancy(slam.keyframes.frames, poses, resolution_m)
