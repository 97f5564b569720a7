"""Laser SLAM numerics: readers, metric, laser simulator, Intensity-ICP, gated SLAM,
RBPF, occupancy maps and the CLI."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, place, relative
from chizu.numeric.laser import Laser, LaserConfig
from chizu.numeric.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap, build_occupancy
from chizu.numeric.scan import Scan
from chizu.numeric.slam.datasets import slam_data_dir
from chizu.numeric.slam.evaluation import local_failures, relation_errors
from chizu.numeric.slam.gated import GateConfig, SingleHypothesisSlam, inside_gate
from chizu.numeric.slam.logs import (
    read_carmen,
    read_log,
    read_relations,
    read_tum,
    write_carmen,
    write_tum,
)
from chizu.numeric.slam.matching.intensity_icp import IcpConfig, Reference, intensity_icp
from chizu.numeric.slam.rbpf import RbpfConfig, RbpfSlam, systematic_resample
from chizu.numeric.slam.simulate import simulated_log
from chizu.numeric.world import World, WorldDescription
from chizu.numeric.worlds import from_template
from chizu.service.cli import app as cli

_DATA = slam_data_dir()
DATA = _DATA or Path("/nonexistent")
needs_data = pytest.mark.skipif(_DATA is None, reason="benchmark logs not present")


@pytest.fixture(scope="module")
def room_log():  # type: ignore[no-untyped-def]
    return simulated_log("room_a", seed=0)


@pytest.fixture(scope="module")
def corridor_log():  # type: ignore[no-untyped-def]
    return simulated_log("corridor", seed=0)


# -- readers and metric --------------------------------------------------------------------
@needs_data
def test_carmen_flaser_and_robotlaser() -> None:
    mit = read_carmen(DATA / "mit-csail" / "mit-csail.clf", limit=5)
    s = mit.scans[0]
    assert len(s.ranges) == 361 and s.angles[0] == pytest.approx(-np.pi / 2)
    assert s.angles[-1] == pytest.approx(np.pi / 2)
    aces = read_carmen(DATA / "aces" / "aces.recon.clf", limit=3)
    assert np.degrees(aces.scans[0].angles[1] - aces.scans[0].angles[0]) == pytest.approx(1.0)
    clinic = read_carmen(DATA / "fr-clinic" / "fr-clinic.recon.clf", limit=3)
    assert clinic.scans[0].sensor_pose[0] == pytest.approx(0.22, abs=1e-3)
    assert len(clinic.scans[0].ranges) == 181


@needs_data
def test_ros_bag_matches_the_carmen_rebuild() -> None:
    bag = read_log(DATA / "aces" / "aces.orig.bag", limit=30)
    clf = read_log(DATA / "aces" / "aces.recon.clf", limit=30)
    assert np.allclose(bag.times, clf.times, atol=1e-6)
    assert np.allclose(bag.scans[10].ranges, clf.scans[10].ranges, atol=1e-4)
    assert np.allclose(bag.odometry[:, :2], clf.odometry[:, :2], atol=0.02)


@needs_data
def test_relation_metric_reproduces_the_raw_odometry_figures() -> None:
    """SOURCES.md: raw odometry on aces 0.549 ± 2.676 m / 2.32 ± 6.43 deg."""
    log = read_log(DATA / "aces" / "aces.recon.clf")
    rt, rd = read_relations(DATA / "aces" / "aces.relations")
    e = relation_errors(log.times, log.odometry, rt, rd)
    assert e.n == 1279 and e.missing == 0
    assert (round(e.trans_m, 3), round(e.trans_std_m, 3)) == (0.549, 2.676)
    assert (round(e.rot_deg, 2), round(e.rot_std_deg, 2)) == (2.32, 6.43)


def test_relation_metric_is_zero_for_the_truth_and_sees_a_bias(tmp_path: Path) -> None:
    t = np.arange(50) * 0.1
    truth = np.column_stack([0.1 * np.arange(50), np.zeros(50), 0.01 * np.arange(50)])
    rel_t = np.column_stack([t[:-5], t[5:]])
    rel = relative(truth[:-5], truth[5:])
    assert relation_errors(t, truth, rel_t, rel).trans_m == pytest.approx(0, abs=1e-12)
    scaled = truth.copy()
    scaled[:, 0] *= 1.1
    assert relation_errors(t, scaled, rel_t, rel).trans_m > 0.03
    with pytest.raises(InvalidInput):
        relation_errors(t + 100, truth, rel_t, rel)


def test_local_failures_are_short_relations_the_odometry_gets_right() -> None:
    """A straight drive at 0.3 m/s, relations 3 s long. The estimate stands still for
    2 s at t = 20 s (a scan that pulls the match along a hall): the relations that
    span the stop are 0.3-0.6 m short along the way and counted. Where the odometry is
    off as well (a 0.5 m sideways slip at t = 40 s, in both), nothing is counted: that
    is drift the odometry had, not the method's own failure."""
    t = np.arange(0.0, 60.0, 0.5)
    truth = np.column_stack([0.3 * t, np.zeros_like(t), np.zeros_like(t)])
    odom, est = truth.copy(), truth.copy()
    stop = (t >= 20.0) & (t < 22.0)
    est[stop, 0] = 0.3 * 20.0
    est[t >= 22.0, 0] -= 0.6
    for p in (odom, est):
        p[t >= 40.0, 1] += 0.5  # a wheel slip both carry
    rel_t = np.column_stack([t[:-6], t[6:]])
    rel = relative(truth[:-6], truth[6:])
    f = local_failures(t, est, t, odom, rel_t, rel)
    assert len(f) > 0
    assert np.all((f.t1 > 17.0) & (f.t1 < 22.0))
    assert np.all((f.error[:, 0] >= -0.6 - 1e-9) & (f.error[:, 0] < -0.3))  # short along
    assert np.allclose(f.error[:, 1:], 0.0)
    assert len(local_failures(t, truth, t, odom, rel_t, rel)) == 0


