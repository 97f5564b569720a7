"""Eigenspace localization (numeric): camera, eqs. 1-7, triplets, states, strategies."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from chizu.numeric.camera import Camera, CameraConfig
from chizu.numeric.eigenspace.analysis import (
    EigenspaceAnalysis,
    EigenspaceConfig,
    analyse,
    free_grid,
)
from chizu.numeric.eigenspace.interpolation import affine_weights, interpolate_pose
from chizu.numeric.eigenspace.learning import LearningStrategyConfig, f_d, learning_grid
from chizu.numeric.eigenspace.learning_strategy import hypothetical_gain
from chizu.numeric.eigenspace.localization import (
    LocalizationConfig,
    Session,
    TurnCandidates,
    session_from_dict,
    session_to_dict,
    turn_appearance,
    turn_candidates,
    whole_turn_fit,
)
from chizu.numeric.eigenspace.movement_strategy import (
    RegionLayout,
    StateBelief,
    StrategyConfig,
    apply_action,
    choose_action,
    initial_samples,
    session_belief,
    transition,
)
from chizu.numeric.eigenspace.regions import (
    EntryModel,
    RegionConfig,
    false_admissions,
    fit_c_a,
    fit_entry_model,
)
from chizu.numeric.eigenspace.triplets import TripletConfig, Triplets
from chizu.numeric.geometry import compose, invert, relative, wrap_angle
from chizu.numeric.world import Wall, World, WorldDescription
from chizu.numeric.worlds import room_a, room_b, room_c, room_d, twin_hexagon
from tests.eigenspace.conftest import SMALL


@pytest.fixture(scope="module")
def hexagon() -> tuple[World, EigenspaceAnalysis]:
    """The twin hexagon (symmetric under a half turn) and its analysis on the grid."""
    w = World(twin_hexagon())
    return w, analyse(w, EigenspaceConfig.model_validate(SMALL))


# -- camera ---------------------------------------------------------------------------------
def corridor(texture: str = "camera") -> World:
    return World(WorldDescription(name="c", walls=[
        Wall(a=(10, -5), b=(10, 5), texture=texture), Wall(a=(0, -5), b=(0, 5)),
        Wall(a=(0, -5), b=(10, -5)), Wall(a=(0, 5), b=(10, 5))]))


def wall_rows(img: np.ndarray, cfg: CameraConfig) -> int:
    """Rows of the centre column that show neither floor nor ceiling."""
    col = img[:, img.shape[1] // 2]
    return int(np.sum((np.abs(col - cfg.floor_level) > 1e-6)
                      & (np.abs(col - cfg.ceiling_level) > 1e-6)))


def test_camera_perspective_scales_with_inverse_distance() -> None:
    cfg = CameraConfig(width_px=64, height_px=64, supersample=1, wall_height_m=1.5,
                       camera_height_m=0.75, hfov_rad=np.deg2rad(90))
    cam = Camera(corridor(), cfg)
    near = wall_rows(cam.render(np.array([6.0, 0.0, 0.0])), cfg)   # 4 m from the wall
    far = wall_rows(cam.render(np.array([2.0, 0.0, 0.0])), cfg)    # 8 m
    assert far > 0
    assert near / far == pytest.approx(2.0, rel=0.15)


def test_camera_images_in_range_and_deterministic(room: World) -> None:
    cam = Camera(room)
    a = cam.render_turn(np.array([3.0, 3.0]), 0.2, 8)
    b = cam.render_many(np.column_stack([np.full(8, 3.0), np.full(8, 3.0),
                                         0.2 + 2 * np.pi * np.arange(8) / 8]))
    assert a.shape == (8, 32, 64) and 0 <= a.min() and a.max() <= 1
    np.testing.assert_allclose(a, b)
    assert np.std(a[0]) > 0.05  # a photograph, not a flat wall


def test_camera_sees_objects_and_lighting() -> None:
    a, d = World(room_a()), World(room_d())
    pose = np.array([5.0, 5.0, np.pi / 2])  # looking at the north wall (poster in D)
    ia, id_ = Camera(a).render(pose), Camera(d).render(pose)
    assert np.abs(ia - id_).mean() > 0.02
    for f in (room_b, room_c):
        assert len(World(f()).surfaces.a) > len(a.surfaces.a)


def test_unknown_texture_rejected() -> None:
    with pytest.raises(ValueError, match="unknown texture"):
        Wall(a=(0, 0), b=(1, 0), texture="no_such_photo")


# -- eqs. 1-5 -------------------------------------------------------------------------------
def test_eq2_difference_is_rms_of_projection_difference() -> None:
    a, b = np.zeros(4), np.array([2.0, 0, 0, 0])
    assert f_d(a, b, 16) == pytest.approx(2.0 / 4.0)


def test_learning_projection_reproduces_stored_projections(analysis: EigenspaceAnalysis,
                                                           room: World) -> None:
    m = analysis.model
    cam = Camera(room, analysis.config.camera)
    imgs = cam.render_turn(m.points[3], 0.0, len(m.directions))
    np.testing.assert_allclose(m.project(imgs), m.projections[3], atol=1e-9)


def test_interpolation_recovers_affine_weights_and_wraps_theta() -> None:
    rng = np.random.default_rng(0)
    x3 = rng.normal(size=(3, 6))
    k = np.array([0.2, 0.5, 0.3])
    x = k @ x3 + 0.0
    np.testing.assert_allclose(affine_weights(x, x3), k, atol=1e-9)
    s3 = np.array([[0, 0, np.pi - 0.1], [1, 0, -np.pi + 0.1], [0, 1, np.pi - 0.1]])
    s = interpolate_pose(np.array([0.25, 0.5, 0.25]), s3)
    assert s[0] == pytest.approx(0.5) and s[1] == pytest.approx(0.25)
    assert abs(wrap_angle(s[2] - np.pi)) < 1e-9  # the mean of +-(pi - 0.1) is pi, not 0


def test_compose_and_relative_are_inverse() -> None:
    p, d = np.array([1.0, 2.0, 2.5]), np.array([0.5, -0.3, 1.0])
    np.testing.assert_allclose(relative(p, compose(p, d)), d, atol=1e-12)


def test_invert_undoes_a_pose_on_either_side() -> None:
    poses = np.array([[1.0, 2.0, 2.5], [-3.0, 0.5, -3.0], [0.0, 0.0, 0.0]])
    for p in poses:
        np.testing.assert_allclose(compose(p, invert(p)), 0.0, atol=1e-12)
        np.testing.assert_allclose(compose(invert(p), p), 0.0, atol=1e-12)
    np.testing.assert_allclose(invert(poses), [relative(p, np.zeros(3)) for p in poses])
    assert invert(poses[0])[2] == pytest.approx(-2.5)


# -- §2.3 triplets, §2.4 regions --------------------------------------------------------------
def test_triplets_satisfy_the_search_conditions(analysis: EigenspaceAnalysis) -> None:
    m, t = analysis.model, analysis.triplets
    cfg = TripletConfig()
    assert len(t) > 10
    for i in range(len(t)):
        pts, th = m.points[t.point_idx[i]], m.directions[t.dir_idx[i]]
        dmax = max(np.linalg.norm(pts[a] - pts[b]) for a in range(3) for b in range(3))
        assert dmax <= cfg.neighbour_max_m + 1e-9
        # all three rays pass within D_alpha of the common target, in front of the points
        for p, a in zip(pts, th, strict=True):
            u = np.array([np.cos(a), np.sin(a)])
            v = t.target[i] - p
            assert v @ u > 0
            assert abs(u[0] * v[1] - u[1] * v[0]) <= cfg.d_alpha_m
        assert max(abs(wrap_angle(th[0] - th[1])), abs(wrap_angle(th[0] - th[2]))) \
            < cfg.theta_alpha_rad


def test_learning_image_of_a_triplet_lies_in_its_region(analysis: EigenspaceAnalysis) -> None:
    m, t = analysis.model, analysis.triplets
    w, j = t.point_idx[0, 1], t.dir_idx[0, 1]
    imgs_proj = m.projections[w]  # the learning turn at w
    from chizu.numeric.eigenspace.regions import region_candidates

    c = region_candidates(m, t, imgs_proj, analysis.c_a, analysis.config.regions.d_thd_m)
    hit = (c.t == 0) & (c.m == j)
    assert hit.any() and c.d[hit][0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(c.pose[hit][0], [*m.points[w], m.directions[j]], atol=1e-6)


def test_fits_recover_known_constants() -> None:
    rng = np.random.default_rng(1)
    d, area = rng.uniform(0, 0.1, 200), rng.uniform(1, 4, 200)
    assert fit_c_a(d, area, 5.0 * d / np.sqrt(area)) == pytest.approx(5.0)
    dist = rng.uniform(0, 3, (400, 3))
    entered = rng.random((400, 3)) < np.clip(0.8 - 0.3 * dist, 0, 1)
    e = fit_entry_model(dist, entered, 3.0)
    assert e.c0 == pytest.approx(0.8, abs=0.12) and e.c1 == pytest.approx(-0.3, abs=0.08)


def test_triplets_that_place_other_learning_images_wrong_are_rejected(
        analysis: EigenspaceAnalysis) -> None:
    """Room A has false triplets (a bland image matches turns from metres away); the
    analysis drops them, and no kept triplet's region places a learning image of
    another point more than 1 m or 15 deg off."""
    loc = analysis.config.localization
    r = analysis.config.regions
    bad, _ = false_admissions(analysis.model, analysis.triplets, analysis.c_a, r.d_thd_m,
                              loc.same_position_m, loc.same_heading_rad, r.plane_thd_m)
    assert analysis.rejected_triplets > 0
    assert len(bad) == len(analysis.triplets) > 0 and not bad.any()


def test_a_symmetric_room_keeps_its_twins_in_candidate_multiple_sets(
        hexagon: tuple[World, EigenspaceAnalysis]) -> None:
    """In the twin hexagon every place has a look-alike. Its triplets admit each
    other's images, which alone would reject them all; as twins grouped by §3.3's
    candidate-multiple sets they stay, and a stop that enters regions is ambiguous
    (hits within one set, no unique vote) instead of a confident pose."""
    w, a = hexagon
    cfg = a.config
    r, loc = cfg.regions, cfg.localization
    bad, twins = false_admissions(a.model, a.triplets, a.c_a, r.d_thd_m,
                                  loc.same_position_m, loc.same_heading_rad, r.plane_thd_m)
    assert len(a.triplets) > 10 and twins and not bad.any()
    assert a.candidate_sets
    set_of = a.set_of()
    cam, rng = Camera(w, cfg.camera), np.random.default_rng(0)
    entered = 0
    for p in w.sample_free(30, rng):
        s = Session(loc)
        s.add_stop(turn_candidates(a.regions, cam.render_turn(p, rng.uniform(-3, 3), 72)),
                   r.d_thd_m)
        if not s.triplet:
            continue
        entered += 1
        assert len({int(set_of[t]) for t in s.triplet}) == 1 and min(set_of[s.triplet]) >= 0
        assert not s.vote().unique
    assert entered >= 2


def test_a_room_learning_found_symmetric_localizes_without_the_whole_turn_check(
        analysis: EigenspaceAnalysis) -> None:
    """Where §4.2 learned an added point's twin, a look-alike place explains a whole
    turn as well as the right one: the room's localization has no whole-turn check.
    Elsewhere it keeps the configuration's."""
    assert analysis.localization.turn_check_fd == analysis.config.localization.turn_check_fd
    assert analysis.localization.turn_check_fd is not None
    twin = replace(analysis, strategy_trace=[{"added": [3.0, 2.0], "twin": [7.0, 6.0]}])
    assert twin.localization.turn_check_fd is None
    assert twin.localization.turn_min_range_m == analysis.config.localization.turn_min_range_m


