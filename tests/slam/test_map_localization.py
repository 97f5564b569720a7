"""Localization only, on a saved map: an unknown start, a robot carried away, a laser
that is not the map's, and the CLI."""

from __future__ import annotations

import dataclasses
import json
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, relative, wrap_angle
from chizu.numeric.probability_grid import GridConfig, ProbabilityGrid, no_stamps
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam import saved_map as sm
from chizu.numeric.slam.graph import ScanOdometry
from chizu.numeric.slam.map_localization import (
    GlobalAnswer,
    GlobalSearch,
    LocalizationRun,
    MapLocalizationConfig,
    MapLocalizer,
    bridged,
    localize_log,
)
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import drive, simulated_log
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a
from chizu.service.cli import app as cli
from tests.slam.drives import MODERATE_ODOMETRY, ODOMETRY_QUALITIES, ROOM_A_TOUR

CLIP = Path(__file__).resolve().parents[2] / "examples" / "aces-clip.clf"
#: where the second robot's odometry starts, unknown to the method
HIDDEN = np.array([3.0, -2.0, 2.0])


@pytest.fixture(scope="module")
def room_map() -> sm.SavedMap:
    """room_a mapped by graph SLAM from the built-in tour."""
    log = simulated_log("room_a", speed_m_s=1.0)
    slam, _ = run_log(log, SlamOptions(method="graph"))
    return sm.saved_map_of_log(slam, log, "graph", 0.05)


@pytest.fixture(scope="module")
def other_drive() -> LaserLog:
    """The tour driven the other way round, its odometry in a frame of its own."""
    b = drive(World(room_a()), ROOM_A_TOUR[::-1].copy(), MODERATE_ODOMETRY, None, 0.5,
              np.random.default_rng(3), "reverse")
    return LaserLog(b.name, [dataclasses.replace(s, odom=compose(HIDDEN, s.odom))
                             for s in b.scans], b.truth)


def _errors(run: LocalizationRun, truth: np.ndarray) -> np.ndarray:
    ok = run.localized
    return np.asarray(np.hypot(*(run.poses[ok, :2] - truth[ok, :2]).T))


def test_a_robot_finds_itself_from_an_unknown_start(room_map: sm.SavedMap,
                                                    other_drive: LaserLog) -> None:
    run = localize_log(room_map, other_drive)
    assert run.first_fix_s() is not None and run.first_fix_s() < 5.0
    assert run.localized.mean() > 0.9 and not run.losses
    e = _errors(run, other_drive.truth)
    assert np.median(e) < 0.08 and e.max() < 0.4