def test_tum_and_carmen_round_trip(tmp_path: Path, room_log) -> None:  # type: ignore[no-untyped-def]
    write_tum(tmp_path / "t.tum", room_log.times, room_log.truth)
    t, p = read_tum(tmp_path / "t.tum")
    assert np.allclose(t, room_log.times) and np.allclose(p, room_log.truth, atol=1e-5)
    short = room_log.head(20)
    write_carmen(tmp_path / "s.clf", short)
    back = read_log(tmp_path / "s.clf")
    assert len(back) == 20
    assert np.allclose(back.scans[3].ranges, short.scans[3].ranges, atol=1e-3)
    assert np.allclose(back.scans[3].intensities, short.scans[3].intensities, atol=1)
    assert np.allclose(back.scans[3].angles, short.scans[3].angles, atol=1e-5)


def test_scan_validation_names_the_field() -> None:
    ok = {"t": 0.0, "angles": np.zeros(3), "odom": np.zeros(3)}
    with pytest.raises(InvalidInput) as e:
        Scan(ranges=np.array([1.0, np.nan, 2.0]), **ok)  # type: ignore[arg-type]
    assert e.value.field == "ranges"
    with pytest.raises(InvalidInput) as e:
        Scan(ranges=np.ones(3), intensities=np.ones(2), **ok)  # type: ignore[arg-type]
    assert e.value.field == "intensities"
    with pytest.raises(InvalidInput):
        Scan(t=0.0, ranges=np.ones(0), angles=np.zeros(0), odom=np.zeros(3))


