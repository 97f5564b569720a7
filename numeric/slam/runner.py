"""One entry point for the methods (odometry, Intensity-ICP, gated SLAM and RBPF from
the paper; graph SLAM beyond it): options, a factory, and a run over a whole log with the
outputs the CLI and the service write."""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.occupancy import OccupancyMap, build_occupancy_fitting
from chizu.numeric.scan import LaserLog, Scan
from chizu.numeric.slam.gated import SingleHypothesisSlam
from chizu.numeric.slam.graph import GraphSlam, GraphSlamConfig
from chizu.numeric.slam.keyframes import Keyframes
from chizu.numeric.slam.matching.intensity_icp import IcpConfig
from chizu.numeric.slam.rbpf import Proposal, RbpfConfig, RbpfSlam, Resample
from chizu.numeric.slam.simulate import simulated_log

Method = Literal["odom", "icp", "gated-icp", "gated", "rbpf", "graph"]


def _field(model: type[BaseModel], name: str) -> Any:
    """A copy of ``model``'s declaration of field ``name`` (type bounds, default,
    description): the options below take each estimator parameter's bounds from the
    estimator's own config, so they are declared once."""
    return copy.copy(model.model_fields[name])


class SlamOptions(BaseModel):
    """What a SLAM run is asked to do (CLI flags and the REST body share it); the
    estimator parameters carry the bounds of :class:`RbpfConfig`."""

    model_config = ConfigDict(extra="forbid")
    method: Method = Field("graph", description="graph SLAM (the recommended method), "
                           "the RBPF of the paper with Grisetti et al.'s proposal (rbpf), "
                           "the paper's gated single-hypothesis SLAM with the RBPF's scan "
                           "matcher (gated) or with Intensity-ICP as in the paper "
                           "(gated-icp), icp or odom")
    particles: int = _field(RbpfConfig, "particles")
    alpha: float = _field(RbpfConfig, "alpha")
    proposal: Proposal = _field(RbpfConfig, "proposal")
    resample: Resample = _field(RbpfConfig, "resample")
    sigma_z: float = _field(RbpfConfig, "sigma_z")
    map_resolution_m: float = Field(0.05, ge=0.01, le=1.0, allow_inf_nan=False)
    seed: int = _field(RbpfConfig, "seed")

    def to_config(self) -> RbpfConfig | GraphSlamConfig | IcpConfig:
        """The estimator's config: RBPF's (also the gated single hypothesis's), graph
        SLAM's, or the Intensity-ICP config of the paper's single-hypothesis methods."""
        icp = IcpConfig(alpha=self.alpha)
        if self.method == "graph":
            return GraphSlamConfig(alpha=self.alpha)
        if self.method == "gated":
            return RbpfConfig.single_hypothesis(alpha=self.alpha, seed=self.seed)
        if self.method == "rbpf":
            return RbpfConfig(particles=self.particles, alpha=self.alpha,
                              proposal=self.proposal, resample=self.resample,
                              sigma_z=self.sigma_z, icp=icp, seed=self.seed)
        return icp


class Slam(Protocol):
    """What every estimator offers. ``finish()`` ends a run: graph SLAM's global scan
    alignment, and the improved RBPF's (its best particle's trajectory); the paper's
    filters have nothing to do there. ``aligned``: whether the outputs
    are finish()'s (until the next scan)."""

    keyframes: Keyframes

    def process(self, scan: Scan) -> object: ...
    def finish(self) -> int: ...
    @property
    def aligned(self) -> bool: ...
    def trajectory(self) -> tuple[np.ndarray, np.ndarray]: ...
    def map_poses(self) -> np.ndarray: ...
    @property
    def pose(self) -> np.ndarray: ...


def create(options: SlamOptions) -> Slam:
    """A fresh estimator for ``options.method``."""
    cfg = options.to_config()
    if isinstance(cfg, GraphSlamConfig):
        return GraphSlam(cfg, seed=options.seed)
    if isinstance(cfg, RbpfConfig):
        return RbpfSlam(cfg)
    assert options.method in ("odom", "icp", "gated-icp")
    return SingleHypothesisSlam(method=options.method, icp=cfg)


_WARM: set[tuple[str, str]] = set()
_WARM_LOCK = threading.Lock()
#: scans of the warm-up tour per method (None: all of it): graph SLAM's whole tour
#: reaches its first finished submap's searches; the RBPF's first 60 scans hold
#: tracking, updates and new keyframes (the whole tour would take 5 s with its
#: per-update searches)
_WARM_SCANS: dict[str, int | None] = {"graph": None, "rbpf": 60}


def warm_up(options: SlamOptions) -> float:
    """Run a throwaway estimator of ``options.method`` (at most 8 particles) over the
    start of a simulated tour (the built-in ``room_a`` at 1 m/s), once per process and
    method. numba loads its compiled kernels from the disk cache (or compiles them) at
    their first call: on aces the improved RBPF's first tracked scan took 470 ms and
    graph SLAM's first scan 590 ms, where the next take 1-15 ms -- a robot streaming at
    10 Hz would start five scans behind. Returns the seconds it took (0 when already
    warm). Kernels first called later (a loop search, a relocalisation) still load
    then, once."""
    key = (options.method, options.proposal if options.method == "rbpf" else "")
    with _WARM_LOCK:
        if key in _WARM:
            return 0.0
        t0 = time.perf_counter()
        scans = simulated_log("room_a", speed_m_s=1.0).scans
        slam = create(options.model_copy(update={"particles": min(options.particles, 8)}))
        for scan in scans[:_WARM_SCANS.get(options.method, 30)]:
            slam.process(scan)
        _WARM.add(key)
        return time.perf_counter() - t0


@dataclass
class SlamResult:
    """A run over a log: its trajectory, map and seconds; ``online_poses``, the
    trajectory before finish()'s global scan alignment (None when nothing was
    aligned)."""

    times: np.ndarray
    poses: np.ndarray
    map: OccupancyMap
    seconds: float
    online_poses: np.ndarray | None = None


def run_log(log: LaserLog, options: SlamOptions,
            progress: Callable[[int], None] | None = None) -> tuple[Slam, SlamResult]:
    """Run ``options.method`` over every scan of ``log``; ``progress(i)`` after each."""
    slam = create(options)
    t0 = time.perf_counter()
    for i, scan in enumerate(log.scans):
        slam.process(scan)
        if progress is not None:
            progress(i + 1)
    online = slam.trajectory()[1]
    slam.finish()  # global scan alignment (graph, improved RBPF), once the log is over
    seconds = time.perf_counter() - t0
    times, poses = slam.trajectory()
    return slam, SlamResult(times, poses, whole_map(slam, options.map_resolution_m), seconds,
                            online if slam.aligned else None)


def whole_map(slam: Slam, resolution_m: float) -> OccupancyMap:
    """The run's map at ``resolution_m``, or coarser where it would not fit
    (:func:`~chizu.numeric.occupancy.build_occupancy_fitting`)."""
    return build_occupancy_fitting(slam.keyframes.frames, slam.map_poses(), resolution_m)
