"""The improved proposal of Grisetti, Stachniss & Burgard, "Improved Techniques for Grid
Mapping with Rao-Blackwellized Particle Filters", IEEE T-RO 23(1), 2007 (GMapping), on
chizu's keyframe likelihood fields (:mod:`chizu.numeric.slam.matching.likelihood_field`).

Per particle i, with x_{t-1} its pose, u_t the odometry increment and m its own map (its
keyframe poses; the scans and their likelihood fields are shared):

1. **scan matching** (§IV-A): from the odometry prediction ``x' = x_{t-1} (+) u_t`` to
   the mode x̂ of τ = ``p(z_t|m,x) p(x|x_{t-1},u_t)``
   (:func:`~chizu.numeric.slam.matching.likelihood_field.scan_match`). The paper matches
   ``argmax_x p(z_t | m, x)``; with the motion model in the objective (``match_prior``)
   the mode is the same wherever the scan constrains the pose, but it stays at the
   odometry along a corridor's axis instead of wandering on the likelihood's flat,
   noisy floor. Once per update the best particle is matched from several headings
   and shifts (:func:`robust_increment`) and every particle starts from
   ``x_{t-1} (+) û``: odometry headings can be off by more than the matcher's basin in
   fast turns, and all particles share that error;
2. **sampling around the mode** (§IV-A, "the interval L^(i)"): K = 27 poses
   ``x_j = x̂ + δ_j`` with δ_j on the grid ``{-Δ, 0, Δ}^3``, each with its τ(x_j). Δ per
   axis is the standard deviation of the Laplace approximation of τ at x̂
   (:func:`sample_steps`), floored: the samples resolve the peak along directions the
   scan constrains and follow the motion model along those it does not;
3. **Gaussian fit** (eqs. 14-16, :func:`gaussian_fit`): ``μ = 1/η Σ_j x_j τ(x_j)``,
   ``Σ = 1/η Σ_j τ(x_j) (x_j - μ)(x_j - μ)^T``, ``η = Σ_j τ(x_j)``; the new pose is drawn
   from N(μ, Σ) and the weight becomes ``w_t = w_{t-1} · η`` (times the grid cell volume
   ΔV, so that it estimates ``∫ p(z|m,x) p(x|x_{t-1},u) dx`` and stays comparable with
   the weight of a particle that fell back to the motion model). Everything is in log
   values (log-sum-exp), so nothing underflows;
4. **fallback**: when the match fails (too few beams within the cutoff at x̂) the
   particle is drawn from the motion model and weighted by ``p(z_t | m, x_t)``
   (:func:`loglik_all`) -- the plain RBPF step.

The motion model is the Gaussian of eq. 7 of Hara et al. on the increment in the frame
of x_{t-1}. All particles are handled in one compiled kernel (:func:`propose_all`,
releasing the GIL so that the filter can split them over threads).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from chizu.numeric.geometry import compose_into, relative, wrap_scalar
from chizu.numeric.slam.matching.likelihood_field import (
    Beams,
    FieldPack,
    MatchModel,
    Workspace,
    count_inliers,
    kposes,
    new_workspace,
    scan_match,
    score,
    score_offsets,
    solve3,
)
from chizu.numeric.threads import thread_map

_LOG_2PI = math.log(2.0 * math.pi)

__all__ = ["Sampling", "Starts", "count_inliers", "gaussian_fit", "loglik_all",
           "match_starts", "propose_all", "robust_increment", "sample_steps"]


class Sampling(NamedTuple):
    """Steps 2-4's constants: the floor of Δ per axis ``min_delta (3,)`` (m, m, rad) and
    the inliers a match needs ``min_inliers``."""

    min_delta: np.ndarray
    min_inliers: int


class Starts(NamedTuple):
    """The multi-start match of :func:`robust_increment`: heading offsets (rad) and
    shifts along the predicted heading (m) of the starts, the log-likelihood ``margin``
    a start other than the odometry's must win by, and whether the motion model enters
    the matches of the turned starts (``use_prior``)."""

    headings: np.ndarray
    shifts: np.ndarray
    margin: float
    use_prior: bool
    min_along: float = 0.0


@njit(cache=True, nogil=True)
def _motion_logp(x0: np.ndarray, u: np.ndarray, sig: np.ndarray, x: float, y: float,
                 th: float) -> float:
    """log N(relative(x0, x) - u; 0, diag(sig^2)): the odometry motion model (eq. 7 of
    the chizu paper) as a normalised density."""
    c = math.cos(x0[2])
    s = math.sin(x0[2])
    dx = x - x0[0]
    dy = y - x0[1]
    w0 = (c * dx + s * dy - u[0]) / sig[0]
    w1 = (-s * dx + c * dy - u[1]) / sig[1]
    w2 = wrap_scalar(th - x0[2] - u[2]) / sig[2]
    return (-0.5 * (w0 * w0 + w1 * w1 + w2 * w2) - math.log(sig[0] * sig[1] * sig[2])
            - 1.5 * _LOG_2PI)


@njit(cache=True, nogil=True)
def gaussian_fit(offsets: np.ndarray, log_tau: np.ndarray,
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Eqs. 14-16 of Grisetti et al. 2007 for K sampled points: ``offsets (K, 3)`` the
    points x_j (relative to any centre; angles unwrapped), ``log_tau (K,)`` their
    ``log τ(x_j) = log p(z|m,x_j) + log p(x_j|x_{t-1},u_t)``. Returns
    ``μ = Σ_j x_j τ_j / η`` (3,), ``Σ = Σ_j τ_j (x_j - μ)(x_j - μ)^T / η`` (3, 3) and
    ``log η = log Σ_j τ_j``, computed as ``m + log Σ_j exp(log τ_j - m)`` with
    ``m = max_j log τ_j`` so that nothing underflows (``-inf`` when every τ_j is 0)."""
    n = offsets.shape[0]
    m = -np.inf
    for j in range(n):
        if log_tau[j] > m:
            m = log_tau[j]
    mu = np.zeros(3)
    cov = np.zeros((3, 3))
    if not m > -np.inf:
        return mu, cov, -np.inf
    w = np.empty(n)
    eta = 0.0
    for j in range(n):
        w[j] = math.exp(log_tau[j] - m)
        eta += w[j]
    for j in range(n):
        for a in range(3):
            mu[a] += w[j] * offsets[j, a]
    mu /= eta
    for j in range(n):
        for a in range(3):
            da = offsets[j, a] - mu[a]
            for b in range(3):
                cov[a, b] += w[j] * da * (offsets[j, b] - mu[b])
    cov /= eta
    return mu, cov, m + math.log(eta)


