"""Global scan alignment (Lu & Milios 1997), the last step of graph SLAM: pairwise
point-to-line matches with their covariances, one batch optimisation, and the end of a
graph SLAM run."""

from __future__ import annotations

import numpy as np
import pytest

from chizu.numeric.geometry import compose, relative, wrap_angle
from chizu.numeric.slam.alignment import (
    AlignmentConfig,
    align_globally,
    align_scans,
    candidate_pairs,
    estimate_closures,
    match_pair,
)
from chizu.numeric.slam.graph import GraphSlam, GraphSlamConfig
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.matching.intensity_icp import Reference
from chizu.numeric.slam.pose_graph import GraphConfig
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import simulated_log
from tests.slam.test_graph_slam import CORRIDOR, scan_at


def test_a_corridor_match_is_uncertain_along_the_corridor_only() -> None:
    """The covariance comes from the point-to-line Jacobian: in a plain corridor the
    walls fix the width and the heading, not the length -- also when the matched scan
    is turned, since the covariance is moved into its frame."""
    a, b = np.array([14.0, 1.0, 0.0]), np.array([14.3, 1.05, 0.5])
    ref = Reference(scan_at(a, CORRIDOR, 4.0), None, 0.0)  # dense walls
    found = match_pair(ref, scan_at(b, CORRIDOR, 4.0), None,
                       relative(a, b) + np.array([0.0, 0.04, 0.01]), AlignmentConfig())
    assert found is not None
    delta, cov = found
    assert abs(delta[1] - relative(a, b)[1]) < 0.01  # across: found
    assert abs(wrap_angle(delta[2] - relative(a, b)[2])) < 0.005
    along_b = np.array([np.cos(-b[2]), np.sin(-b[2])])  # the corridor's axis in b's frame
    across_b = np.array([-along_b[1], along_b[0]])
    var_along = along_b @ cov[:2, :2] @ along_b
    var_across = across_b @ cov[:2, :2] @ across_b
    assert var_along > 100 * var_across


def test_a_match_far_from_its_guess_is_refused() -> None:
    """Alignment refines the online estimate; it does not re-decide it: ICP that moves
    the guess by more than max_correction_m gives no match, even when it is right."""
    a, b = np.array([14.0, 1.0, 0.0]), np.array([14.3, 1.05, 0.2])
    ref = Reference(scan_at(a, CORRIDOR, 4.0), None, 0.0)
    guess = relative(a, b) + np.array([0.0, 0.18, 0.0])  # 0.18 m across the corridor
    loose = match_pair(ref, scan_at(b, CORRIDOR, 4.0), None, guess,
                       AlignmentConfig(max_correction_m=0.3))
    assert loose is not None and abs(loose[0][1] - relative(a, b)[1]) < 0.01
    assert match_pair(ref, scan_at(b, CORRIDOR, 4.0), None, guess, AlignmentConfig()) is None


def test_candidate_pairs_take_sequential_scans_and_other_passes() -> None:
    poses = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]] * 10, dtype=float)
    pairs = candidate_pairs(poses, AlignmentConfig(revisit_min_gap=5))
    assert (0, 1) in pairs and (0, 8) in pairs and (31, 39) in pairs
    revisits = [(a, b) for a, b in pairs if b - a > 8]
    assert revisits and all(np.hypot(*(poses[a] - poses[b])[:2]) <= 1.5 and b - a > 5
                            for a, b in revisits)
    assert max(sum(1 for a, b in revisits if b == k) for k in range(40)) <= 3
    # the scans before ``first`` held: the same pairs, less those among them
    assert candidate_pairs(poses, AlignmentConfig(revisit_min_gap=5), first=17) == [
        (a, b) for a, b in pairs if b >= 17]


def test_estimate_closures_take_the_pairs_facing_apart() -> None:
    """A corridor driven out and back: the return leg faces away from the way out, where
    a 180° laser sees too little of the same walls for the revisit matches, and the
    online estimate's relative pose of each returning scan to its nearest outgoing one
    becomes a closure."""
    out = np.array([[0.5 * k, 0.0, 0.0] for k in range(20)])
    back = np.array([[9.5 - 0.5 * k, 0.1, np.pi - 0.05] for k in range(20)])
    poses = np.vstack([out, back])
    cfg = AlignmentConfig(revisit_min_gap=5)
    closures = estimate_closures(poses, cfg)
    assert len({b for _, b, _ in closures}) == len(closures)  # one per scan at most
    assert {b for _, b, _ in closures} >= set(range(22, 40))  # the return leg, past the turn
    for a, b, delta in closures:
        assert a < b - 5 and np.hypot(*(poses[a] - poses[b])[:2]) <= 1.5
        assert abs(wrap_angle(poses[b, 2] - poses[a, 2])) >= cfg.apart_rad
        assert np.allclose(delta, relative(poses[a], poses[b]))
        near = [j for j in range(b - 5) if abs(wrap_angle(poses[b, 2] - poses[j, 2])) >= 1.0]
        assert np.hypot(*(poses[a] - poses[b])[:2]) == min(
            np.hypot(*(poses[j] - poses[b])[:2]) for j in near)
    # the revisits are tried at any heading: ICP's overlap test decides whether a pair
    # facing apart sees enough of the same walls
    revisits = {(a, b) for a, b in candidate_pairs(poses, cfg) if b - a > 8}
    assert {b for _, b in revisits} >= set(range(23, 40))
    assert all(abs(wrap_angle(poses[b, 2] - poses[a, 2])) > 3 for a, b in revisits)
    facing = cfg.model_copy(update={"revisit_max_turn_rad": 1.0})  # as map localization
    assert not [(a, b) for a, b in candidate_pairs(poses, facing) if b - a > 8]
    same_way = np.array([[0.5 * (k % 20), 0.0, 0.0] for k in range(40)])  # twice, same way
    assert estimate_closures(same_way, cfg) == []