def test_a_robot_carried_away_is_found_again(room_map: sm.SavedMap,
                                             other_drive: LaserLog) -> None:
    """A third of the drive's scans dropped: the robot reappears elsewhere; it is lost
    at the gap and fixed again within two seconds of log, in the right place."""
    n = len(other_drive)
    cut = other_drive.carried(n // 3, 2 * n // 3)
    run = localize_log(room_map, cut)
    gap_t = cut.scans[n // 3].t
    assert len(run.losses) == 1 and run.losses[0] == pytest.approx(gap_t)
    assert len(run.fixes) == 2 and run.fixes[1] - gap_t < 2.0
    after = run.times >= run.fixes[1]
    ok = run.localized & after
    assert np.median(np.hypot(*(run.poses[ok, :2] - cut.truth[ok, :2]).T)) < 0.08


def test_a_gap_in_the_log_does_not_lose_a_robot_that_drove_on(
        room_map: sm.SavedMap, other_drive: LaserLog) -> None:
    """Records dropped for a few seconds while the robot drove on: its wheels read the
    motion, its scan fits the map there, and once a global search confirms the pose it
    is tracked on -- the same fix, not lost. Carried off for the same time (the wheels
    read nothing), it is lost at the gap."""
    run = localize_log(room_map, other_drive)
    t = other_drive.times
    start = int(np.searchsorted(t, run.fixes[0] + 5.0))
    stop = int(np.searchsorted(t, t[start] + 3.0))
    assert t[stop] - t[start - 1] > MapLocalizationConfig().gap_s
    keep = np.r_[0:start, stop:len(other_drive)]
    dropped = LaserLog("dropped", [other_drive.scans[i] for i in keep],
                       other_drive.truth[keep])
    carried = other_drive.carried(start, stop)
    held = localize_log(room_map, dropped)
    assert not held.losses and held.fixes == run.fixes
    k = start + MapLocalizationConfig().confirm_scans
    assert held.states[start:k] == ["confirming"] * (k - start)
    assert held.localized[k:].mean() > 0.9
    ok = held.localized & (held.times >= t[stop])
    assert np.median(np.hypot(*(held.poses[ok, :2] - dropped.truth[ok, :2]).T)) < 0.08
    lost = localize_log(room_map, carried)
    assert lost.losses == [pytest.approx(t[stop])]
    assert lost.fixes[-1] > t[stop]


def test_a_carried_log_drops_the_scans_and_the_wheels_read_nothing(
        other_drive: LaserLog) -> None:
    c = other_drive.carried(10, 30)
    assert len(c) == len(other_drive) - 20
    assert [s.t for s in c.scans] == [s.t for s in other_drive.scans[:10] + other_drive.scans[30:]]
    o, oc = other_drive.odometry, c.odometry
    assert np.allclose(oc[10], o[9])  # no motion read over the carry
    assert np.allclose(relative(oc[10], oc[20]), relative(o[30], o[40]))  # then as before
    assert other_drive.truth is not None and c.truth is not None
    assert np.allclose(c.truth[10], other_drive.truth[30])
    for bad in ((0, 5), (5, 4), (5, len(other_drive))):
        with pytest.raises(InvalidInput) as e:
            other_drive.carried(*bad)
        assert e.value.field == "scans"


@pytest.mark.parametrize(("answers", "tracking"),
                         [(["agrees"], True),
                          (["ambiguous", "none", "agrees"], True),
                          (["ambiguous", "elsewhere"], False),
                          (["ambiguous", "none", "ambiguous"], False)])
def test_a_fix_is_confirmed_by_a_unique_second_search_tried_again_if_it_has_none(
        room_map: sm.SavedMap, other_drive: LaserLog, monkeypatch: pytest.MonkeyPatch,
        answers: list[str], tracking: bool) -> None:
    """The confirming search: one agreeing unique answer takes the fix; no answer or an
    ambiguous one (a rival as good) is tried again ``confirm_scans`` scans later, up to
    ``confirm_tries`` times; a unique answer 5 m away drops the fix at once."""
    cfg = MapLocalizationConfig()
    loc = MapLocalizer(room_map, cfg)
    real_search = loc.globally.search_all
    tries: list[int] = []

    def search_all(xy: np.ndarray, min_score: float | None = None) -> GlobalAnswer:
        a = real_search(xy, min_score)
        if min_score is None:  # the first fix's search
            return a
        tries.append(len(states))  # the scan being processed
        assert a.best is not None  # the tracked pose, found again
        say = answers[len(tries) - 1]
        far = dataclasses.replace(a.best, pose=compose(a.best.pose, np.array([5.0, 0, 0])))
        return {"agrees": GlobalAnswer(a.best, True), "ambiguous": GlobalAnswer(a.best, False),
                "none": GlobalAnswer(None, False), "elsewhere": GlobalAnswer(far, True)}[say]

    monkeypatch.setattr(loc.globally, "search_all", search_all)
    states: list[str] = []
    for scan in other_drive.scans[:60]:
        states.append(loc.process(scan).state)
        if states[-1] != "confirming" and tries:
            break
    assert len(tries) == len(answers)
    assert np.all(np.diff(tries) == cfg.confirm_scans)  # every tracked scan fits here
    assert states[-1] == ("tracking" if tracking else "searching")
    assert len(loc.fixes) == int(tracking) and not loc.losses  # no fix was lost


def test_a_pose_held_across_a_gap_gets_one_confirming_search(
        room_map: sm.SavedMap, other_drive: LaserLog, monkeypatch: pytest.MonkeyPatch) -> None:
    """No global search found a pose held across a gap (the wheels put it there and one
    scan fitted): an ambiguous confirming search is not tried again, the robot is lost
    at the gap."""
    t = other_drive.times
    start = 60
    stop = int(np.searchsorted(t, t[start] + 3.0))
    keep = np.r_[0:start, stop:len(other_drive)]
    dropped = LaserLog("dropped", [other_drive.scans[i] for i in keep],
                       other_drive.truth[keep])
    loc = MapLocalizer(room_map)
    real_search = loc.globally.search_all
    after_gap: list[GlobalAnswer] = []

    def search_all(xy: np.ndarray, min_score: float | None = None) -> GlobalAnswer:
        a = real_search(xy, min_score)
        if min_score is None or loc._held_from is None:
            return a
        after_gap.append(a)
        return GlobalAnswer(a.best, False)  # the held pose found, a rival as good

    monkeypatch.setattr(loc.globally, "search_all", search_all)
    states = [loc.process(s).state for s in dropped.scans[:start + 20]]
    assert states[start - 1] == "tracking" and states[start] == "confirming"
    assert len(after_gap) == 1 and loc.losses == [pytest.approx(t[stop])]
    k = start + MapLocalizationConfig().confirm_scans  # the scan of the one try
    assert states[start:k] == ["confirming"] * (k - start) and states[k] == "searching"


@pytest.mark.parametrize(("shift_m", "score", "taken"),
                         [(0.2, 0.45, False), (0.2, 0.7, True), (0.03, 0.45, True)])
def test_a_mediocre_match_does_not_move_the_pose_far(
        room_map: sm.SavedMap, other_drive: LaserLog, monkeypatch: pytest.MonkeyPatch,
        shift_m: float, score: float, taken: bool) -> None:
    """While tracking, the map's answer is taken when it stays near local SLAM's
    prediction or scores well; a mediocre one that moves the pose far (walls sliding
    along walls) leaves the prediction."""
    loc = MapLocalizer(room_map)
    k = 0
    while loc.state != "tracking":
        loc.process(other_drive.scans[k])
        k += 1
    seen: dict[str, np.ndarray] = {}

    def fit(xy: np.ndarray, predicted: np.ndarray) -> tuple[np.ndarray, float, float]:
        seen["predicted"] = predicted.copy()
        return compose(predicted, np.array([shift_m, 0.0, 0.0])), score, 0.9

    monkeypatch.setattr(loc, "fit", fit)
    step = loc.process(other_drive.scans[k])
    moved = compose(seen["predicted"], np.array([shift_m, 0.0, 0.0]))
    assert step.state == "tracking" and step.pose is not None
    assert np.allclose(step.pose, moved if taken else seen["predicted"])


def test_a_log_of_another_laser_is_refused(room_map: sm.SavedMap,
                                           other_drive: LaserLog) -> None:
    half = LaserLog("half", [dataclasses.replace(s, ranges=s.ranges[::2], angles=s.angles[::2],
                                                 intensities=None if s.intensities is None
                                                 else s.intensities[::2])
                             for s in other_drive.scans[:20]])
    with pytest.raises(InvalidInput, match="steps") as e:
        localize_log(room_map, half)
    assert e.value.field == "map"


def test_the_cli_localizes_a_log_on_a_saved_map(tmp_path: Path) -> None:
    r = CliRunner()
    res = r.invoke(cli, ["slam", str(CLIP), "--out", str(tmp_path / "map")])
    assert res.exit_code == 0, res.output
    res = r.invoke(cli, ["slam-localize", str(CLIP), "--map", str(tmp_path / "map"),
                         "--out", str(tmp_path / "loc")])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "loc" / "localization.json").read_text())
    assert report["scans"] == 350 and report["localized"] > 300
    assert report["first_fix_s"] is not None and report["first_fix_s"] < 5.0
    lines = (tmp_path / "loc" / "trajectory.tum").read_text().splitlines()
    assert report["placed"] >= report["localized"]
    assert len([ln for ln in lines if not ln.startswith("#")]) == report["placed"]