def test_the_learned_turns_show_a_rooms_symmetry(hexagon: tuple[World, EigenspaceAnalysis],
                                                 analysis: EigenspaceAnalysis) -> None:
    """The twin hexagon is symmetric under a half turn about (5, 4): its grid points'
    turns are matched by far points' turns turned by 180 deg, and those pairs agree on
    that motion. Room A has no twins."""
    from chizu.numeric.eigenspace.twins import twin_transform

    t = twin_transform(hexagon[1].model)
    assert t is not None and t.pairs >= 8
    assert abs(abs(wrap_angle(t.phi)) - np.pi) < 0.1
    np.testing.assert_allclose(t.apply(np.array([3.0, 2.0])), [7.0, 6.0], atol=0.3)
    assert twin_transform(analysis.model) is None


def test_the_learning_strategy_learns_an_added_points_twin_in_a_symmetric_room(
        hexagon: tuple[World, EigenspaceAnalysis]) -> None:
    """An added point alone has no look-alike learning point, so its triplets form no
    candidate-multiple set, and a turn at its twin place enters them and is placed on
    the wrong side. Learned with its twin, the added triplets are grouped with the
    twin's (§3.3): no hit outside a set is placed wrong, and no turn there is answered."""
    from chizu.numeric.eigenspace.learning_strategy import learning_strategy
    from chizu.numeric.eigenspace.twins import twin_transform

    w, base = hexagon
    cfg = base.config
    lcfg = LearningStrategyConfig(target_probability=1.0, max_additions=6)
    res = learning_strategy(base, w, lcfg, np.random.default_rng(0))
    added = [s for s in res.steps if s.added is not None]
    assert len(added) == 6 and all(s.twin is not None for s in added)
    for s in added:  # the twin is the point turned half about the hexagon's centre
        np.testing.assert_allclose(np.add(s.added, s.twin), [10.0, 8.0], atol=0.6)
    assert len(res.analysis.model.points) == len(base.model.points) + 12
    single = learning_strategy(base, w, lcfg.model_copy(update={"learn_twins": False}),
                               np.random.default_rng(0))
    assert len(single.analysis.model.points) == len(base.model.points) + 6
    # turns at the twin places of the points added alone, which see what they saw
    cam, rng = Camera(w, cfg.camera), np.random.default_rng(1)
    twin = twin_transform(base.model)
    assert twin is not None
    poses = [(twin.apply(np.array(st.added)) + rng.uniform(-0.2, 0.2, 2), rng.uniform(-3, 3))
             for st in single.steps if st.added is not None for _ in range(4)]

    def outcome(a: EigenspaceAnalysis) -> tuple[int, int]:
        """(unique answers, hits outside any candidate set placed more than 1 m off)"""
        unique = wrong = 0
        set_of = a.set_of()
        for p, th in poses:
            s = Session(cfg.localization)
            c = s.add_stop(turn_candidates(a.regions, cam.render_turn(p, th, 72)),
                           cfg.regions.d_thd_m)
            unique += bool(s.triplet) and s.vote(set_of).unique
            off = np.linalg.norm(c.start_pose[:, :2] - p, axis=1) > 1.0
            wrong += int((off & (set_of[c.t] < 0)).sum())
        return unique, wrong

    assert outcome(res.analysis) == (0, 0)
    assert outcome(single.analysis)[1] > 0


