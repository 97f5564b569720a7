"""The Fourier-signature baseline (Menegatti et al. 2004; Payá et al. 2014): rotation
invariance of the magnitudes, the heading from the phases, nearest-neighbour position."""

from __future__ import annotations

import numpy as np
import pytest

from chizu.numeric.camera import Camera, CameraConfig
from chizu.numeric.eigenspace.fourier_signature import FourierMap, panorama, phase_lag, signature
from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import wrap_angle
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a

N = 72


@pytest.fixture(scope="module")
def camera() -> Camera:
    return Camera(World(room_a()), CameraConfig(width_px=32, height_px=16))


def test_turning_changes_only_the_phases(camera: Camera) -> None:
    turn = camera.render_turn(np.array([4.0, 5.0]), 0.0, N)
    turned = np.roll(turn, -7, axis=0)  # the same place, started 7 steps later
    a, b = signature(panorama(turn)), signature(panorama(turned))
    np.testing.assert_allclose(np.abs(a), np.abs(b), atol=1e-9)
    assert not np.allclose(a, b)
    assert phase_lag(b, a, N) == pytest.approx(7.0)


def test_a_turn_at_a_learning_point_is_placed_there_with_its_heading(camera: Camera) -> None:
    pts = np.array([[2.0, 2.0], [4.0, 5.0], [7.0, 3.0], [6.0, 7.5]])
    fmap = FourierMap.learn(pts, np.zeros(len(pts)),
                            np.stack([camera.render_turn(p, 0.0, N) for p in pts]))
    for i, p in enumerate(pts):
        theta0 = 0.83 + 0.4 * i  # between learned directions
        pose = fmap.localize(camera.render_turn(p, theta0, N))
        np.testing.assert_allclose(pose[:2], p)
        # one column is one learned direction (5 deg); sub-steps interpolate within it
        assert abs(wrap_angle(pose[2] - theta0)) < np.deg2rad(5.0)


def test_a_turn_between_points_goes_to_a_near_one(camera: Camera) -> None:
    pts = np.array([[x, y] for x in (2.0, 5.0, 8.0) for y in (2.0, 5.0, 8.0)])
    fmap = FourierMap.learn(pts, np.zeros(len(pts)),
                            np.stack([camera.render_turn(p, 0.0, N) for p in pts]))
    near = 0
    rng = np.random.default_rng(1)
    for _ in range(10):
        p = pts[rng.integers(len(pts))] + rng.uniform(-0.5, 0.5, 2)
        pose = fmap.localize(camera.render_turn(p, rng.uniform(-np.pi, np.pi), N))
        near += np.linalg.norm(pose[:2] - p) < 1.5
    assert near >= 8


def test_a_turn_of_the_wrong_length_is_refused(camera: Camera) -> None:
    pts = np.array([[2.0, 2.0]])
    fmap = FourierMap.learn(pts, np.zeros(1), camera.render_turn(pts[0], 0.0, N)[None])
    with pytest.raises(InvalidInput, match="72 images"):
        fmap.localize(camera.render_turn(pts[0], 0.0, 36))
    with pytest.raises(InvalidInput):
        panorama(np.zeros((72, 16)))