# -- laser simulator -----------------------------------------------------------------------
def test_laser_ranges_and_intensity_follow_the_world() -> None:
    desc = WorldDescription(name="w", walls=[
        {"a": [2, -5], "b": [2, 0], "reflectivity": 0.9},
        {"a": [2, 0], "b": [2, 5], "reflectivity": 0.1}])
    laser = Laser(World(desc), LaserConfig())
    r, i = laser.measure(np.array([0.0, 0.0, 0.0]))
    ang = LaserConfig().angles
    ahead = np.abs(ang) < 0.3
    assert np.allclose(r[ahead], 2 / np.cos(ang[ahead]), atol=1e-6)
    right, left = (ang < -0.05) & ahead, (ang > 0.05) & ahead
    assert i[right].min() > 3 * i[left].max()  # reflectivity 0.9 vs 0.1
    assert np.all(r[np.abs(ang) > np.radians(100)] == 5.6)  # nothing behind: no return
    assert len(ang) == 342 and np.degrees(ang[-1] - ang[0]) == pytest.approx(240, abs=0.5)


# -- Intensity-ICP -------------------------------------------------------------------------
def _pair(template: str, pose: np.ndarray, move: np.ndarray, seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    laser = Laser(World(from_template(template, "x")))
    s0 = laser.scan(0, pose, pose, rng)
    p0, i0 = s0.points()
    pose1 = compose(pose, move)
    s1 = laser.scan(0, pose1, pose1, rng)
    p1, i1 = s1.points()
    return place(p0, pose), i0, p1, i1, pose1


def test_icp_recovers_a_known_motion_in_a_room() -> None:
    ref_xy, ref_i, p1, i1, pose1 = _pair("room_a", np.array([5, 5, 0.3]),
                                         np.array([0.15, 0.02, 0.05]), 1)
    init = compose(pose1, [-0.1, 0.05, -0.05])
    for metric in ("point", "line"):
        res = intensity_icp(Reference(ref_xy, ref_i, 0.0), p1, i1, init,
                            IcpConfig(metric=metric, max_iterations=80))
        assert np.hypot(*(res.pose[:2] - pose1[:2])) < 0.02, metric
        assert abs(res.pose[2] - pose1[2]) < 0.01
        assert res.inliers > 150
    # the correction is reported in the initial estimate's frame
    assert np.allclose(compose(init, res.transform), res.pose, atol=1e-9)


def test_intensity_holds_where_geometry_slides() -> None:
    """In the stripe corridor geometric ICP cannot see motion along the walls; with the
    intensity term (eq. 1) the along-corridor error shrinks (10 seeded trials)."""
    rng = np.random.default_rng(3)
    err = {0.0: [], 1e-9: []}
    for k in range(10):
        pose = np.array([rng.uniform(8, 32), 1 + rng.normal(0, 0.1), rng.normal(0, 0.05)])
        ref_xy, ref_i, p1, i1, pose1 = _pair("corridor", pose, np.array([0.2, 0, 0.02]), k)
        init = compose(pose1, [rng.normal(0, 0.1), rng.normal(0, 0.03), rng.normal(0, 0.02)])
        for alpha in err:
            cfg = IcpConfig(alpha=alpha, trim_factor=100, max_iterations=100)
            res = intensity_icp(Reference(ref_xy, ref_i, alpha), p1, i1, init, cfg)
            err[alpha].append(abs(res.pose[0] - pose1[0]))
    assert np.mean(err[1e-9]) < 0.6 * np.mean(err[0.0])


def test_gate_of_eq5() -> None:
    g = GateConfig(eps_xy_m=0.05, eps_xy_ratio=0.0, eps_theta_rad=0.05, eps_theta_ratio=0.0)
    prev, u = np.array([1.0, 2.0, 0.5]), np.array([0.3, 0.0, 0.1])
    assert inside_gate(prev, compose(prev, u + [0.04, -0.04, 0.04]), u, g)
    assert not inside_gate(prev, compose(prev, u + [0.06, 0, 0]), u, g)
    assert not inside_gate(prev, compose(prev, u + [0, 0, -0.06]), u, g)


# -- SLAM runs in the simulator ------------------------------------------------------------
def _mean_err(poses: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(np.hypot(*(poses[:, :2] - truth[:, :2]).T)))


def test_gated_slam_beats_odometry_in_the_room(room_log) -> None:  # type: ignore[no-untyped-def]
    odo = _mean_err(room_log.odometry, room_log.truth)
    s = SingleHypothesisSlam(method="gated-icp")
    for scan in room_log.scans:
        s.process(scan)
    t, p = s.trajectory()
    assert len(t) == len(room_log) and np.allclose(t, room_log.times)
    assert _mean_err(p, room_log.truth) < 0.5 * odo
    assert 0 < s.accepted <= s.matched


def test_gated_slam_with_the_rbpf_matcher_is_one_deterministic_hypothesis(room_log) -> None:  # type: ignore[no-untyped-def]
    """Method ``gated``: one particle whose pose is the match's mean (no draw: two seeds
    give one trajectory), well below the odometry's error in the room."""
    from chizu.numeric.slam.rbpf import RbpfSlam
    from chizu.numeric.slam.runner import SlamOptions, run_log

    odo = _mean_err(room_log.odometry, room_log.truth)
    runs = []
    for seed in (0, 1):
        slam, res = run_log(room_log, SlamOptions(method="gated", seed=seed))
        runs.append(res.poses)
    assert isinstance(slam, RbpfSlam) and len(slam.x) == 1 and slam.reloc is None
    assert np.array_equal(runs[0], runs[1])
    assert _mean_err(runs[0], room_log.truth) < 0.5 * odo


def test_the_single_hypothesis_keeps_its_start_when_eq5_refuses_the_match() -> None:
    """Eq. 5 around the increment the front end started from: a match inside the box is
    taken, one outside it (or a failed one) leaves the start."""
    from chizu.numeric.slam.rbpf import RbpfConfig, RbpfSlam
    from chizu.numeric.slam.rbpf.improved import _single

    slam = RbpfSlam(RbpfConfig.single_hypothesis())
    slam.x = np.array([[1.0, 2.0, 0.5]])
    u = np.array([0.2, 0.0, 0.0])
    start = compose(slam.x[0], u)
    near = compose(slam.x[0], np.array([0.22, 0.01, 0.01]))
    far = compose(slam.x[0], np.array([0.6, 0.0, 0.0]))
    assert np.allclose(_single(slam, u, near, True)[0][0], near)
    assert np.allclose(_single(slam, u, far, True)[0][0], start)
    new, _, fell_back = _single(slam, u, near, False)
    assert np.allclose(new[0], start) and fell_back == 1


def test_rbpf_tracks_and_keeps_maps_without_copies(room_log) -> None:  # type: ignore[no-untyped-def]
    cfg = RbpfConfig(particles=64, seed=1, proposal="odometry")
    s = RbpfSlam(cfg)
    for scan in room_log.scans:
        s.process(scan)
    t, p = s.trajectory()
    assert p.shape == (len(room_log), 3)
    assert _mean_err(p, room_log.truth) < _mean_err(room_log.odometry, room_log.truth)
    assert s.x.shape == (64, 3) and s.resamples > 0
    mp = s.map_poses()
    assert mp.shape == (len(s.keyframes), 3)
    # the best particle's last keyframe pose is an ancestor of its current pose: the
    # trajectory passes through it at the keyframe's scan
    k = len(s.keyframes) - 1
    assert np.allclose(p[s.keyframes.frames[k].scan_index], mp[k], atol=1e-4)


def test_systematic_resampling_keeps_the_count_and_follows_weights() -> None:
    rng = np.random.default_rng(0)
    w = np.array([0.7, 0.1, 0.1, 0.1])
    idx = systematic_resample(w, rng)
    assert len(idx) == 4 and np.sum(idx == 0) in (2, 3)


# -- maps ----------------------------------------------------------------------------------
def test_occupancy_map_exports(room_log) -> None:  # type: ignore[no-untyped-def]
    s = SingleHypothesisSlam(method="odom")
    for scan in room_log.scans[:120]:
        s.process(scan)
    g = build_occupancy(s.keyframes.frames, s.map_poses(), 0.05)
    summ = g.summary()
    assert summ["free_m2"] > 5 and summ["occupied_m2"] > 0.5
    pgm = g.to_pgm()
    assert pgm.startswith(b"P5\n")
    w, h = g.shape
    assert f"\n{w} {h}\n255\n".encode() in pgm and len(pgm.split(b"255\n", 1)[1]) == w * h
    assert "resolution: 0.050000" in g.to_yaml() and "image: map.pgm" in g.to_yaml()
    png = Image.open(io.BytesIO(g.to_png()))
    assert png.size == (w, h)
    back = OccupancyMap.from_npz(g.to_npz())
    assert np.array_equal(back.state, g.state)


def test_unknown_regions_are_enclosed_components() -> None:
    st = np.full((40, 40), FREE, dtype=np.int8)
    st[:, :3] = UNKNOWN  # touches the border: not a region
    st[10:20, 10:20] = UNKNOWN  # 100 cells = 1 m² at 0.1 m
    st[30:32, 30:32] = UNKNOWN  # 0.04 m²: below the threshold
    st[9, 9:21] = OCCUPIED
    g = OccupancyMap(np.array([0.0, 0.0]), 0.1, st, np.full(st.shape, np.nan))
    regions = g.unknown_regions(0.5)
    assert len(regions) == 1
    assert regions[0]["area_m2"] == pytest.approx(1.0)
    assert regions[0]["x"] == pytest.approx(1.5) and regions[0]["y"] == pytest.approx(1.5)


# -- CLI -------------------------------------------------------------------------------------
def test_cli_slam_and_eval(tmp_path: Path) -> None:
    runner = CliRunner()
    log = tmp_path / "room.clf"
    r = runner.invoke(cli, ["slam-sim", "room_a", "--out", str(log)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    r = runner.invoke(cli, ["slam", str(log), "--method", "gated", "--out", str(out)])
    assert r.exit_code == 0, r.output
    for f in ("trajectory.tum", "map.png", "map.pgm", "map.yaml"):
        assert (out / f).stat().st_size > 0
    t, p = read_tum(out / "trajectory.tum")
    truth_t, truth = read_tum(Path(str(log) + ".truth.tum"))
    assert np.allclose(t, truth_t)  # one pose per scan, the log's own stamps
    # relations from the truth: every 10th scan
    rel = np.column_stack([truth_t[:-10:10], truth_t[10::10]])
    rels = np.column_stack([rel, relative(truth[:-10:10], truth[10::10])[:, [0, 1]],
                            np.zeros((len(rel), 3)), relative(truth[:-10:10], truth[10::10])[:, 2]])
    np.savetxt(tmp_path / "r.relations", rels)
    r = runner.invoke(cli, ["slam-eval", str(out / "trajectory.tum"),
                            str(tmp_path / "r.relations")])
    assert r.exit_code == 0 and "abs trans" in r.output
    r = runner.invoke(cli, ["slam", str(tmp_path / "missing.clf")])
    assert r.exit_code == 2
    r = runner.invoke(cli, ["slam", str(log), "--method", "magic"])
    assert r.exit_code == 2


def test_a_method_is_warmed_up_once_per_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """warm_up runs a throwaway estimator of the method (its kernels loaded before a
    robot's first scan), once per method and proposal; the next asks cost nothing."""
    import chizu.numeric.slam.runner as runner
    from chizu.numeric.slam.runner import SlamOptions

    monkeypatch.setattr(runner, "_WARM", set())
    opts = SlamOptions(method="rbpf", particles=64)
    assert runner.warm_up(opts) > 0.0
    assert runner.warm_up(opts) == 0.0
    assert runner.warm_up(opts.model_copy(update={"seed": 3})) == 0.0
    assert runner.warm_up(opts.model_copy(update={"proposal": "odometry"})) > 0.0
    assert runner._WARM == {("rbpf", "improved"), ("rbpf", "odometry")}