# -- §2.5 localization ------------------------------------------------------------------------
def test_multi_stop_localization_in_room_a(analysis: EigenspaceAnalysis, room: World) -> None:
    """Seeded trials: the voted pose is close to the truth when the vote is unique."""
    rng = np.random.default_rng(3)
    cam = Camera(room, analysis.config.camera.model_copy(update={"noise_sigma": 0.01}), rng=rng)
    n = len(analysis.model.directions)
    errors = []
    for p in room.sample_free(12, rng, clearance_m=0.8):
        pose = np.array([*p, rng.uniform(-np.pi, np.pi)])
        s = Session(LocalizationConfig())
        prev = pose.copy()
        for _stop in range(3):
            c = turn_candidates(analysis.regions, cam.render_turn(pose[:2], pose[2], n))
            s.add_stop(c, analysis.config.regions.d_thd_m, motion=relative(prev, pose))
            v = s.vote()
            if v.unique and v.winner is not None:
                errors.append(np.linalg.norm(s.estimate(v)[:2] - pose[:2]))
                break
            prev = pose.copy()
            pose = apply_action(pose[None], np.array([0.0, 1.0, 0.0]),
                                (room.surfaces.a, room.surfaces.b), 0.3)[0]
    assert len(errors) >= 6
    assert np.median(errors) < 1.0


@pytest.mark.parametrize(("d_err", "unique"), [((0.19,), False), ((0.0,), True),
                                               ((0.1, 0.1), True), ((0.19, 0.19), False)])
