"""One map from two: a saved map resumed with a new log, two saved maps merged, each in
the first map's frame; maps that share no place, or of another laser, are refused; the
CLI commands."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam import saved_map as sm
from chizu.numeric.slam.matching.correlative import Match
from chizu.numeric.slam.merge import MergeConfig, frame_transform, merge, resume
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import drive, simulated_log
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a
from chizu.service.cli import app as cli
from tests.slam.drives import MODERATE_ODOMETRY, ROOM_A_TOUR

CLIP = Path(__file__).resolve().parents[2] / "examples" / "aces-clip.clf"
#: the second robot's odometry frame, unknown to the methods
HIDDEN = np.array([3.0, -2.0, 2.0])


def mapped(log: LaserLog) -> sm.SavedMap:
    slam, _ = run_log(log, SlamOptions(method="graph"))
    return sm.saved_map_of_log(slam, log, "graph", 0.05)


@pytest.fixture(scope="module")
def first_log() -> LaserLog:
    return simulated_log("room_a", speed_m_s=1.0)


@pytest.fixture(scope="module")
def first(first_log: LaserLog) -> sm.SavedMap:
    """room_a mapped by graph SLAM from the built-in tour (in the world's frame)."""
    return mapped(first_log)


def rigid_errors(xy: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distances of ``xy`` to ``truth`` after the best rigid motion of ``xy`` onto it
    (Kabsch): how far a trajectory is from the truth whatever frame it is in."""
    a, b = xy - xy.mean(0), truth - truth.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    r = (u @ vt).T
    if np.linalg.det(r) < 0:
        vt[-1] *= -1
        r = (u @ vt).T
    return np.asarray(np.hypot(*((a @ r.T) - b).T))


@pytest.fixture(scope="module")
def second_log() -> LaserLog:
    """The tour driven the other way round, its odometry in a frame of its own."""
    b = drive(World(room_a()), ROOM_A_TOUR[::-1].copy(), MODERATE_ODOMETRY, None, 0.5,
              np.random.default_rng(3), "reverse")
    return LaserLog(b.name, [dataclasses.replace(s, odom=compose(HIDDEN, s.odom))
                             for s in b.scans], b.truth)


@pytest.fixture(scope="module")
def second(second_log: LaserLog) -> sm.SavedMap:
    return mapped(second_log)


def test_a_log_resumes_a_map_in_its_frame(first: sm.SavedMap, first_log: LaserLog,
                                          second: sm.SavedMap, second_log: LaserLog) -> None:
    m, poses = resume(first, second)
    assert np.array_equal(m.poses[len(first.poses):], poses)
    both = np.vstack([first_log.truth, second_log.truth])[:, :2]
    e = rigid_errors(m.poses[:, :2], both)
    assert np.median(e) < 0.05 and e.max() < 0.2
    # in the first map's frame: its keyframes move little (anchored at the first)
    assert np.hypot(*(m.kf_pose[:len(first), :2] - first.kf_pose[:, :2]).T).max() < 0.2
    assert len(m) == len(first) + len(second)
    cross = (m.constraints.a < len(first)) & (m.constraints.b >= len(first))
    assert cross.sum() > 5  # loops closed across the two runs, kept in the map
    assert m.meta["placement"]["agree"] >= 3
    assert sm.from_bytes(sm.to_bytes(m)).kf_pose.shape == m.kf_pose.shape


def test_two_maps_merge_in_the_first_ones_frame(first: sm.SavedMap, first_log: LaserLog,
                                                second: sm.SavedMap,
                                                second_log: LaserLog) -> None:
    m, placed = merge(first, second)
    assert np.array_equal(m.times, np.concatenate([first.times, second.times]))
    both = np.vstack([first_log.truth, second_log.truth])[:, :2]
    e = rigid_errors(m.poses[:, :2], both)
    assert np.median(e) < 0.05 and e.max() < 0.25
    assert np.hypot(*(m.kf_pose[:len(first), :2] - first.kf_pose[:, :2]).T).max() < 0.2
    # the transform found puts the second map's first keyframe where it truly was
    assert placed.agree >= 3
    assert np.hypot(*(compose(placed.transform, second.kf_pose[0])[:2]
                      - second_log.truth[second.kf_scan[0], :2])) < 0.2


def test_a_map_without_a_pose_graph_merges_on_its_odometry(
        first: sm.SavedMap, first_log: LaserLog, second: sm.SavedMap,
        second_log: LaserLog) -> None:
    """A map of the RBPF or gated SLAM keeps no constraints: its keyframes are bound by
    the odometry between them, and the merged map holds those edges."""
    bare = dataclasses.replace(first, constraints=sm.Constraints.empty())
    m, _ = merge(bare, second)
    both = np.vstack([first_log.truth, second_log.truth])[:, :2]
    e = rigid_errors(m.poses[:, :2], both)
    assert np.median(e) < 0.05 and e.max() < 0.25
    odometry = sm.EDGE_KINDS.index("odometry")
    chain = (m.constraints.kind == odometry) & (m.constraints.b < len(first))
    assert chain.sum() == len(first) - 1


def test_a_third_run_joins_a_merged_map(first: sm.SavedMap, first_log: LaserLog,
                                        second: sm.SavedMap, second_log: LaserLog) -> None:
    """A merged map holds two runs, each with its own odometry: a third joins it, and
    no odometry edge is made across a join."""
    two, _ = merge(first, second)
    three, _ = merge(two, first)
    truth = np.vstack([first_log.truth, second_log.truth, first_log.truth])[:, :2]
    e = rigid_errors(three.poses[:, :2], truth)
    assert np.median(e) < 0.05 and e.max() < 0.25
    c = three.constraints
    odometry = c.kind == sm.EDGE_KINDS.index("odometry")
    starts = {len(first), len(first) + len(second)}
    assert not (set(c.b[odometry].tolist()) & starts)


def test_maps_that_share_no_place_are_refused(first: sm.SavedMap) -> None:
    corridor = mapped(simulated_log("corridor", speed_m_s=1.0))
    with pytest.raises(InvalidInput) as e:
        merge(first, corridor)
    assert e.value.field == "map" and "share no place" in str(e.value)


@pytest.mark.parametrize(("keyframes", "agreeing", "joined"),
                         [(60, range(20, 26), False),  # six fixes over 5 m of travel
                          (60, range(20, 44, 8), True),  # three over 16 m
                          (60, range(20, 31, 5), False),  # three over exactly 10 m
                          (12, range(2, 9, 3), True),  # B travels 11 m: over 6 m
                          (12, range(2, 7, 2), False)])  # over 4 m
def test_agreeing_fixes_must_come_from_more_than_one_stretch_of_travel(
        keyframes: int, agreeing: range, joined: bool) -> None:
    """Neighbouring keyframes' contexts are mostly the same returns: their fixes agreeing
    is one piece of evidence (a corridor seen turned round fits them all alike); they
    count only spread over more than ``context_m`` of B's travel (10 m here), or half
    of it when B is shorter."""
    kf_pose = np.array([[float(k), 0.0, 0.0] for k in range(keyframes)])  # 1 m apart
    kf_xy = [np.ones((20, 2))] * keyframes
    true = np.array([5.0, -3.0, 1.0])
    rng = np.random.default_rng(0)

    class Globally:
        def __init__(self) -> None:
            self.k = -1

        def fix(self, xy: np.ndarray, min_score: float | None = None) -> Match | None:
            self.k += 1  # the keyframes are searched in order, every one (at most 60)
            if self.k in agreeing:
                return Match(compose(true, kf_pose[self.k]), 0.6)
            if self.k % 7 == 0:  # fixes elsewhere, each its own
                return Match(np.array([*rng.uniform(-50, 50, 2), rng.uniform(-3, 3)]), 0.6)
            return None

    a = SimpleNamespace(globally=Globally())  # the map A: only its global search
    cfg = MergeConfig(context_m=10.0)
    if joined:
        placed = frame_transform(a, kf_xy, kf_pose, cfg)
        assert placed.agree == len(agreeing) and np.allclose(placed.transform, true)
    else:
        with pytest.raises(InvalidInput, match="agree over more than"):
            frame_transform(a, kf_xy, kf_pose, cfg)


def test_a_map_of_another_laser_is_refused(first: sm.SavedMap, second: sm.SavedMap) -> None:
    other = dataclasses.replace(second, laser=dataclasses.replace(
        second.laser, angle_increment=2 * second.laser.angle_increment))
    with pytest.raises(InvalidInput) as e:
        merge(first, other)
    assert e.value.field == "map" and "deg steps" in str(e.value)


def test_the_cli_resumes_and_merges(tmp_path: Path) -> None:
    run = CliRunner()
    r = run.invoke(cli, ["slam", str(CLIP), "--limit", "200", "--out", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    r = run.invoke(cli, ["slam", str(CLIP), "--resume", str(tmp_path / "a"), "--out",
                         str(tmp_path / "ab")])
    assert r.exit_code == 0, r.output
    a, ab = sm.load(tmp_path / "a"), sm.load(tmp_path / "ab")
    assert len(ab) > len(a) and len(ab.times) == 200 + 350
    tum = (tmp_path / "ab" / "trajectory.tum").read_text().splitlines()
    assert len(tum) == 350  # the new log's poses
    # the resumed log's first 200 scans lie where the map has them
    xy = np.array([[float(v) for v in line.split()[1:3]] for line in tum[:200]])
    assert np.median(np.hypot(*(xy - ab.poses[:200, :2]).T)) < 0.05
    assert np.median(np.hypot(*(ab.poses[:200, :2] - a.poses[:, :2]).T)) < 0.05
    r = run.invoke(cli, ["slam-merge", str(tmp_path / "a"), str(tmp_path / "ab" / "map.chizu"),
                         "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    assert len((tmp_path / "m" / "trajectory.tum").read_text().splitlines()) == 200 + 550
    # bad input: another method, a missing map; nothing written
    for args in (["--method", "icp", "--resume", str(tmp_path / "a")],
                 ["--resume", str(tmp_path / "nothing")]):
        r = run.invoke(cli, ["slam", str(CLIP), "--limit", "50", *args, "--out",
                             str(tmp_path / "bad")])
        assert r.exit_code == 2, r.output
    r = run.invoke(cli, ["slam-merge", str(tmp_path / "a"), str(tmp_path / "nothing"),
                         "--out", str(tmp_path / "bad")])
    assert r.exit_code == 2, r.output
    assert not (tmp_path / "bad").exists()