@pytest.mark.parametrize("bad", ["missing", "garbage"])
def test_the_cli_refuses_a_bad_map_and_writes_nothing(tmp_path: Path, bad: str) -> None:
    m = tmp_path / "m"
    if bad == "garbage":
        m.mkdir()
        (m / sm.FILE_NAME).write_bytes(b"not a map")
    res = CliRunner().invoke(cli, ["slam-localize", str(CLIP), "--map", str(m),
                                   "--out", str(tmp_path / "loc")])
    assert res.exit_code == 2 and "map" in res.output
    assert not (tmp_path / "loc").exists()


def test_local_slam_predicts_better_than_drifting_odometry() -> None:
    """The localizer's motion estimate (local SLAM alone) keeps the heading where the
    odometry's random-walks, and holds no submap grid it no longer matches against."""
    b = drive(World(room_a()), ROOM_A_TOUR, ODOMETRY_QUALITIES["drifting"], None, 0.5,
              np.random.default_rng(5), "drifting")
    so = ScanOdometry()
    est = np.array([so(s) for s in b.scans])

    def heading_drift(p: np.ndarray) -> float:
        d = relative(p[0], p)[:, 2] - relative(b.truth[0], b.truth)[:, 2]
        return float(np.max(np.abs(wrap_angle(d))))

    assert heading_drift(est) < 0.5 * heading_drift(b.odometry)
    slam = so._slam
    assert len(slam.submaps) > 3
    assert all(not s.grid.prob.size for s in slam.submaps if s.finished)
    so.restart()
    assert np.allclose(so(b.scans[10]), b.scans[10].odom)