def test_a_weak_answer_without_rivals_is_not_unique(d_err: tuple[float, ...],
                                                    unique: bool) -> None:
    """A group needs min_votes (1.0) to be unique even with no rival: one hit just
    inside D_thd (weight 0.05) is not a localization, one exact hit or two halfway
    hits that agree are."""
    s = Session(LocalizationConfig())
    n = len(d_err)
    poses = np.tile([2.0, 3.0, 0.5], (n, 1)) + np.arange(n)[:, None] * [0.1, 0.0, 0.0]
    s.add_stop(TurnCandidates(np.arange(n), np.array(d_err), poses, np.zeros(n, int)), 0.2)
    assert s.vote().unique is unique


def test_a_lead_within_one_candidate_set_is_not_unique() -> None:
    """Hits only on triplets of one candidate-multiple set (look-alike places) never
    make a unique vote, however strong; a later hit outside the set lets the vote
    decide (odometry carries the first stop's candidates to it)."""
    set_of = np.array([0, 0, -1])
    s = Session(LocalizationConfig())
    poses = np.array([[2.0, 3.0, 0.0], [8.0, 5.0, np.pi]])  # twins
    s.add_stop(TurnCandidates(np.array([0, 1]), np.array([0.0, 0.1]), poses,
                              np.zeros(2, int)), 0.2)
    assert s.vote().unique and not s.vote(set_of).unique
    # one metre ahead, a triplet in no set confirms the first twin
    s.add_stop(TurnCandidates(np.array([2]), np.array([0.0]), np.array([[3.0, 3.0, 0.0]]),
                              np.zeros(1, int)), 0.2, motion=np.array([1.0, 0.0, 0.0]))
    v = s.vote(set_of)
    assert v.unique and np.allclose(s.estimate(v)[:2], [3.0, 3.0], atol=0.05)


def test_the_estimate_is_the_weighted_mean_of_the_winning_group() -> None:
    """Three candidates agree near (2, 3), one lies far away: the answer is their
    weighted mean (weights 1 - D_err/D_thd), heading on the circle, carried by the
    odometry to the latest stop."""
    s = Session(LocalizationConfig())
    poses = np.array([[2.0, 3.0, 3.1], [2.4, 3.0, -3.1], [2.0, 3.4, 3.1], [8.0, 1.0, 0.0]])
    d_err = np.array([0.0, 0.1, 0.15, 0.18])  # weights 1, 0.5, 0.25, 0.1 at D_thd 0.2
    s.add_stop(TurnCandidates(np.arange(4), d_err, poses, np.zeros(4, dtype=int)), 0.2)
    s.add_stop(TurnCandidates(np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                              np.zeros(0, int)), 0.2, motion=np.array([1.0, 0.0, 0.0]))
    v = s.vote()
    assert v.unique and v.winner == 0
    w = np.array([1.0, 0.5, 0.25])
    now = compose(poses[:3], np.array([1.0, 0.0, 0.0]))  # each carried to stop 2
    th = np.arctan2(w @ np.sin(now[:, 2]), w @ np.cos(now[:, 2]))
    assert np.allclose(s.estimate(v), [*((w @ now[:, :2]) / w.sum()), th])
    assert abs(th) > 3.0  # the mean of 3.1 and -3.1 rad is pi, not 0


def test_the_whole_turn_fit_finds_a_learning_point_and_the_middle_of_two(
        analysis: EigenspaceAnalysis, room: World) -> None:
    """A noiseless turn at a learning point comes back at that point from an estimate
    0.4 m off; a turn halfway between two points lands between them, nearer the truth
    than the estimate it started from. Images of near walls are left out; with every
    image left out there is no answer, unless a nearer bound is allowed to fall back to."""
    m = analysis.model
    walls = (room.surfaces.a, room.surfaces.b)
    cam = Camera(room, analysis.config.camera)
    n = len(m.directions)
    i = int(np.argmin(np.linalg.norm(m.points - [5.0, 5.0], axis=1)))  # a middle point
    q = m.project(cam.render_turn(m.points[i], 0.3, n))
    start = np.array([*(m.points[i] + [0.3, -0.25]), 0.3])
    fit = whole_turn_fit(m, q, start, walls, 4.0)
    assert fit is not None and np.linalg.norm(fit.pose[:2] - m.points[i]) < 0.15
    j = int(np.argmin(np.linalg.norm(m.points - (m.points[i] + [2.0, 0.0]), axis=1)))
    mid = (m.points[i] + m.points[j]) / 2
    q = m.project(cam.render_turn(mid, -1.0, n))
    start = np.array([*(mid + [0.0, 0.4]), -1.0])
    fit = whole_turn_fit(m, q, start, walls, 4.0)
    assert fit is not None and np.linalg.norm(fit.pose[:2] - mid) < 0.4 * 0.75
    assert whole_turn_fit(m, q, start, walls, 100.0) is None
    # too few walls that far: the fit falls back to the near bound, and only then
    back = whole_turn_fit(m, q, start, walls, 100.0, near_range_m=4.0)
    assert back is not None and np.allclose(back.pose, fit.pose)
    unused = whole_turn_fit(m, q, start, walls, 4.0, near_range_m=100.0)
    assert unused is not None and np.allclose(unused.pose, fit.pose)


def test_the_whole_turn_fit_finds_the_heading_the_start_missed(
        analysis: EigenspaceAnalysis, room: World) -> None:
    """A turn started 6 degrees off its estimate's heading: the heading scan comes back
    within 1.5 degrees of the truth and the position lands nearer the truth than
    without the scan (the fit held at the estimate's heading compares each image with
    the wrong learned directions)."""
    m = analysis.model
    walls = (room.surfaces.a, room.surfaces.b)
    cam = Camera(room, analysis.config.camera)
    truth = np.array([4.6, 5.3, 0.7])
    q = m.project(cam.render_turn(truth[:2], truth[2], len(m.directions)))
    start = np.array([4.8, 5.1, truth[2] + np.deg2rad(6.0)])
    scan_fit = whole_turn_fit(m, q, start, walls, 4.0)
    held_fit = whole_turn_fit(m, q, start, walls, 4.0, heading_span_rad=0.0)
    assert scan_fit is not None and held_fit is not None
    scanned, held = scan_fit.pose, held_fit.pose
    assert scan_fit.residual < held_fit.residual
    assert held[2] == pytest.approx(start[2])
    assert abs(wrap_angle(scanned[2] - truth[2])) < np.deg2rad(1.5)
    assert np.linalg.norm(scanned[:2] - truth[:2]) < np.linalg.norm(held[:2] - truth[:2])