@pytest.fixture(scope="module")
def room_run() -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    log = simulated_log("room_a", seed=3, speed_m_s=0.6).head(240)
    assert log.truth is not None
    pts = [voxel_downsample(s.points()[0], None, 0.05)[0] for s in log.scans]
    return pts, log.truth, log.odometry


def test_a_forgotten_scan_is_held_to_its_neighbour_as_local_slam_held_it() -> None:
    """A scan without points is tied to the scan before by the online estimate's
    relative pose with local SLAM's sigmas, against the odometry's: the two weighed by
    their precisions (here 1.0 m of odometry against 1.1 m of online estimate, whose
    sigma is a third of the odometry's); as a loop closure (Huber-robust, outvoted), the
    odometry would win."""
    noise = GraphConfig()
    poses = np.array([[0.0, 0.0, 0.0], [1.05, 0.0, 0.0]])
    odometry = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    online = np.array([1.1, 0.0, 0.0])
    held = align_globally(poses, odometry, [], [], AlignmentConfig(), noise,
                          local=[(0, 1, online)])
    w_odo = 1 / noise.odometry_sigmas(odometry[1])[0] ** 2
    w_loc = 1 / noise.local_sigmas(online)[0] ** 2
    assert held[1, 0] == pytest.approx((1.0 * w_odo + 1.1 * w_loc) / (w_odo + w_loc), abs=1e-3)
    assert held[1, 0] > 1.08
    as_closure = align_globally(poses, odometry, [], [(0, 1, online)], AlignmentConfig(), noise)
    assert as_closure[1, 0] < 1.05


def test_alignment_pulls_perturbed_poses_back_to_the_truth(room_run) -> None:  # type: ignore[no-untyped-def]
    """Poses 3 cm / 0.7 deg off the truth (as a grid-based front end leaves them) come
    back to within a fraction of that: the pairwise matches hold the scans together."""
    pts, truth, odom = room_run
    rng = np.random.default_rng(0)
    noisy = truth + np.column_stack([rng.normal(0, 0.03, (len(truth), 2)),
                                     rng.normal(0, np.radians(0.7), len(truth))])
    noisy[0] = truth[0]  # the first pose anchors the frame
    aligned, matches = align_scans(pts, [None] * len(pts), noisy, odom, [],
                                   AlignmentConfig())
    assert matches > 3 * len(pts)

    def rel_err(p: np.ndarray) -> float:
        d = relative(p[:-5], p[5:])
        t = relative(truth[:-5], truth[5:])
        return float(np.mean(np.hypot(*(d - t)[:, :2].T)))

    assert rel_err(aligned) < rel_err(noisy) / 3
    assert rel_err(aligned) < 0.02


def test_graph_slam_finish_aligns_and_a_new_scan_resumes_online() -> None:
    log = simulated_log("loop", seed=2, speed_m_s=0.8).head(260)
    truth = log.truth
    assert truth is not None
    s = GraphSlam(GraphSlamConfig())
    for scan in log.scans[:-1]:
        s.process(scan)
    _, online = s.trajectory()
    assert s.finish() > 0 and s.aligned
    _, aligned = s.trajectory()
    assert np.allclose(s.pose, aligned[-1]) and len(s.map_poses()) == len(s.local)
    err = lambda p: float(np.mean(np.hypot(*(compose(relative(p[0], p), np.zeros(3))  # noqa: E731
                                             - relative(truth[0], truth[:len(p)]))[:, :2].T)))
    assert err(aligned) <= err(online) * 1.05  # no worse (the sim's laser is coarse)
    s.process(log.scans[-1])  # a new scan: the online estimate is current again
    assert not s.aligned and len(s.trajectory()[1]) == len(log.scans)
    off = GraphSlam(GraphSlamConfig(alignment=None))
    off.process(log.scans[0])
    assert off.finish() == 0 and not off.aligned


def test_a_graph_run_over_a_log_ends_aligned() -> None:
    log = simulated_log("room_a", seed=1, speed_m_s=0.6).head(120)
    slam, result = run_log(log, SlamOptions(method="graph"))
    assert slam.aligned
    assert np.array_equal(result.poses, slam.trajectory()[1])
