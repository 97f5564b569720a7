"""One filter update with the improved proposal (Grisetti, Stachniss & Burgard 2007, §IV),
replacing the paper's steps 1-2: the start every particle is matched from (the
odometry, corrected by a multi-start match of the best particle, or a loop start or a
relocalisation), then every particle's match, samples and Gaussian fit
(:func:`~chizu.numeric.slam.rbpf.proposal.propose_all`), its draw and its weight.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, wrap_angle
from chizu.numeric.slam.gated import inside_gate
from chizu.numeric.slam.matching.likelihood_field import Beams, FieldPack
from chizu.numeric.slam.rbpf.proposal import (
    Sampling,
    Starts,
    loglik_all,
    propose_all,
    robust_increment,
)
from chizu.numeric.threads import thread_map

if TYPE_CHECKING:
    from chizu.numeric.slam.rbpf.filter import RbpfSlam


def copies(x: np.ndarray, kf_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particles that are copies of each other (the same pose ``x (P, 3)`` and the same
    map, ``kf_pose (K, P, 3)``), so that each is matched once: the index of one of each
    ``(U,)`` and, per particle, which of those it copies ``(P,)``. Particles whose poses
    all differ (every update but those right after a resampling) are told apart by the
    poses alone, without comparing their maps."""
    p = len(x)
    if len(np.unique(x, axis=0)) == p:
        return np.arange(p), np.arange(p)
    key = np.concatenate([x, kf_pose.transpose(1, 0, 2).reshape(p, -1)], axis=1)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, inv.reshape(-1)