def test_the_estimate_averages_eq5_with_the_whole_turn(analysis: EigenspaceAnalysis,
                                                       room: World) -> None:
    """Given the eigenspace and the walls, the position is the mean of eq. 5's and the
    whole turn's, and the heading is the whole turn's; without them, or with
    turn_min_range_m None, eq. 5's alone. The latest turn survives the store."""
    m = analysis.model
    walls = (room.surfaces.a, room.surfaces.b)
    cam = Camera(room, analysis.config.camera)
    truth = np.array([4.6, 5.3, 0.7])
    q = m.project(cam.render_turn(truth[:2], truth[2], len(m.directions)))
    eq5 = np.array([4.9, 5.0, 0.75])
    for cfg in (LocalizationConfig(), LocalizationConfig(turn_min_range_m=None)):
        s = Session(cfg)
        s.add_stop(TurnCandidates(np.array([0]), np.array([0.0]), eq5[None],
                                  np.zeros(1, int), projections=q), 0.2)
        v = s.vote()
        assert np.allclose(s.estimate(v), eq5)
        rng = LocalizationConfig().turn_min_range_m
        assert rng is not None
        fit = whole_turn_fit(m, q, eq5, walls, rng)
        assert fit is not None
        turn = fit.pose
        both = s.estimate(v, m, walls)
        if cfg.turn_min_range_m is None:
            assert np.allclose(both, eq5)
        else:
            assert np.allclose(both, [*((eq5[:2] + turn[:2]) / 2), turn[2]])
            assert np.linalg.norm(both[:2] - truth[:2]) < np.linalg.norm(eq5[:2] - truth[:2])
            assert abs(wrap_angle(both[2] - truth[2])) < abs(wrap_angle(eq5[2] - truth[2]))
        back = session_from_dict(session_to_dict(s))
        assert back.last_turn is not None and np.allclose(back.last_turn, q, atol=1e-5)
        assert np.allclose(back.estimate(back.vote(), m, walls), both, atol=1e-4)


def test_the_whole_turn_check_answers_a_turn_the_plane_test_refuses(
        analysis: EigenspaceAnalysis, room: World) -> None:
    """A turn none of whose images passes the plane test: eq. 6 on d alone admits some,
    and the whole turn fitted at their place explains every image, so the stop is
    answered there. Without the walls, or with turn_check_fd None, it has no hit."""
    m = analysis.model
    walls = (room.surfaces.a, room.surfaces.b)
    cam = Camera(room, analysis.config.camera)
    truth = np.array([8.71, 2.75, 2.01])
    imgs = cam.render_turn(truth[:2], truth[2], len(m.directions))
    cfg = LocalizationConfig()
    assert len(turn_candidates(analysis.regions, imgs)) == 0
    off = turn_candidates(analysis.regions, imgs, walls, LocalizationConfig(turn_check_fd=None))
    assert len(off) == 0 and off.checked is None
    c = turn_candidates(analysis.regions, imgs, walls, cfg)
    assert c.checked is not None and len(c) > 0
    assert np.linalg.norm(c.checked[:2] - truth[:2]) < 0.5
    s = Session(cfg)
    s.add_stop(c, analysis.config.regions.d_thd_m)
    v = s.vote(analysis.set_of())
    assert v.unique
    est = s.estimate(v, m, walls)
    assert np.linalg.norm(est[:2] - truth[:2]) < 0.5
    assert abs(wrap_angle(est[2] - truth[2])) < np.deg2rad(5.0)


