"""The relation metric of Kümmerle et al. 2009, "On measuring the accuracy of SLAM
algorithms".

For every relation (t1, t2, delta_ref) the estimated relation is
``delta_est = inv(X_t1) X_t2`` from the trajectory's poses at t1 and t2 (nearest stamp
within ``max_dt_s``) and the error is ``E = inv(delta_ref) delta_est``; the
translational error is ``|t(E)|`` (m), the rotational ``|angle(E)|`` (reported in
degrees, as the published tables are). Means and sample standard deviations (n - 1) of
the absolute and squared errors are returned, like the Freiburg metricEvaluator and
Cartographer's ``compute_relations_metrics``. :func:`local_failures` counts the short
relations a method gets wrong where the raw odometry gets them right.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, invert, relative


@dataclass(frozen=True)
class RelationErrors:
    """Mean ± std of the per-relation errors (m, m², deg, deg²) and how many relations
    were evaluated (``n``) or had no pose within the time tolerance (``missing``)."""

    n: int
    missing: int
    trans_m: float
    trans_std_m: float
    trans_sq_m2: float
    trans_sq_std_m2: float
    rot_deg: float
    rot_std_deg: float
    rot_sq_deg2: float
    rot_sq_std_deg2: float

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _mean_std(v: np.ndarray) -> tuple[float, float]:
    return float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0


def poses_at(times: np.ndarray, poses: np.ndarray, query: np.ndarray,
             max_dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``(Q, 3)`` of the trajectory at the nearest stamp to each query time and a
    mask of queries that had a stamp within ``max_dt_s``."""
    order = np.argsort(times, kind="stable")
    ts = times[order]
    i = np.clip(np.searchsorted(ts, query), 1, max(len(ts) - 1, 1))
    left = np.clip(i - 1, 0, len(ts) - 1)
    right = np.clip(i, 0, len(ts) - 1)
    pick = np.where(np.abs(ts[left] - query) <= np.abs(ts[right] - query), left, right)
    ok = np.abs(ts[pick] - query) <= max_dt_s
    return poses[order][pick], ok


#: a relation's end has a pose when the trajectory has a stamp this near it (s)
RELATION_MAX_DT_S = 0.1


def relation_error_poses(times: np.ndarray, poses: np.ndarray, rel_times: np.ndarray,
                         rel_delta: np.ndarray, max_dt_s: float) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """``E = inv(delta_ref) delta_est`` ``(R, 3)`` of every relation, in the reference
    relation's frame, and a mask of the relations whose two ends had a pose within
    ``max_dt_s`` (E is meaningless elsewhere)."""
    p1, ok1 = poses_at(times, poses, rel_times[:, 0], max_dt_s)
    p2, ok2 = poses_at(times, poses, rel_times[:, 1], max_dt_s)
    return compose(invert(rel_delta), relative(p1, p2)), ok1 & ok2


def relation_errors(times: np.ndarray, poses: np.ndarray, rel_times: np.ndarray,
                    rel_delta: np.ndarray, max_dt_s: float = RELATION_MAX_DT_S
                    ) -> RelationErrors:
    """Errors of the trajectory (``times (N,)``, ``poses (N, 3)``) on the relations
    (``rel_times (R, 2)``, ``rel_delta (R, 3)``)."""
    if len(times) == 0 or len(times) != len(poses):
        raise InvalidInput("the trajectory is empty or its times and poses differ in length",
                           field="trajectory")
    err, ok = relation_error_poses(times, poses, rel_times, rel_delta, max_dt_s)
    if not np.any(ok):
        raise InvalidInput("no relation falls on the trajectory's time stamps "
                           f"(tolerance {max_dt_s} s)", field="relations")
    err = err[ok]
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    tm, ts = _mean_std(trans)
    tq, tqs = _mean_std(trans**2)
    rm, rs = _mean_std(rot)
    rq, rqs = _mean_std(rot**2)
    return RelationErrors(int(ok.sum()), int((~ok).sum()), tm, ts, tq, tqs, rm, rs, rq, rqs)


#: :func:`local_failures`' defaults: relations shorter than this (s), off by more than
#: this (m), where the raw odometry is within this (m)
LOCAL_MAX_GAP_S = 20.0
LOCAL_OFF_M = 0.3
LOCAL_ODOM_OK_M = 0.1


@dataclass(frozen=True)
class LocalFailures:
    """Short relations the estimate gets wrong where the raw odometry gets them right:
    their start times ``t1`` and errors ``error (F, 3)`` as (along the reference
    relation, across it, heading), in the reference relation's frame (m, m, rad)."""

    t1: np.ndarray
    error: np.ndarray

    def __len__(self) -> int:
        return len(self.t1)


def local_failures(times: np.ndarray, poses: np.ndarray, odom_times: np.ndarray,
                   odom: np.ndarray, rel_times: np.ndarray, rel_delta: np.ndarray,
                   max_gap_s: float = LOCAL_MAX_GAP_S, off_m: float = LOCAL_OFF_M,
                   odom_ok_m: float = LOCAL_ODOM_OK_M,
                   max_dt_s: float = RELATION_MAX_DT_S,
                   ) -> LocalFailures:
    """The relations shorter than ``max_gap_s`` on which the trajectory is more than
    ``off_m`` off while the raw odometry (``odom_times``, ``odom``) is within
    ``odom_ok_m``: failures of the method's local matching, not drift the odometry
    already had. Where a relation's whole error comes from (along-track shortfall,
    lateral, heading) tells a scan that pulls the match along a hall from a heading
    flip in a corridor."""
    short = (rel_times[:, 1] - rel_times[:, 0]) < max_gap_s
    rt, rd = rel_times[short], rel_delta[short]
    est, ok = relation_error_poses(times, poses, rt, rd, max_dt_s)
    odo, ok_odo = relation_error_poses(odom_times, odom, rt, rd, max_dt_s)
    ok &= ok_odo
    bad = (ok & (np.hypot(est[:, 0], est[:, 1]) > off_m)
           & (np.hypot(odo[:, 0], odo[:, 1]) < odom_ok_m))
    return LocalFailures(rt[bad, 0], est[bad])
