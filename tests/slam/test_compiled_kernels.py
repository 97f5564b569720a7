"""The compiled Intensity-ICP (eqs. 1-3) and the alignment's pair match against plain
NumPy / SciPy / GTSAM versions of the same steps: the kernel's bucket index finds the
k-d tree's nearest points, its iterations land where the NumPy iterations land, and the
pair's covariance is GTSAM's adjoint of the NumPy one."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial import cKDTree

from chizu.numeric.geometry import compose, place, relative, wrap_angle
from chizu.numeric.laser import Laser
from chizu.numeric.slam.alignment import AlignmentConfig, match_pair
from chizu.numeric.slam.matching.intensity_icp import IcpConfig, Reference, intensity_icp
from chizu.numeric.world import World
from chizu.numeric.worlds import from_template


def _tree(ref: Reference) -> cKDTree:
    return cKDTree(ref.aug)


def numpy_icp(ref: Reference, xy: np.ndarray, inten: np.ndarray | None, init: np.ndarray,
              cfg: IcpConfig) -> tuple[np.ndarray, bool, int, int]:
    """Eqs. 1-3 step by step in NumPy with SciPy's k-d tree (chizu's implementation
    before the kernel): pose, converged, iterations, inliers."""
    tree = _tree(ref)
    z1 = place(xy, init)
    total, cur = np.zeros(3), z1
    converged, iterations, inl = False, 0, 0
    for it in range(1, cfg.max_iterations + 1):
        iterations = it
        d, idx = tree.query(ref.augment(cur, inten), distance_upper_bound=cfg.max_correspondence_m)
        ok = np.isfinite(d)
        if ok.sum() < cfg.min_inliers:
            break
        keep = d[ok] <= max(cfg.trim_floor_m, cfg.trim_factor * float(np.median(d[ok])))
        sel = np.flatnonzero(ok)[keep]
        inl = len(sel)
        if inl < cfg.min_inliers:
            break
        src, dst = cur[sel], ref.xy[idx[sel]]
        if cfg.metric == "point":
            cs, cd = src.mean(axis=0), dst.mean(axis=0)
            u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
            r = vt.T @ u.T
            if np.linalg.det(r) < 0:
                vt[1] *= -1
                r = vt.T @ u.T
            t = cd - r @ cs
            step = np.array([t[0], t[1], np.arctan2(r[1, 0], r[0, 0])])
        else:
            n = ref.normals[idx[sel]]
            j = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * src[:, 0] - n[:, 0] * src[:, 1]])
            res = np.einsum("ij,ij->i", n, src - dst)
            step = -np.linalg.solve(j.T @ j + 1e-9 * np.eye(3), j.T @ res)
        total = compose(step, total)
        cur = place(z1, total)
        if np.hypot(step[0], step[1]) < cfg.tolerance_m and abs(step[2]) < cfg.tolerance_rad:
            converged = True
            break
    return compose(total, init), converged, iterations, inl


def _scans(template: str, seed: int, n: int):  # type: ignore[no-untyped-def]
    """Pairs of simulated scans (robot frame, with intensities) a short move apart."""
    rng = np.random.default_rng(seed)
    world = World(from_template(template, "x"))
    laser = Laser(world)
    out = []
    for xy in world.sample_free(4 * n, rng, clearance_m=0.6):
        if len(out) == n:
            break
        pose = np.array([*xy, rng.uniform(-np.pi, np.pi)])
        move = np.array([rng.uniform(0, 0.4), rng.normal(0, 0.05), rng.normal(0, 0.1)])
        a, b = laser.scan(0, pose, pose, rng), laser.scan(1, compose(pose, move),
                                                          compose(pose, move), rng)
        (xa, ia), (xb, ib) = a.points(), b.points()
        if len(xa) >= 20 and len(xb) >= 20:
            out.append((xa, ia, xb, ib, move))
    assert len(out) == n
    return out


def test_the_bucket_index_finds_the_kd_trees_nearest_points() -> None:
    rng = np.random.default_rng(0)
    for alpha in (0.0, 1e-9):
        for trial in range(20):
            ref_xy = rng.uniform(-8, 8, (int(rng.integers(1, 400)), 2))
            inten = rng.uniform(0, 40_000, len(ref_xy))
            ref = Reference(ref_xy, inten, alpha, cell_m=float(rng.choice([0.1, 0.3, 1.0])))
            q = rng.uniform(-10, 10, (300, 2))
            qi = rng.uniform(0, 40_000, 300)
            for upper in (0.05, 0.3, 0.7, 2.5, 1e6):  # 1e6: the whole reference
                d, i = ref.nearest(q, qi, upper)
                dk, ik = _tree(ref).query(ref.augment(q, qi), distance_upper_bound=upper)
                assert np.array_equal(np.isfinite(d), np.isfinite(dk)), (alpha, trial, upper)
                hit = np.isfinite(d)
                assert np.allclose(d[hit], dk[hit], rtol=0, atol=1e-12)
                assert np.all(i[~hit] == len(ref_xy))
                assert np.all(i[hit] == ik[hit])


@pytest.mark.parametrize("template", ["room_a", "corridor"])
def test_compiled_icp_follows_the_numpy_iterations(template: str) -> None:
    """Same pose, iteration count, inliers and convergence as NumPy's eqs. 1-3, for both
    metrics, with and without the intensity term, from perturbed starts."""
    rng = np.random.default_rng(1)
    for k, (xa, ia, xb, ib, move) in enumerate(_scans(template, 2, 12)):
        alpha = (0.0, 1e-9)[k % 2]
        cfg = IcpConfig(alpha=alpha, metric=("point", "line")[(k // 2) % 2],
                        max_correspondence_m=(0.3, 1.0)[(k // 4) % 2])
        ref = Reference(xa, ia, alpha)
        init = compose(move, rng.normal(0, [0.05, 0.05, 0.03]))
        res = intensity_icp(ref, xb, ib, init, cfg)
        pose, converged, iterations, inliers = numpy_icp(ref, xb, ib, init, cfg)
        assert np.allclose(res.pose, pose, rtol=0, atol=1e-9), k
        assert (res.converged, res.iterations, res.inliers) == (converged, iterations, inliers)
        assert np.allclose(compose(init, res.transform), res.pose, atol=1e-9)


def test_pair_match_covariance_is_gtsams_adjoint_of_the_numpy_one() -> None:
    cfg = AlignmentConfig()
    icp = IcpConfig(metric="line", max_iterations=cfg.max_iterations,
                    max_correspondence_m=cfg.max_correspondence_m)
    rng = np.random.default_rng(3)
    held = 0
    for xa, _, xb, _, move in _scans("room_a", 4, 10):
        ref = Reference(xa, None, 0.0)
        guess = compose(move, rng.normal(0, [0.02, 0.02, 0.01]))
        found = match_pair(ref, xb, None, guess, cfg)
        pose, converged, _, _ = numpy_icp(ref, xb, None, guess, icp)
        c = relative(guess, pose)
        cur = place(xb, pose)
        d, idx = _tree(ref).query(cur, distance_upper_bound=cfg.inlier_m)
        ok = np.isfinite(d)
        counts = (converged and np.hypot(c[0], c[1]) <= cfg.max_correction_m
                  and abs(c[2]) <= cfg.max_correction_rad
                  and ok.sum() >= max(cfg.min_overlap * len(xb), 10))
        assert (found is not None) == counts
        if found is None:
            continue
        held += 1
        n, src = ref.normals[idx[ok]], cur[ok]
        jac = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * src[:, 0] - n[:, 0] * src[:, 1]])
        rms = np.sqrt(np.mean(np.einsum("ij,ij->i", n, src - ref.xy[idx[ok]]) ** 2))
        sigma = max(cfg.point_sigma_m, cfg.residual_scale * rms)
        cov = (np.linalg.inv(jac.T @ jac / sigma**2 + np.diag([1e-6, 1e-6, 1e-8]))
               + np.diag([cfg.floor_sigma_m**2] * 2 + [cfg.floor_sigma_rad**2]))
        adj = gtsam.Pose2(*pose).inverse().AdjointMap()
        assert np.allclose(found[0], pose, atol=1e-9)
        assert abs(wrap_angle(found[0][2] - pose[2])) < 1e-9
        assert np.allclose(found[1], adj @ cov @ adj.T, rtol=1e-6, atol=1e-15)
    assert held >= 5