@njit(cache=True, nogil=True)
def _cholesky3(a: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a 3x3 covariance whose diagonal is floored first."""
    s = a.copy()
    for i in range(3):
        if s[i, i] < floor[i]:
            s[i, i] = floor[i]
    low = np.zeros((3, 3))
    for i in range(3):
        for j in range(i + 1):
            acc = s[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            if i == j:
                low[i, i] = math.sqrt(max(acc, floor[i]))
            else:
                low[i, j] = acc / low[j, j]
    return low


@njit(cache=True, nogil=True)
def _prior(x0: np.ndarray, u: np.ndarray, sig: np.ndarray, use: bool) -> np.ndarray:
    """``(2, 3)``: the odometry prediction x' = x0 (+) u and 1/σ² of the motion model
    (world axes: σ_x = σ_y), or zeros in the second row when ``use`` is False."""
    out = np.zeros((2, 3))
    compose_into(x0, u, out[0])
    if use:
        for i in range(3):
            out[1, i] = 1.0 / (sig[i] * sig[i])
    return out


@njit(cache=True, nogil=True)
def sample_steps(h: np.ndarray, inv_s2: float, sig: np.ndarray, floor: np.ndarray,
                 out: np.ndarray) -> None:
    """Δ per axis of the sample grid: the standard deviations of the Laplace
    approximation of τ at x̂ -- information ``J^T J / σ² + diag(1/sig²)`` (likelihood
    plus motion model) -- floored at ``floor``. This is the "meaningful area" of §IV-A
    that the scan matcher determines: the samples then resolve the peak along
    directions the scan constrains and follow the motion model along those it does
    not (a corridor's axis)."""
    a = h * inv_s2
    for i in range(3):
        a[i, i] += 1.0 / (sig[i] * sig[i])
    e = np.zeros(3)
    col = np.zeros(3)
    for i in range(3):
        e[:] = 0.0
        e[i] = 1.0
        if solve3(a, e, col) and col[i] > 0.0:
            out[i] = max(math.sqrt(col[i]), floor[i])
        else:
            out[i] = max(sig[i], floor[i])


def robust_increment(x0: np.ndarray, u: np.ndarray, sig: np.ndarray, beams: Beams,
                     fields: FieldPack, kf_pose: np.ndarray, model: MatchModel,
                     starts: Starts, threads: int = 1) -> tuple[np.ndarray, int]:
    """The increment from ``x0`` (one particle, ``kf_pose (K, 1, 3)`` its map) to the best
    of several scan matches started at ``x0 (+) u`` turned by each of ``starts.headings``
    or moved along its heading by each of ``starts.shifts``, best by ``log p(z|m,x) +
    log p(x|x0,u)``; a start other than the first wins only by more than
    ``starts.margin`` (the likelihood field is sharp and, without free-space evidence,
    ambiguous: small differences favour wrong alignments as often as right ones).
    Odometry headings can be off by more than the matcher's basin during fast turns,
    and odometry can read forward while the robot backs up (beyond the field's cutoff),
    so the shifted starts are matched on the scan alone, the motion model (sure of the
    wrong odometry) only scoring the result. The particles being close, one robust
    start serves them all. Also returns which start won (0: the odometry's own).

    The starts are matched independently (:func:`match_starts`), split over ``threads``
    threads; the choice among them is the same whatever their number."""
    kf_pose = np.ascontiguousarray(kf_pose)
    n = starts.headings.shape[0] + starts.shifts.shape[0]
    parts = np.array_split(np.arange(n), max(1, min(threads, n)))
    done = thread_map(lambda q: match_starts(x0, u, sig, beams, fields, kf_pose, model,
                                             starts, int(q[0]), int(q[-1]) + 1),
                      parts, threads)
    hats = np.concatenate([d[0] for d in done])
    scores = np.concatenate([d[1] for d in done])
    # the odometry's start wins ties and keeps a margin; among the others, the first best
    adjusted = np.where(np.isnan(scores), -np.inf, scores)
    adjusted[0] += starts.margin
    won = int(np.argmax(adjusted))
    return relative(x0, hats[won]), won


@njit(cache=True, nogil=True)
def match_starts(x0: np.ndarray, u: np.ndarray, sig: np.ndarray, beams: Beams,
                 fields: FieldPack, kf_pose: np.ndarray, model: MatchModel, starts: Starts,
                 q_from: int, q_to: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`robust_increment`'s starts ``q_from .. q_to - 1`` (headings first, then
    shifts), each matched by :func:`scan_match`: the matched poses ``(n, 3)`` and their
    scores ``log p(z|m,x) + log p(x|x0,u)`` ``(n,)``."""
    kpose = np.empty((kf_pose.shape[0], 4))
    kposes(kf_pose, 0, kpose)
    ws = new_workspace(beams.pts.shape[0])
    h = np.zeros((3, 3))
    start = np.empty(3)
    prior = _prior(x0, u, sig, starts.use_prior)
    free = _prior(x0, u, sig, False)
    ns = starts.headings.shape[0]
    hats = np.empty((q_to - q_from, 3))
    scores = np.empty(q_to - q_from)
    for q in range(q_from, q_to):
        start[:] = prior[0]  # x0 (+) u, turned by a heading or moved along it by a shift
        if q < ns:
            start[2] += starts.headings[q]
        else:
            start[0] += starts.shifts[q - ns] * math.cos(prior[0, 2])
            start[1] += starts.shifts[q - ns] * math.sin(prior[0, 2])
        # a shifted start is matched on the scan alone: the motion model, sure of the
        # odometry, would pull it back to the odometry's (wrong) place
        hat, cost, _ = scan_match(start, beams, fields, kpose, model, ws, h,
                                  prior if q < ns else free)
        hats[q - q_from] = hat
        scores[q - q_from] = (-cost * model.inv_2s2
                              + _motion_logp(x0, u, sig, hat[0], hat[1], hat[2]))
        if q >= ns:  # a shift along a direction the scan does not pin down says nothing
            c, s = math.cos(prior[0, 2]), math.sin(prior[0, 2])
            if c * c * h[0, 0] + 2.0 * c * s * h[0, 1] + s * s * h[1, 1] < starts.min_along:
                scores[q - q_from] = np.nan
    return hats, scores


@njit(cache=True, nogil=True)
def _sample_grid() -> np.ndarray:
    """The 27 unit offsets {-1, 0, 1}^3 of step 2."""
    grid27 = np.zeros((27, 3))
    j = 0
    for a in range(-1, 2):
        for b in range(-1, 2):
            for c in range(-1, 2):
                grid27[j, 0] = a
                grid27[j, 1] = b
                grid27[j, 2] = c
                j += 1
    return grid27


@njit(cache=True, nogil=True)
def propose_all(x_prev: np.ndarray, u: np.ndarray, u_start: np.ndarray, sig: np.ndarray,
                beams: Beams, fields: FieldPack, kf_pose: np.ndarray, model: MatchModel,
                sampling: Sampling,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-3 for every particle ``x_prev (U, 3)`` with keyframe poses
    ``kf_pose (K, U, 3)``: scan matching from ``x_{t-1} (+) u_start`` (``u_t``, or the
    increment :func:`robust_increment` found for the best particle), the 27 samples
    ``x̂ + {-Δ, 0, Δ}^3`` (Δ from :func:`sample_steps`, evaluated on x̂'s two best
    keyframes per beam) and the Gaussian fit. ``sig`` (3,) is the motion model's sigma
    (x, y in the frame of x_{t-1}, which the steps treat as world axes: equal sigmas).
    Returns μ (U, 3) as absolute poses, the Cholesky factors of Σ (U, 3, 3),
    ``log η + log ΔV`` (U,), whether the match succeeded (U,) and x̂ (U, 3)."""
    n_u = x_prev.shape[0]
    mu_out = np.zeros((n_u, 3))
    chol_out = np.zeros((n_u, 3, 3))
    logeta = np.full(n_u, -np.inf)
    ok = np.zeros(n_u, dtype=np.bool_)
    xhat = np.zeros((n_u, 3))
    grid27 = _sample_grid()
    offs = np.zeros((27, 3))
    delta = np.zeros(3)
    floor = np.empty(3)
    kpose = np.empty((kf_pose.shape[0], 4))
    ws = new_workspace(beams.pts.shape[0])
    h = np.zeros((3, 3))
    log_tau = np.empty(27)
    costs = np.empty(27)
    start = np.empty(3)
    inv_2s2 = model.inv_2s2
    for p in range(n_u):
        kposes(kf_pose, p, kpose)
        x0 = x_prev[p]
        compose_into(x0, u_start, start)  # x' = x_{t-1} (+) u
        hat, _, inl = scan_match(start, beams, fields, kpose, model, ws, h,
                                 _prior(x0, u, sig, True))
        xhat[p] = hat
        if inl < sampling.min_inliers:
            continue
        sample_steps(h, 2.0 * inv_2s2, sig, sampling.min_delta, delta)
        for j in range(27):
            for a in range(3):
                offs[j, a] = grid27[j, a] * delta[a]
        score_offsets(hat, offs, beams, fields, kpose, model.cut2, ws.cand, costs)
        for j in range(27):
            log_tau[j] = -costs[j] * inv_2s2 + _motion_logp(x0, u, sig, hat[0] + offs[j, 0],
                                                            hat[1] + offs[j, 1],
                                                            hat[2] + offs[j, 2])
        mu, cov, le = gaussian_fit(offs, log_tau)
        if not le > -np.inf:
            continue
        mu_out[p, 0] = hat[0] + mu[0]
        mu_out[p, 1] = hat[1] + mu[1]
        mu_out[p, 2] = wrap_scalar(hat[2] + mu[2])
        for a in range(3):
            floor[a] = (1e-3 * delta[a]) ** 2
        chol_out[p] = _cholesky3(cov, floor)
        logeta[p] = le + math.log(delta[0] * delta[1] * delta[2])
        ok[p] = True
    return mu_out, chol_out, logeta, ok, xhat


@njit(cache=True, nogil=True)
def loglik_all(poses: np.ndarray, beams: Beams, fields: FieldPack, kf_pose: np.ndarray,
               model: MatchModel) -> np.ndarray:
    """``log p(z | m, x) = -Σ_b ρ_b / (2σ²)`` of each pose ``(P, 3)`` against its own map
    ``kf_pose (K, P, 3)`` (the weight of a particle drawn from the motion model)."""
    n_p = poses.shape[0]
    out = np.empty(n_p)
    kpose = np.empty((kf_pose.shape[0], 4))
    n_b = beams.pts.shape[0]
    ws = Workspace(np.zeros((1, 2), dtype=np.int64), np.empty((6, n_b)),
                   np.empty((2, n_b), dtype=np.int64))
    h = np.zeros((3, 3))
    g = np.zeros(3)
    for p in range(n_p):
        kposes(kf_pose, p, kpose)
        cost, _ = score(poses[p, 0], poses[p, 1], poses[p, 2], beams, fields, kpose,
                        model.cut2, 0, ws, h, g, False)
        out[p] = -cost * model.inv_2s2
    return out