def test_scans_between_placed_ones_are_bridged_within_stretches() -> None:
    """Unplaced scans between two placed ones follow the motion estimate and meet both
    ends; before the first and after the last placed scan of a part of the log they run
    from the one end; a part with no placed scan stays unplaced."""
    n = 40
    odometry = np.column_stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)])
    truth = compose(np.array([5.0, 2.0, 0.5]), odometry)
    poses = np.full((n, 3), np.nan)
    poses[[3, 10, 11]] = truth[[3, 10, 11]]
    poses[10, :2] += 0.07  # the map's fix disagrees a little with the odometry
    cfg = MapLocalizationConfig()
    out = bridged(poses, odometry, np.array([20, 30]), cfg)
    assert np.array_equal(out[[3, 10, 11]], poses[[3, 10, 11]])
    assert np.allclose(out[:3], truth[:3]) and np.allclose(out[12:20], truth[12:20])
    step = np.hypot(*np.diff(out[3:11, :2], axis=0).T)
    assert np.all(np.abs(step - 0.1) < 0.02)  # the misfit spread along the way
    assert np.isnan(out[20:]).all()
    # a fix in the wrong place (turned, metres off), shorter than the right ones
    # around it that agree with each other through the path, is dropped
    poses[[14, 15, 16]] = truth[[14, 15, 16]]
    poses[10:12] = compose(poses[10:12], np.array([3.0, 1.0, 1.2]))
    out = bridged(poses, odometry, np.array([20, 30]), cfg)
    assert np.allclose(out[:20], truth[:20]) and np.isnan(out[20:]).all()


def test_the_global_search_places_the_robot_only_near_free_cells() -> None:
    """Offsets of the search window where the robot would stand inside a wall, in rooms
    the map never saw or outside the map are pruned before they are scored."""
    res = 0.05
    prob = np.zeros((200, 100), dtype=np.float32)  # 10 m x 5 m
    grid = ProbabilityGrid(GridConfig(resolution_m=res), np.zeros(2), prob,
                           no_stamps(prob.shape), 1)
    free = np.zeros(prob.shape, dtype=bool)
    free[40:80, 20:40] = True  # x 2-4 m, y 1-2 m
    g = GlobalSearch(grid, free, MapLocalizationConfig(global_free_m=1.0))
    mask = g.allowed[0]
    step = g.search.grid.resolution_m
    w = (mask.shape[0] - 1) // 2

    def allowed(x: float, y: float) -> bool:
        i, j = np.floor((np.array([x, y]) - g.centre[:2]) / step + 0.5).astype(int) + w
        return bool(mask[i, j])

    assert allowed(3.0, 1.5) and allowed(3.0, 2.9) and allowed(1.1, 1.5)
    assert not allowed(3.0, 3.6) and not allowed(8.0, 1.5) and not allowed(0.5, 0.5)
    # the strip and 1 m around it (11.1 m²) of the 10 m x 10 m window; none outside the map
    assert 10.0 < mask.sum() * step**2 < 12.0


def test_a_lost_robot_searches_again_only_once_it_has_moved(
        room_map: sm.SavedMap, other_drive: LaserLog,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Standing still, its scans are the last search's and so would be the answer;
    driving, it searches again after 0.5 m of travel (or a turn of 0.5 rad), and once
    the searches have failed over 10 m (all they match at once), after 2 m."""
    loc = MapLocalizer(room_map)
    calls: list[float] = []

    def fix(xy: np.ndarray, min_score: float | None = None) -> None:
        calls.append(loc._t or 0.0)

    monkeypatch.setattr(loc.globally, "fix", fix)
    s0 = other_drive.scans[0]
    for k in range(20):  # ten seconds standing
        loc.process(dataclasses.replace(s0, t=s0.t + 0.5 * k))
    assert len(calls) == 1
    path = 0.0
    for a, b in pairwise(other_drive.scans):
        loc.process(dataclasses.replace(b, t=b.t + 10.0))
        path += float(np.hypot(*(b.odom[:2] - a.odom[:2])))
    # once a second (the tour takes a minute) were 60 and more; every 0.5 m, as many
    assert 4 < len(calls) < 10.0 / 0.5 + (path - 10.0) / 2.0 + 8