def robust_start(slam: RbpfSlam, u: np.ndarray, beams: Beams, fields: FieldPack,
                 kf_best: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`~chizu.numeric.slam.rbpf.proposal.robust_increment` of the best particle (its
    map ``kf_best (K, 1, 3)``) from ``x_best (+) u``. It scores the starts with the fixed
    motion model, not the learned one: it is what finds the odometry's failures, the
    tail a spread learned from the core does not cover. Returns the increment and
    which start won (0: the odometry's). The starts are split over the filter's
    threads."""
    cfg, imp = slam.config, slam.config.improved
    starts = Starts(np.asarray(imp.start_headings_rad, dtype=float),
                    np.asarray(imp.start_shifts_m, dtype=float), float(imp.start_margin), True,
                    float(imp.start_min_along))
    inc, won = robust_increment(slam.x[slam.best], u, cfg.motion.sigmas(u), beams, fields,
                                kf_best, slam.model, starts, cfg.threads)
    return inc, won


def improved_update(slam: RbpfSlam, u: np.ndarray, xy: np.ndarray,
                    inten: np.ndarray | None) -> np.ndarray:
    """One filter update (Grisetti et al. 2007, §IV). The reference keyframes are chosen
    once, by the best particle (as the paper's likelihood does), and every particle
    matched against its own poses of them: scan-matched from ``x_{t-1} (+) u_start``
    (step 1), its new pose drawn from the Gaussian fitted to τ around the match (steps
    2-3, eqs. 14-15), or from the motion model when the match fails (step 4). Moves
    ``slam.x`` and returns the log weight increments: ``log η`` (eq. 16) or, after a
    fallback, ``log p(z|m,x_t)``, both times ``weight_gain``."""
    imp = slam.config.improved
    chosen, fp, alpha = slam.best_map(u, inten)
    lineage = slam._lineage[chosen]  # (K, P)
    kf_pose = slam._kf_pose[chosen[:, None], lineage]  # (K, P, 3): each particle's map
    beams = Beams.of(xy, inten, alpha)
    u, u_start, sig = _start(slam, u, beams, fp, chosen, kf_pose)
    new, inc, fell_back = _draw(slam, u, u_start, sig, beams, fp, kf_pose)
    slam.x = new
    slam.improved_failures += fell_back
    return np.asarray(imp.weight_gain * inc)


def _start(slam: RbpfSlam, u: np.ndarray, beams: Beams, fp: FieldPack, chosen: np.ndarray,
           kf_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The increment every particle's motion model is centred on, the one its match
    starts from, and the motion model's sigmas: the odometry's ``u``, the start
    corrected by the best particle's multi-start match (and then the fixed sigmas, the
    learned ones describing odometry that did not fail), or a loop start's or a
    relocalisation's increment for both."""
    imp = slam.config.improved
    best = slam.best
    kf_best = kf_pose[:, best:best + 1]
    sig = slam.sigmas(u)
    u_start = u
    if imp.odometry.window:
        slam.calibration.add_residual(slam, u, beams)
    if len(imp.start_headings_rad) > 1:
        u_start, won = robust_start(slam, u, beams, fp, kf_best)
        if won:  # the odometry failed here: its learned sigma does not apply
            sig = slam.config.motion.sigmas(u)
    u_loop = None
    if slam.updates % imp.loop.every == 0:
        u_loop = slam.loop.search(slam, u_start, chosen, beams, kf_best)
    if u_loop is None and slam.reloc is not None:
        u_loop = slam.reloc.search(slam, u_start, beams)
    if u_loop is not None:  # the loop's increment replaces the odometry's
        u = u_start = u_loop
    return u, u_start, sig


def _draw(slam: RbpfSlam, u: np.ndarray, u_start: np.ndarray, sig: np.ndarray, beams: Beams,
          fp: FieldPack, kf_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Every particle's new pose and log weight increment, and how many fell back to
    the motion model. Copies of one particle are matched once; the particles are split
    over the threads (the kernel releases the GIL)."""
    cfg, imp = slam.config, slam.config.improved
    p = len(slam.x)
    first, inv = copies(slam.x, kf_pose)
    min_in = max(imp.min_inliers, int(np.ceil(imp.min_match_fraction * len(beams.pts))))
    sampling = Sampling(np.array([imp.sample_min_xy_m, imp.sample_min_xy_m,
                                  imp.sample_min_theta_rad]), int(min_in))
    xs, kfs = slam.x[first], kf_pose[:, first]

    def propose(ix: np.ndarray) -> tuple[np.ndarray, ...]:
        return propose_all(xs[ix], u, u_start, sig, beams, fp,
                           np.ascontiguousarray(kfs[:, ix]), slam.model, sampling)

    parts = np.array_split(np.arange(len(first)), max(1, min(cfg.threads, len(first) // 16)))
    done = thread_map(propose, parts, cfg.threads)
    mu, chol, logeta, ok = (np.concatenate([d[i] for d in done]) for i in range(4))
    if p == 1:
        return _single(slam, u_start, mu[0], bool(ok[0]))
    noise = slam.rng.normal(size=(p, 3))
    okp = ok[inv]
    new = np.empty_like(slam.x)
    inc = np.empty(p)
    if np.any(okp):
        j = inv[okp]
        draw = mu[j] + np.einsum("pij,pj->pi", chol[j], noise[okp])
        draw[:, 2] = wrap_angle(draw[:, 2])
        new[okp] = draw
        inc[okp] = logeta[j]
    fb = ~okp
    if np.any(fb):  # the plain RBPF step: eq. 7, weighted by the likelihood
        new[fb] = compose(slam.x[fb], u + noise[fb] * sig)
        inc[fb] = loglik_all(new[fb], beams, fp, np.ascontiguousarray(kf_pose[:, fb]),
                             slam.model)
    return new, inc, int(fb.sum())


def _single(slam: RbpfSlam, u_start: np.ndarray, mu: np.ndarray,
            ok: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """One particle: the single hypothesis of §6, where a draw would only add noise. Its
    pose is the match's mean when eq. 5 accepts it -- inside ``x_{t-1} (+) (u ± ε)``,
    ``u`` the increment the front end started from (the odometry's, corrected by the
    multi-start match or a loop start: the paper's odometry gate applied to raw
    odometry would refuse every match where the odometry failed, as fr079's does in
    its turns) -- else the start itself."""
    x0 = slam.x[0]
    pose = mu.copy()
    pose[2] = wrap_angle(pose[2])
    if not ok or not inside_gate(x0, pose, u_start, slam.config.gate):
        return compose(x0, u_start)[None, :], np.zeros(1), int(not ok)
    return pose[None, :], np.zeros(1), 0
