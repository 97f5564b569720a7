"""Why a stop went unanswered (numeric.eigenspace.diagnosis), and the seeded rooms the
unseen-room benchmark draws."""

from __future__ import annotations

import numpy as np
import pytest

from chizu.numeric.camera import Camera
from chizu.numeric.eigenspace.analysis import EigenspaceAnalysis
from chizu.numeric.eigenspace.diagnosis import refusal
from chizu.numeric.eigenspace.localization import LocalizationConfig, Session, TurnCandidates
from chizu.numeric.world import World
from chizu.numeric.worlds import CAMERA_ROOM_SHAPES, random_camera_room


def no_hits() -> TurnCandidates:
    z = np.zeros(0, dtype=int)
    return TurnCandidates(z, np.zeros(0), np.zeros((0, 3)), z)


def hits(d_err: list[float], poses: list[list[float]]) -> TurnCandidates:
    n = len(d_err)
    return TurnCandidates(np.arange(n), np.array(d_err), np.array(poses, float),
                          np.zeros(n, dtype=int))


def test_a_turn_outside_every_region_is_refused_by_eq6(analysis: EigenspaceAnalysis,
                                                      room: World) -> None:
    """A turn facing a wall from a corner enters no region: the refusal names eq. 6 and
    the smallest D_err of its images, at or above D_thd."""
    cam = Camera(room, analysis.config.camera)
    n = len(analysis.model.directions)
    imgs = cam.render_turn(np.array([0.5, 0.5]), 0.0, n)
    q = analysis.model.project(analysis.model.check_images(imgs))
    turn = TurnCandidates(np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                          np.zeros(0, int), projections=q)
    s = Session(analysis.config.localization)
    s.add_stop(turn, analysis.config.regions.d_thd_m)
    r = refusal(analysis.regions, s, s.vote(analysis.set_of()))
    assert r is not None
    if r.reason == "no_region":
        assert r.d_err_min_m is not None and r.d_err_min_m >= analysis.config.regions.d_thd_m
    else:  # some image passed eq. 6 on d: then the plane test refused it
        assert r.reason == "plane_test" and r.d_err_min_m < analysis.config.regions.d_thd_m


@pytest.mark.parametrize(("d_err", "poses", "set_of", "reason"), [
    ([0.19], [[2.0, 3.0, 0.5]], None, "vote_threshold"),
    ([0.0, 0.05], [[2.0, 3.0, 0.5], [7.0, 1.0, 2.0]], None, "vote_margin"),
    ([0.0, 0.1], [[2.0, 3.0, 0.0], [8.0, 5.0, np.pi]], np.array([0, 0]), "candidate_set"),
    ([0.0], [[2.0, 3.0, 0.5]], None, None),
])
def test_the_vote_names_what_held_it_back(d_err: list[float], poses: list[list[float]],
                                         set_of: np.ndarray | None, reason: str | None,
                                         analysis: EigenspaceAnalysis) -> None:
    s = Session(LocalizationConfig())
    s.add_stop(hits(d_err, poses), 0.2)
    r = refusal(analysis.regions, s, s.vote(set_of))
    assert (None if r is None else r.reason) == reason
    if r is not None:
        assert r.votes is not None and r.votes > 0


def test_a_session_with_earlier_hits_is_judged_by_its_vote(
        analysis: EigenspaceAnalysis) -> None:
    """A later stop without hits does not make the refusal eq. 6's: the earlier weak
    hit is what the vote lacks."""
    s = Session(LocalizationConfig())
    s.add_stop(hits([0.19], [[2.0, 3.0, 0.5]]), 0.2)
    s.add_stop(no_hits(), 0.2, motion=np.array([1.0, 0.0, 0.0]))
    r = refusal(analysis.regions, s, s.vote())
    assert r is not None and r.reason == "vote_threshold"


@pytest.mark.parametrize("shape", CAMERA_ROOM_SHAPES)
def test_seeded_rooms_are_closed_repeatable_and_differ_by_seed(shape: str) -> None:
    a, b, c = (random_camera_room(s, shape) for s in (5, 5, 6))
    assert a == b and a != c
    w = World(a)
    lo, hi = w.bounds
    free = w.sample_free(50, np.random.default_rng(0))
    assert len(free) == 50 and w.is_free(free).all()
    outside = np.array([[lo[0] - 1.0, lo[1] - 1.0], [hi[0] + 1.0, hi[1] + 1.0]])
    assert not w.is_free(outside).any()
    sample = np.random.default_rng(1).uniform(lo, hi, (2000, 2))
    area = np.mean(w.is_free(sample)) * np.prod(hi - lo)
    assert area > 30.0  # m^2: a room to learn, not a closet
    with pytest.raises(ValueError, match="shape"):
        random_camera_room(1, "round")