def test_the_whole_turn_check_answers_only_one_place(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two places eq. 6 admits, 3 m apart: when the whole turn fits both, the check
    does not answer; when only one fits, it answers that one with its own hits."""
    import chizu.numeric.eigenspace.localization as loc
    start = np.array([[1.0, 1.0, 0.0], [1.2, 1.1, 0.05], [4.0, 1.0, 0.0]])
    d_err = np.array([0.05, 0.1, 0.02])
    residual = {1.0: 0.01, 4.0: 0.01}

    def fit(model: object, q: np.ndarray, pose: np.ndarray, *a: object) -> loc.TurnFit:
        return loc.TurnFit(np.asarray(pose, dtype=float), residual[float(pose[0])])

    monkeypatch.setattr(loc, "whole_turn_fit", fit)
    cfg = LocalizationConfig()
    walls = (np.zeros((0, 2)), np.zeros((0, 2)))
    assert loc.whole_turn_check(None, np.zeros((8, 2)), start, d_err, walls, cfg) is None  # type: ignore[arg-type]
    residual[4.0] = 0.05  # above turn_check_fd
    got = loc.whole_turn_check(None, np.zeros((8, 2)), start, d_err, walls, cfg)  # type: ignore[arg-type]
    assert got is not None
    assert np.allclose(got[0], start[0]) and got[1].tolist() == [True, True, False]


def test_a_place_the_whole_turn_check_found_wins_the_vote() -> None:
    """Three strong hits agree on one place, one weak hit names another: the vote
    takes the strong place, unless the turn's check found the weak one and that one is
    in no candidate-multiple set. The check speaks for its own stop only, and survives
    the store."""
    poses = np.array([[2.0, 2.0, 0.0], [2.2, 2.0, 0.0], [2.0, 2.3, 0.0], [6.0, 5.0, 1.0]])
    d_err = np.array([0.0, 0.0, 0.0, 0.15])

    def stop(checked: np.ndarray | None) -> TurnCandidates:
        return TurnCandidates(np.arange(4), d_err, poses, np.zeros(4, dtype=int),
                              checked=checked)

    plain = Session(LocalizationConfig())
    plain.add_stop(stop(None), 0.2)
    v = plain.vote()
    assert v.unique and v.winner in (0, 1, 2) and not v.checked
    s = Session(LocalizationConfig())
    s.add_stop(stop(np.array([6.1, 5.0, 1.0])), 0.2)
    v = s.vote()
    assert v.unique and v.winner == 3 and v.checked
    # a checked place among look-alike places (its hit in a candidate-multiple set) is
    # no answer: the vote is as it would be without the check
    in_set = np.array([-1, -1, -1, 0])
    v = s.vote(in_set)
    assert v.winner in (0, 1, 2) and not v.checked
    assert s.vote(np.full(4, -1)).winner == 3
    back = session_from_dict(session_to_dict(s))
    assert back.checked[0] is not None and np.allclose(back.checked[0], [6.1, 5.0, 1.0])
    assert back.vote().winner == 3
    s.add_stop(TurnCandidates(np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                              np.zeros(0, int)), 0.2, motion=np.zeros(3))
    assert s.vote().winner in (0, 1, 2)


# -- §3.5 movement strategy -------------------------------------------------------------------
UNIT_ENTRY = EntryModel(1.0, -1.0)


def layout_one_region(xy: tuple[float, float], walls: World,
                      entry: EntryModel = UNIT_ENTRY) -> RegionLayout:
    pts = np.array([[xy, (xy[0] + 0.5, xy[1]), (xy[0], xy[1] + 0.5)]], dtype=float)
    return RegionLayout(entry, pts, np.array([-1]),
                        (walls.surfaces.a, walls.surfaces.b))


def test_entry_probabilities_use_the_nearest_of_each_triplets_points(room: World) -> None:
    """Eq. 7 with D(s) of §3.2: the distance to the nearest of a triplet's three
    learning points, the points shared between triplets as in a learning grid."""
    rng = np.random.default_rng(4)
    grid = rng.uniform(0, 10, (8, 2))
    pts = grid[rng.integers(0, 8, (20, 3))]
    lay = RegionLayout(EntryModel(0.9, -0.3), pts, np.full(20, -1),
                       (room.surfaces.a, room.surfaces.b))
    xy = rng.uniform(0, 10, (50, 2))
    d = np.linalg.norm(xy[:, None, None, :] - pts[None], axis=-1).min(axis=2)
    np.testing.assert_allclose(lay.entry_probabilities(xy), np.clip(0.9 - 0.3 * d, 0, 1))


def test_state_probabilities_sum_to_one_and_z_absorbs(room: World) -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(1, 9, (6, 3, 2))
    lay = RegionLayout(EntryModel(0.6, -0.3), pts, np.array([0, 0, 1, 1, -1, -1]),
                       (room.surfaces.a, room.surfaces.b))
    b = StateBelief.start(50, lay.n_sets)
    for _ in range(3):
        b = transition(b, lay.entry_probabilities(rng.uniform(1, 9, (50, 2))), lay)
        np.testing.assert_allclose(b.x + b.y.sum(axis=1) + b.z, 1.0, atol=1e-12)
    z = StateBelief(np.zeros(5), np.zeros((5, 2)), np.ones(5), np.full(5, 0.2))
    assert transition(z, np.zeros((5, 6)), lay).p_z() == pytest.approx(1.0)
    x = StateBelief.start(5, 2)
    assert transition(x, np.zeros((5, 6)), lay).p_z() == pytest.approx(0.0)


def test_strategy_drives_towards_the_only_region(room: World) -> None:
    lay = layout_one_region((6.3, 5.0), room)
    poses = np.array([[2.0, 5.0, np.pi / 2]])  # facing north; the region is east
    dec = choose_action(poses, StateBelief.start(1, 0), lay, StrategyConfig())
    assert dec.action[0] == pytest.approx(-np.pi / 2)  # turn right ...
    assert dec.action[1] == pytest.approx(4.0)          # ... and drive as far as allowed
    assert 0.0 < dec.q_z < 1.0


def test_turn_appearance_is_smallest_at_the_learning_point_and_heading(
        analysis: EigenspaceAnalysis, room: World) -> None:
    """A turn rendered at learning point 7 starting at direction 10 matches that point's
    own turn shifted by 10 (A = 0 there, up to pixel noise), and nothing else as well."""
    m = analysis.model
    n = len(m.directions)
    cam = Camera(room, analysis.config.camera)
    q = m.project(cam.render_turn(m.points[7], m.directions[10], n))
    a = turn_appearance(m, q)
    assert a is not None and a.shape == (len(m.points), n)
    assert np.unravel_index(int(np.argmin(a)), a.shape) == (7, 10)
    assert a[7, 10] < 1e-4 < np.sort(a, axis=None)[1]
    assert turn_appearance(m, q[::2]) is None  # a turn of another length: no shift
    # a turn with region hits leaves state X, where the appearance serves: none kept
    hit = turn_candidates(analysis.regions, cam.render_turn(m.points[7], m.directions[10], n))
    assert len(hit) > 0 and hit.appearance is None


@pytest.mark.parametrize("tau", [StrategyConfig().appearance_tau, None])
def test_appearance_narrows_where_the_robot_may_be_while_in_x(
        analysis: EigenspaceAnalysis, room: World, tau: float | None) -> None:
    """Eq. 8's samples of stop 0, weighed by a turn's appearance, gather near the true
    pose and heading; with ``appearance_tau`` null (the paper) they stay spread over the
    room."""
    cfg = StrategyConfig(appearance_tau=tau, n_samples=200)
    lay = analysis.layout(room)
    rng = np.random.default_rng(1)
    cam = Camera(room, analysis.config.camera.model_copy(update={"noise_sigma": 0.01}),
                 rng=rng)
    n = len(analysis.model.directions)
    for p in room.sample_free(50, rng):  # the first pose whose turn enters no region
        pose = np.array([*p, rng.uniform(-np.pi, np.pi)])
        c = turn_candidates(analysis.regions, cam.render_turn(pose[:2], pose[2], n))
        if len(c) == 0:
            break
    assert len(c) == 0
    s = Session(LocalizationConfig())
    s.add_stop(c, 0.2)
    samples0 = initial_samples(room.sample_free, cfg.appearance_samples,
                               np.random.default_rng(2))
    now, belief = session_belief(s, lay, samples0, config=cfg)
    w = belief.weight / belief.weight.sum()
    off = np.hypot(now[:, 0] - pose[0], now[:, 1] - pose[1])
    turn = np.abs(wrap_angle(now[:, 2] - pose[2]))
    near = float(w @ (off < 1.5))
    facing = float(w @ (turn < np.deg2rad(20)))
    if tau is None:  # measured: 0.05 near, 0.11 facing
        assert len(now) == cfg.appearance_samples
        assert near < 0.2 and facing < 0.25
    else:  # measured: 0.88 near, 1.0 facing
        assert len(now) == cfg.n_samples
        assert near > 0.7 and facing > 0.8


def test_sessions_keep_their_turns_appearance_through_the_store() -> None:
    s = Session(LocalizationConfig())
    app = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    s.add_stop(TurnCandidates(np.zeros(0, int), np.zeros(0), np.zeros((0, 3)), np.zeros(0, int),
                              app), 0.2)
    s.add_stop(TurnCandidates(np.zeros(0, int), np.zeros(0), np.zeros((0, 3)), np.zeros(0, int)),
               0.2, np.array([1.0, 0.0, 0.0]))
    b = session_from_dict(session_to_dict(s))
    assert b.appearance[1] is None and b.appearance[0] is not None
    np.testing.assert_allclose(b.appearance[0], app, atol=1e-5)
    old = session_to_dict(s)
    del old["appearance"]  # stored before the appearance was kept
    assert session_from_dict(old).appearance == []


def test_hypothetical_gain_prefers_uncovered_space(room: World) -> None:
    lay = layout_one_region((2.0, 2.0), room, EntryModel(1.0, -0.25))  # 2 m radius
    pts = np.array([[1, 1], [3, 1], [1, 3], [3, 3], [7, 7], [9, 7], [7, 9]], dtype=float)
    grid = np.array([(x, y) for x in np.arange(0.5, 10, 0.5) for y in np.arange(0.5, 10, 0.5)])
    g = hypothetical_gain(lay, pts, np.array([[2.0, 2.0], [8.0, 8.0], [5.0, 0.5]]), grid,
                          2.9, 0.05)
    assert g[1] > g[0] > 0  # around (2, 2) much is covered already
    assert g[2] == 0  # (5, 0.5) has no neighbour pair within 2.9 m


def test_analysis_roundtrip(analysis: EigenspaceAnalysis, room: World) -> None:
    b = EigenspaceAnalysis.from_bytes(analysis.to_bytes())
    assert b.summary(room)["triplets"] == analysis.summary(room)["triplets"]
    np.testing.assert_array_equal(b.model.projections, analysis.model.projections)


# -- §4.2 learning strategy -----------------------------------------------------------------
def test_learning_strategy_does_not_learn_where_a_point_is(
        analysis: EigenspaceAnalysis, room: World, monkeypatch: pytest.MonkeyPatch) -> None:
    """A candidate that already has a learning point is no candidate: when its triplets
    are all rejected it gains nothing, stays the best, and was learned again and again."""
    import chizu.numeric.eigenspace.learning_strategy as ls

    cfg = ls.LearningStrategyConfig()
    spot = free_grid(room, cfg.candidate_spacing_m)[40]
    learned = replace(analysis, model=replace(
        analysis.model, points=np.vstack([analysis.model.points, spot])))
    # make the spot the best candidate by far
    monkeypatch.setattr(ls, "hypothetical_gain", lambda lay, pts, cand, *a: -np.linalg.norm(
        cand - spot, axis=1))
    assert np.allclose(ls.choose_learning_point(analysis, room, cfg, 0.0,
                                                np.random.default_rng(0)), spot)
    p = ls.choose_learning_point(learned, room, cfg, 0.0, np.random.default_rng(0))
    assert p is not None and np.linalg.norm(p - spot) >= cfg.candidate_spacing_m / 2


def test_learn_with_strategy_adds_points_and_keeps_the_trace(room: World) -> None:
    from chizu.numeric.eigenspace.learning_strategy import learn_with_strategy

    cfg = EigenspaceConfig.model_validate({
        **SMALL, "strategy": {"n_samples": 40},
        "learning_strategy": {"target_probability": 1.0, "max_additions": 2}})
    stages: list[str] = []
    a = learn_with_strategy(room, cfg, lambda stage, frac: stages.append(stage))
    grid = len(learning_grid(room, cfg.learning.spacing_m, cfg.learning.margin_m))
    assert len(a.model.points) == grid + 2
    steps, checked = a.strategy_trace[:-1], a.strategy_trace[-1]
    assert [s["added"] is None for s in steps] == [True, False, False]
    assert [s["learning_points"] for s in steps] == [grid, grid + 1, grid + 2]
    # the last entry: P(Z) once the added points' triplets have met the probes
    assert checked["checked"] and checked["triplets"] == len(a.triplets)
    assert checked["learning_points"] == grid + 2 and len(checked["p_z"]) == 5
    added = np.array([s["added"] for s in steps[1:]])
    np.testing.assert_allclose(a.model.points[grid:], added)
    assert any(s.startswith("learning strategy") for s in stages)
    b = EigenspaceAnalysis.from_bytes(a.to_bytes())
    assert b.strategy_trace == a.strategy_trace
    assert b.summary(room)["learning_strategy"] == a.strategy_trace


def test_a_region_that_places_near_probes_wrong_is_rejected(
        analysis: EigenspaceAnalysis) -> None:
    """A probe turn 1.3 m from a triplet (not far: the far test lets it pass) that the
    region admits and eq. 5 places 1.3 m off makes the triplet imprecise: it goes
    with ``max_wrong_share``, and stays with it off."""
    from chizu.numeric.eigenspace.analysis import (
        EntryObservations,
        far_admissions,
        probe_validated,
        wrong_placements,
    )

    a, cfg = analysis, analysis.config
    t = 0
    w = a.triplets.point_idx[t, 0]
    corners = a.model.points[a.triplets.point_idx[t]]
    away = np.array([[1.3, 0.0], [-1.3, 0.0], [0.0, 1.3], [0.0, -1.3]])
    near_xy = next(corners[0] + d for d in away
                   if np.linalg.norm(corners - (corners[0] + d), axis=1).min() > 1.2)
    probes = EntryObservations(near_xy[None], np.array([a.model.directions[0]]),
                               a.model.projections[w][None])
    none = np.full(len(a.triplets), -1)
    assert far_admissions(a.model, a.triplets, a.c_a, cfg, probes, none)[t] == 0
    hits, wrong = wrong_placements(a.model, a.triplets, a.c_a, cfg, probes, none)
    assert hits[t] == 1 and wrong[t] == 1
    in_set = none.copy()
    in_set[t] = 0
    assert wrong_placements(a.model, a.triplets, a.c_a, cfg, probes, in_set)[1][t] == 0

    def key(tr: Triplets, i: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
        return tuple(tr.point_idx[i]), tuple(tr.dir_idx[i])

    kept = probe_validated(a.triplets, a.model, a.c_a, cfg, probes)
    assert key(a.triplets, t) not in {key(kept, i) for i in range(len(kept))}
    off = cfg.model_copy(update={"regions": cfg.regions.model_copy(
        update={"max_wrong_share": None})})
    assert len(probe_validated(a.triplets, a.model, a.c_a, off, probes)) == len(a.triplets)


def test_probes_from_far_away_reject_a_region_that_admits_them(
        analysis: EigenspaceAnalysis) -> None:
    """A turn of known pose that looks like a triplet's own images but is taken far from
    it is a look-alike place: the triplet goes, unless a candidate-multiple set covers
    it (state Y), or it is not among the triplets to test."""
    from chizu.numeric.eigenspace.analysis import EntryObservations, far_admissions, probe_validated

    a, cfg = analysis, analysis.config
    t = 0
    w = a.triplets.point_idx[t, 0]
    corners = a.model.points[a.triplets.point_idx[t]]
    far_xy = a.model.points[np.argmax(np.linalg.norm(a.model.points - corners[0], axis=1))]
    assert np.linalg.norm(corners - far_xy, axis=1).min() > 2.0
    # w's own learning turn, as if taken at far_xy
    probes = EntryObservations(far_xy[None], np.array([a.model.directions[0]]),
                               a.model.projections[w][None])
    none = np.full(len(a.triplets), -1)
    counts = far_admissions(a.model, a.triplets, a.c_a, cfg, probes, none)
    assert counts[t] >= 1
    in_set = none.copy()
    in_set[t] = 0
    assert far_admissions(a.model, a.triplets, a.c_a, cfg, probes, in_set)[t] == 0
    kept = probe_validated(a.triplets, a.model, a.c_a, cfg, probes)
    key = (tuple(a.triplets.point_idx[t]), tuple(a.triplets.dir_idx[t]))
    keys = {(tuple(p), tuple(d)) for p, d in zip(kept.point_idx, kept.dir_idx, strict=True)}
    assert key not in keys and len(kept) < len(a.triplets)
    untested = probe_validated(a.triplets, a.model, a.c_a, cfg, probes,
                               only=np.zeros(len(a.triplets), dtype=bool))
    assert len(untested) == len(a.triplets)


def test_plane_bound_is_metres_whatever_d_thd_and_reads_stored_ratios() -> None:
    """The plane test bounds eq. 5's error in metres: a larger D_thd widens the paper's
    test, not the plane bound. Configs stored before name it as a share of D_thd."""
    assert RegionConfig().plane_thd_m == pytest.approx(0.1)
    assert RegionConfig(d_thd_m=0.3).plane_thd_m == pytest.approx(0.1)
    old = RegionConfig.model_validate({"d_thd_m": 0.3, "plane_ratio": 0.5})
    assert old.plane_thd_m == pytest.approx(0.15)
    assert RegionConfig.model_validate({"plane_ratio": None}).plane_thd_m is None
    assert RegionConfig.model_validate({"plane_ratio": 0.5, "plane_m": 0.2}).plane_thd_m == 0.2
    with pytest.raises(ValueError):
        RegionConfig(plane_m=-0.1)
