"""The improved proposal of Grisetti, Stachniss & Burgard, "Improved Techniques for Grid
Mapping with Rao-Blackwellized Particle Filters", IEEE T-RO 23(1), 2007 (GMapping), on
chizu's keyframe likelihood fields.

Per particle i, with x_{t-1} its pose, u_t the odometry increment and m its own map (its
keyframe poses; the scans and their :class:`~numeric.slam.keyframes.LikelihoodField`
grids are shared):

1. **scan matching** (§IV-A): start at the odometry prediction ``x' = x_{t-1} (+) u_t``
   and find the mode x̂ by Levenberg-Marquardt (Gauss-Newton with a damping that only
   accepts improving steps, and a 5 cm / 0.025 rad trust region) on the capped squared
   distances of the scan's beams to the map, bilinearly interpolated in the per-keyframe
   squared-distance grids (the likelihood field of eq. 9 of the chizu paper, with its
   intensity term when ``alpha > 0``). The paper matches ``argmax_x p(z_t | m, x)``;
   by default (``match_prior``) the matcher maximises τ = ``p(z_t|m,x) p(x|x_{t-1},u_t)``
   itself, whose mode is the same wherever the scan constrains the pose, but which stays
   at the odometry along a corridor's axis instead of wandering on the likelihood's
   flat, noisy floor (on fr-clinic's long corridors that wandering cost metres). Full
   evaluations take the minimum over all chosen keyframes and remember each beam's two
   best; the iterations in between and the samples of step 2 look only at those two.
   Once per update the
   best particle is matched from several headings (:func:`robust_increment`) and every
   particle starts from ``x_{t-1} (+) û`` with the increment û found there: odometry
   headings can be off by more than the matcher's basin in fast turns, and all
   particles share that error;
2. **sampling around the mode** (§IV-A, "the interval L^(i)"): K = 27 poses
   ``x_j = x̂ + δ_j`` with δ_j on the grid ``{-Δ, 0, Δ}^3``, each with the target
   ``τ(x_j) = p(z_t | m, x_j) · p(x_j | x_{t-1}, u_t)``. Δ per axis is the standard
   deviation of the Laplace approximation of τ at x̂ (:func:`sample_steps`), floored at
   ``sample_min_*``: the samples resolve the peak along directions the scan constrains
   and follow the motion model along those it does not (a corridor's axis);
3. **Gaussian fit** (eqs. 14-16, :func:`gaussian_fit`): ``μ = 1/η Σ_j x_j τ(x_j)``,
   ``Σ = 1/η Σ_j τ(x_j) (x_j - μ)(x_j - μ)^T`` and ``η = Σ_j τ(x_j)``; the new pose is
   drawn from N(μ, Σ) and the importance weight becomes ``w_t = w_{t-1} · η`` (η times the
   grid cell volume ΔV, so that it estimates ``∫ p(z|m,x) p(x|x_{t-1},u) dx`` and stays
   comparable with the weight of a particle that fell back to the motion model).
   Everything is done with log values (log-sum-exp), so nothing underflows. The RBPF
   multiplies the log increments by ``weight_gain`` (as GMapping smooths its weights);
4. **fallback**: when the match fails (fewer than ``min_inliers`` /
   ``min_match_fraction`` of the beams within the cutoff at x̂) the particle is drawn from
   the motion model and weighted by ``p(z_t | m, x_t)`` -- the plain RBPF step.

The measurement model is the likelihood field:
``log p(z | m, x) = -Σ_b ρ_b(x) / (2 σ²)`` with ``ρ_b = min(cutoff², min_k min_band
(d_k,band(T s_b)² + alpha (l_k,band - l_b)²))``, the minimum over the chosen keyframes k
(each placed at the particle's own pose for it) and intensity bands. The motion model is
the Gaussian of eq. 7 of the chizu paper on the increment in the frame of x_{t-1}.

All particles are handled in one numba kernel (:func:`propose_all`, serial: the machine
is shared); the RBPF passes particles that are exact copies (same pose and same map, as
resampling makes them) once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from pydantic import BaseModel, Field

from numeric.geometry import compose_into, wrap_scalar
from numeric.slam.keyframes import LikelihoodField
from numeric.threads import thread_map

_LOG_2PI = math.log(2.0 * math.pi)
_MAX_STEP_M = 0.05  # largest Levenberg-Marquardt step (trust region)
_MAX_STEP_RAD = 0.025


class ImprovedConfig(BaseModel):
    """Parameters of the improved proposal (Grisetti et al. 2007, §IV).

    ``sigma_m`` is the σ of the likelihood field (GMapping's ``lsigma`` is 0.075 m on
    ``exp(-d²/lsigma)``, i.e. σ ≈ 0.19 m, on a 5 cm grid with sub-cell hit means; chizu's
    fields are quantised to their 5 cm cells, so a few cm is the floor of the
    residuals). ``weight_gain`` tempers the log weight increments (GMapping divides
    them by ``ogain`` = 3 times the particle count); 1 is the paper's weight.

    ``cutoff_m`` caps each beam's residual: a return farther than that from every map
    point counts the same wherever the pose is. A return with no true counterpart in
    the map -- something that moved (fr-clinic at 2 030-2 060 s: a straight line of
    returns across an 8 m hall, 8-10 m ahead, that moves on with the robot and that the
    next scans see through; most likely the floor, which a tilted scan plane meets in a
    line whose distance a small pitch wobble moves by metres), or a wall just beyond
    where an older scan's view of it ended
    -- pulls the match as long as some map point lies within the cap. GMapping's
    matcher looks for a hit in the cells next to the endpoint only. At 0.3 m the RBPF
    lost 1.5 m of 6 m travelled in that hall while the odometry was right to 2 %, and
    23 relations shorter than 20 s, where the odometry is within 0.1 m, were off by more
    than 0.3 m. A smaller cap fixes that but not yet on every log (full logs, 512
    particles, seed 0 where no seed is named; the other parameters as they are):

    - 0.3 m: fr-clinic 0.412 / 0.615 / 0.924 (seeds 0-2), aces 0.046, fr079 0.059;
    - 0.2 m: fr-clinic 0.174 / 1.155 (seeds 0, 2), aces 0.049, fr079 1.027, mit-csail
      0.037;
    - 0.15 m: fr-clinic 0.159 / 0.214 / 0.180 (seeds 0, 1, 3), aces 0.082, fr079 1.404;
    - 0.1 m: fr-clinic 1.102 (the loops no longer close: the old map's pull is cut
      off too).

    fr079 fails at 299-303 s, where the robot backs up while its odometry reads forward
    (relations there 0.5-0.7 m off). With a 0.15 m cap, ``start_margin`` scaled to it
    (12.5; at most cap²/2σ² per beam: 4.5 at 0.15 m, 18 at 0.3 m) brought aces back to
    0.050 but left fr079 at 0.997 and took fr-clinic to 2.444 / 0.993 (seeds 0 / 2);
    shifted starts out to 1 m changed nothing on fr079. What is seen there: at 0.3 m a
    shifted start wins the multi-start match at every update from 303.2 s on; at 0.15 m
    none wins before 305.6 s, when two seconds of keyframes are already misplaced. The
    starts were scored with the fixed Gaussian motion model, against which a 0.45 m
    shift costs about 112 nats, more than the smaller cap lets the beams gain (at
    303.2 s the shifted match explains 86 of 90 beams within 5 cm, the odometry's 52).

    ``shift_penalty_max`` tests that reading: odometry that reads forward while the
    robot backs up is not the tail of a Gaussian but another event, so a shifted
    start's motion model becomes a mixture with a flat failure component, which caps
    its charge (30 nats below the Gaussian's peak). With it (seed 0 unless named): cap
    0.15 m fr079 1.404 -> 0.078 (60 nats: 1.361), but fr-clinic 0.159 -> 0.596 (its
    grand loop did not close). Cap 0.2 m with 30 nats, over seeds 0 / 1 / 2 (bench):
    aces 0.050 / 0.047 / 0.045, mit-csail 0.039 / 0.038 / 0.037, fr079 0.064 / 0.059 /
    0.060, fr-clinic 0.247 / 2.919 / 0.195 (seed 2 from the scratch runner). At 0.2 m
    fr-clinic keeps its 19-23 local failures in the hall (only 0.15 m removed them), and
    at seed 1 the grand loop failed (loop-spanning relations 44.7 m off). So the
    defaults stay at 0.3 m and no limit; the diagnosis of fr079 holds, but no setting
    yet gives fr-clinic below GMapping at every seed without costing another log.

    The ``loop_*`` fields are the loop-aware start (``RbpfSlam._loop_start``,
    :func:`loop_search`): after a long loop the place seen before can be farther off
    than the cutoff, and then no particle's scan match is pulled back. Measured (with the
    0.3 m cap of then) with 512 particles on the full logs (seed 0 unless said), without
    -> with: aces 0.071 -> 0.045 m (loop relations 0.469 -> 0.079), aces seed 1 0.091
    -> 0.073, fr079 0.060 -> 0.060, mit-csail 0.038 -> 0.038 (no loop start taken).
    Corrections of 0.1 to 0.25 m (fr079 took 19) cost fr079 0.0604 -> 0.0615, hence
    ``loop_min_shift_m``.

    The ±1 m grid missed a 2 m loop of aces seed 1 (0.073). A ±2 m grid (0.2 m step)
    closed it but took fr079 to 0.31-0.41 m: at 806 s the robot is in the room next to
    one it mapped at 624 s, whose walls its scan explains 2.45 m off (70 of 90 beams
    within 5 cm, against 20 at the true pose, where only the shared wall is seen), for
    two agreeing updates. What tells them apart is free space: at the true pose no
    return lands in the old keyframes' free space (the rest of the scan is in space they
    never saw), at the false one 19 %; aces's true closures lower that share from
    0.33-0.54 to 0-0.20. Hence ``loop_min_free_drop`` (the current estimate must be
    contradicted by the old map, and the closure must resolve that), the refined
    current estimate as a rival, and the ±2 m grid with ``loop_persistence`` 2: fr079
    0.0601 (13 candidates refused, all of them the false one; none taken), aces seed 1
    0.050.

    The ``reloc_*`` fields are the relocalisation (``RbpfSlam._relocalise``): a return
    from a long loop farther off than the loop start's ±2 m, found by branch and bound
    in a probability grid of the whole old map around the estimate (±30 m, ±0.45 rad;
    the keyframes within 32 m, since session 26).
    Full logs, 512 particles, with ``odometry_min_scale`` 0.03 (both defaults since
    session 23): fr-clinic seeds 0 / 1 / 2 / 4 / 5 0.242 / 0.476 / 0.794 / 0.169 /
    1.757 (before 0.412 / 0.615 / 0.924 / 1.267 / 0.701); it fired at seeds 0 (5.4 m)
    and 4 (11.1 m), and on none of aces (seeds 0, 1), fr079 (0, 1) and mit-csail (0),
    whose figures did not change. A 10 m window missed seed 2's return 18.9 m off;
    with ±20 m (keyframes within 22 m), session 24: fr-clinic seeds 0-5 0.183 / 0.179 /
    0.245 / 0.165 / 0.279 / 1.757 (seed 4 took a 10.9 m match whose heading was 6° off
    before a second one mended it; seed 5 comes back 28 m and 21° off), and again none
    on aces, fr079 and mit-csail. Session 25's variant (``reloc_max_seen`` 0.3,
    ``rigid_persistence``, ±30 m / ±0.45 rad, keyframes within 32 m) took seed 5's
    return 29 m and 0.32 rad off (1.575 -> 0.284) but lost seed 1's 12.8 m return
    (0.182 -> 0.473), which the refinement against the picked keyframes alone refused.
    With the refinement against all old keyframes it is the default since session 26:
    fr-clinic seeds 0-5 0.242 / 0.207 / 0.180 / 0.170 / 0.174 / 0.276, all below
    GMapping's 0.637 (docs/notes/slam-rbpf-fr-clinic.md, "Session 26").
    """

    sigma_m: float = Field(0.05, gt=0, description="σ of the likelihood field (m)")
    cutoff_m: float = Field(0.3, gt=0, description="residual cap of the matcher and of "
                            "p(z|m,x) (at most the fields' own cutoff)")
    weight_gain: float = Field(0.01, gt=0, le=1.0,
                               description="log-weight increments are multiplied by this")
    sample_min_xy_m: float = Field(0.005, gt=0, description="smallest Δ of the samples (m)")
    sample_min_theta_rad: float = Field(0.002, gt=0, description="... and in heading (rad)")
    max_iterations: int = Field(12, ge=1, le=200, description="LM iterations of the matcher")
    min_match_fraction: float = Field(0.3, ge=0, le=1,
                                      description="match fails below this inlier fraction")
    min_inliers: int = Field(10, ge=1)
    match_prior: bool = Field(True, description="the matcher maximises τ = p(z|m,x) "
                              "p(x|x_{t-1},u), not p(z|m,x) alone")
    start_margin: float = Field(50.0, ge=0, description="log-likelihood units another start "
                                "must beat the odometry start by")
    start_shifts_m: tuple[float, ...] = Field(
        (-0.6, -0.4, -0.2, 0.2, 0.4),
        description="further starts of that match, moved along the predicted heading by "
                    "these distances and matched on the scan alone (odometry that reads "
                    "forward while the robot backs up, as fr079's at 300 s)")
    start_headings_rad: tuple[float, ...] = Field(
        (0.0, -0.1, 0.1, -0.2, 0.2, -0.35, 0.35),
        description="heading offsets of the multi-start match that corrects the odometry "
                    "increment once per update (one value: no correction)")
    odometry_window: int = Field(200, ge=0, description="the motion model's heading sigma "
                                 "is learned from the last this many updates "
                                 "(:class:`~numeric.slam.rbpf.OdometryCalibration`); 0: fixed")
    odometry_lag_m: float = Field(3.0, gt=0, description="the residuals it learns from: "
                                  "the heading change since "
                                  "the newest keyframe at least this much odometry path back, "
                                  "matched against that keyframe alone, minus the odometry's "
                                  "(:meth:`~numeric.slam.rbpf.RbpfSlam._calibrate`)")
    odometry_lag_headings_rad: tuple[float, ...] = Field(
        (0.0, -0.035, 0.035, -0.07, 0.07),
        description="heading offsets of that lagged match's starts (the best by the scan "
                    "alone wins)")
    odometry_min_scale: float = Field(0.03, gt=0, le=1, description="... down to this share "
                                      "of the fixed one")
    odometry_knee: float = Field(0.2, gt=0, le=1, description="a spread up to this is "
                                 "taken as it is, one of twice this or more keeps the fixed "
                                 "sigma, linear in between")
    loop_search: bool = Field(True, description="a wide search of the scan against the "
                              "best particle's old keyframes (a loop) once per update; a "
                              "clearly better, well-constrained alignment becomes the start "
                              "and motion prior of every particle")
    loop_radius_m: float = Field(2.0, gt=0, description="half width of its position grid")
    loop_step_m: float = Field(0.2, gt=0, description="... and its spacing")
    loop_angle_rad: float = Field(0.1, ge=0, description="half width of its heading grid")
    loop_angle_step_rad: float = Field(0.025, gt=0, description="... and its spacing")
    loop_coarse_cutoff_m: float = Field(0.2, gt=0, description="residual cap of the grid")
    loop_refine: int = Field(6, ge=1, description="grid poses refined by the scan matcher")
    loop_inlier_m: float = Field(0.05, gt=0, description="a beam this close to the old map "
                                 "is explained by it")
    loop_min_fraction: float = Field(0.6, ge=0, le=1, description="the alternative must "
                                     "explain this share of the beams")
    loop_min_gain: float = Field(0.25, ge=0, le=1, description="... this share more than "
                                 "the current estimate does")
    loop_ambiguity: float = Field(0.15, ge=0, le=1, description="... and this share more "
                                  "than any other refined pose at least loop_min_sep_m away")
    loop_min_sep_m: float = Field(0.3, gt=0, description="distinct modes are this far apart")
    loop_min_eig: float = Field(5.0, ge=0, description="smallest eigenvalue of the position "
                                "block of J^T J at the alternative (~beams that pin down "
                                "its weakest direction; a corridor has ~0)")
    loop_min_shift_m: float = Field(0.25, ge=0, description="smaller corrections are left "
                                    "to the scan matcher")
    loop_min_old: int = Field(3, ge=1, description="old keyframes needed to search")
    loop_min_free_drop: float = Field(0.1, ge=0, le=1, description="the alternative must "
                                      "put this share of the beams fewer than the current "
                                      "estimate does where the old keyframes saw free space")
    loop_free_cell_m: float = Field(0.1, ge=0.02, le=1.0,
                                    description="cell of that free-space grid")
    loop_free_margin_m: float = Field(0.1, ge=0, description="free cells this close to a "
                                      "cell not seen free do not count")
    loop_persistence: int = Field(2, ge=1, description="consecutive updates that must agree "
                                  "on the correction (within loop_min_sep_m) before it is "
                                  "taken")
    reloc_every: int = Field(5, ge=0, description="updates between two relocalisations "
                             "against the old map (RbpfSlam._relocalise); 0: none")
    reloc_min_age_s: float = Field(120.0, ge=0, description="keyframes at least this old "
                                   "make the old map")
    reloc_radius_m: float = Field(32.0, gt=0, description="... those the best particle "
                                  "placed this close to its estimate")
    reloc_max_keyframes: int = Field(60, ge=3, description="... at most this many (evenly "
                                     "picked)")
    reloc_resolution_m: float = Field(0.1, gt=0, description="cell of its probability grid")
    reloc_window_m: float = Field(30.0, gt=0, description="half width of the branch-and-"
                                  "bound window in position")
    reloc_angle_rad: float = Field(0.45, ge=0, description="... and in heading")
    reloc_min_score: float = Field(0.35, gt=0, le=1, description="mean probability of the "
                                   "cells the scan falls in at the match")
    reloc_min_gain: float = Field(0.1, ge=0, le=1, description="... this much more than "
                                  "at the current estimate")
    reloc_min_fraction: float = Field(0.3, ge=0, le=1, description="the refined match must "
                                      "explain this share of the beams within "
                                      "loop_inlier_m")
    reloc_persistence: int = Field(3, ge=1, description="consecutive searches that must "
                                   "agree (within loop_min_sep_m)")
    reloc_unique_m: float = Field(1.0, gt=0, description="no second pose this far from the "
                                  "match ...")
    reloc_unique_ratio: float = Field(0.9, gt=0, le=1, description="... scores this share "
                                      "of its score")
    reloc_max_seen: float | None = Field(0.3, ge=0, le=1, description="a current "
                                         "estimate that puts at most this share of the "
                                         "returns in cells the old keyframes saw (free or "
                                         "hit) cannot be contradicted by them: the match "
                                         "then needs no drop in the free-space share, only "
                                         "its own below loop_min_free_drop ... (None: the "
                                         "drop is always needed)")
    reloc_unseen_travel_m: float = Field(3.0, ge=0, description="... and the searches "
                                         "that agree on it must span this much of the "
                                         "estimate's path (a room that looks like an old "
                                         "one fits from where the robot stands)")
    reloc_drift_m: float = Field(1.0, ge=0, description="a relocalisation moves the "
                                 "estimate at most this far ...")
    reloc_drift_per_m: float = Field(0.05, ge=0, description="... plus this much per m "
                                     "of odometry path since the robot was last at the "
                                     "old keyframes it matched (the drift it can have "
                                     "gathered since)")


@dataclass(frozen=True)
class FieldPack:
    """The chosen keyframes' likelihood fields as the kernels read them: every field's
    squared-distance grid ``(bands, nx, ny)`` flattened into one ``grid`` (and the
    intensity grids into ``inten``, or one dummy value when no intensity is used),
    ``meta (K, 4)`` = offset, bands, nx, ny per keyframe, ``origins (K, 2)`` (m) and the
    common ``inv_res`` (1/m). One copy per filter update: a flat buffer is what keeps
    the innermost lookup a plain array read."""

    grid: np.ndarray
    inten: np.ndarray
    meta: np.ndarray
    origins: np.ndarray
    inv_res: float

    @staticmethod
    def of(fields: list[LikelihoodField], with_intensity: bool) -> FieldPack:
        meta = np.zeros((len(fields), 4), dtype=np.int64)
        off = 0
        for k, f in enumerate(fields):
            nb, nx, ny = f.dist2.shape
            meta[k] = (off, nb, nx, ny)
            off += nb * nx * ny
        grid = np.concatenate([f.dist2.ravel() for f in fields]).astype(np.float32, copy=False)
        inten = (np.concatenate([f.inten.ravel() for f in fields]).astype(np.float32, copy=False)
                 if with_intensity else np.zeros(1, dtype=np.float32))
        origins = np.array([f.origin for f in fields], dtype=float).reshape(-1, 2)
        return FieldPack(grid, inten, meta, origins, 1.0 / fields[0].res)


# -- numba kernels --------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _corners(off: int, nx: int, ny: int, ox: float, oy: float, inv_res: float, qx: float,
             qy: float) -> tuple[int, float, float]:
    """Where the bilinear interpolation at the keyframe-frame point (qx, qy) reads one
    band's grid (flat, at ``off``, ``nx`` by ``ny``): the index of its lower corner cell
    and the fractions (fu, fv) along x and y; index -1 outside the grid."""
    u = (qx - ox) * inv_res - 0.5
    v = (qy - oy) * inv_res - 0.5
    if not (u >= 0.0 and v >= 0.0):
        return -1, 0.0, 0.0
    i = int(u)
    j = int(v)
    if i + 1 >= nx or j + 1 >= ny:
        return -1, 0.0, 0.0
    return off + i * ny + j, u - i, v - j


@njit(cache=True, nogil=True)
def _interpolate(grid: np.ndarray, base: int, ny: int, fu: float, fv: float) -> float:
    """The bilinear value at :func:`_corners`' cell and fractions."""
    p00 = grid[base]
    p01 = grid[base + 1]
    p10 = grid[base + ny]
    p11 = grid[base + ny + 1]
    return (p00 * (1.0 - fu) * (1.0 - fv) + p10 * fu * (1.0 - fv)
            + p01 * (1.0 - fu) * fv + p11 * fu * fv)


@njit(cache=True, nogil=True)
def _slope(grid: np.ndarray, base: int, ny: int, fu: float, fv: float,
           inv_res: float) -> tuple[float, float]:
    """... and its gradient (per m). Apart from :func:`_interpolate`: the matcher needs
    it only where a lookup improves a beam's best, which most lookups do not."""
    p00 = grid[base]
    p01 = grid[base + 1]
    p10 = grid[base + ny]
    p11 = grid[base + ny + 1]
    gx = ((p10 - p00) * (1.0 - fv) + (p11 - p01) * fv) * inv_res
    gy = ((p01 - p00) * (1.0 - fu) + (p11 - p10) * fu) * inv_res
    return gx, gy


@njit(cache=True, nogil=True)
def _lookup(grid: np.ndarray, gint: np.ndarray, off: int, nb: int, nx: int, ny: int,
            ox: float, oy: float, inv_res: float, qx: float, qy: float, li: float,
            alpha: float, cut2: float, bound: float, grad: bool) -> tuple[float, float, float]:
    """Capped augmented squared residual at the keyframe-frame point (qx, qy) and its
    gradient (per m): the bilinear squared distance per intensity band plus
    ``alpha (l_band - li)^2`` with the nearest cell's intensity, the minimum over
    bands; ``cut2`` and no gradient outside the grid. Only values below ``bound`` (a
    beam's best so far, at most ``cut2``) count, and the gradient (with ``grad``) is
    computed only for them: the result is ``bound`` with no gradient when no band
    goes below it."""
    best = bound
    gx = 0.0
    gy = 0.0
    base, fu, fv = _corners(off, nx, ny, ox, oy, inv_res, qx, qy)
    if base < 0:
        return cut2, 0.0, 0.0
    band = nx * ny
    for b in range(nb):
        val = _interpolate(grid, base + b * band, ny, fu, fv)
        if val >= cut2:  # capped: the intensity only adds
            continue
        if alpha > 0.0:
            near = base + b * band + (ny if fu >= 0.5 else 0) + (1 if fv >= 0.5 else 0)
            dl = gint[near] - li
            val += alpha * dl * dl
        if val < best:
            best = val
            if grad:
                gx, gy = _slope(grid, base + b * band, ny, fu, fv, inv_res)
    return best, gx, gy


@njit(cache=True, nogil=True)
def _keyframe(kpose: np.ndarray, meta: np.ndarray, origins: np.ndarray, k: int,
              ) -> tuple[float, float, float, float, int, int, int, int, float, float]:
    """Keyframe ``k``'s constants as the lookups read them: its pose (cos, sin, x, y)
    from ``kpose``, its grid's offset, bands, nx, ny from ``meta`` and origin."""
    return (kpose[k, 0], kpose[k, 1], kpose[k, 2], kpose[k, 3], meta[k, 0], meta[k, 1],
            meta[k, 2], meta[k, 3], origins[k, 0], origins[k, 1])


@njit(cache=True, nogil=True)
def _to_keyframe(ck: float, sk: float, tx: float, ty: float, wx: float, wy: float,
                 ) -> tuple[float, float]:
    """The world point (wx, wy) in the frame of a keyframe at (tx, ty) heading (ck, sk)."""
    dx = wx - tx
    dy = wy - ty
    return ck * dx + sk * dy, -sk * dx + ck * dy


@njit(cache=True, nogil=True)
def _score(x: float, y: float, th: float, pts: np.ndarray, li: np.ndarray, alpha: float,
           grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
           inv_res: float, kpose: np.ndarray, cut2: float, grad: bool, h: np.ndarray,
           g: np.ndarray, cand: np.ndarray, mode: int, work: np.ndarray,
           iwork: np.ndarray) -> tuple[float, int]:
    """Σ_b ρ_b at pose (x, y, th) and the number of beams under the cutoff; with
    ``grad`` also the Gauss-Newton system ``h = Σ J^T J``, ``g = Σ J^T e`` of the
    residuals ``e_b = sqrt(ρ_b)`` (derivatives by the world-frame pose).

    ``kpose (K, 4)``: the particle's pose of each keyframe as (cos, sin, x, y). ``mode``
    0: all keyframes; 1: all keyframes, and ``cand (B, 2)`` records each beam's two best
    keyframes (-1 where none is under the cutoff); 2: only the keyframes in ``cand``
    (the cheap evaluation near a pose where ``cand`` was recorded). ``work (6, B)`` and
    ``iwork (2, B)`` are scratch."""
    c = math.cos(th)
    s = math.sin(th)
    n_b = pts.shape[0]
    n_k = kpose.shape[0]
    use_i = alpha > 0.0
    wx = work[0]
    wy = work[1]
    best = work[2]
    second = work[3]
    bgx = work[4]
    bgy = work[5]
    k1 = iwork[0]
    k2 = iwork[1]
    for b in range(n_b):
        wx[b] = x + c * pts[b, 0] - s * pts[b, 1]
        wy[b] = y + s * pts[b, 0] + c * pts[b, 1]
        best[b] = cut2
        second[b] = cut2
        bgx[b] = 0.0
        bgy[b] = 0.0
        k1[b] = -1
        k2[b] = -1
    if mode < 2:  # keyframe by keyframe: its constants loaded once, a tight beam loop
        for k in range(n_k):
            ck, sk, tx, ty, off, nb, nx, ny, ox, oy = _keyframe(kpose, meta, origins, k)
            geo = nb == 1 and not use_i
            for b in range(n_b):
                qx, qy = _to_keyframe(ck, sk, tx, ty, wx[b], wy[b])
                if geo:  # the common case, written out: most lookups change nothing
                    base, fu, fv = _corners(off, nx, ny, ox, oy, inv_res, qx, qy)
                    if base < 0:
                        continue
                    val = _interpolate(grid, base, ny, fu, fv)
                    if not val < second[b]:
                        continue
                    gqx, gqy = _slope(grid, base, ny, fu, fv, inv_res)
                else:
                    val, gqx, gqy = _lookup(grid, gint, off, nb, nx, ny, ox, oy, inv_res, qx,
                                            qy, li[b] if use_i else 0.0, alpha, cut2,
                                            second[b], True)
                if val < second[b]:
                    if val < best[b]:
                        second[b] = best[b]
                        k2[b] = k1[b]
                        best[b] = val
                        k1[b] = k
                        bgx[b] = ck * gqx - sk * gqy
                        bgy[b] = sk * gqx + ck * gqy
                    else:
                        second[b] = val
                        k2[b] = k
        if mode == 1:
            for b in range(n_b):
                cand[b, 0] = k1[b]
                cand[b, 1] = k2[b]
    else:
        for b in range(n_b):
            for m in range(cand.shape[1]):
                k = cand[b, m]
                if k < 0:
                    continue
                ck, sk, tx, ty, off, nb, nx, ny, ox, oy = _keyframe(kpose, meta, origins, k)
                qx, qy = _to_keyframe(ck, sk, tx, ty, wx[b], wy[b])
                if nb == 1 and not use_i:
                    base, fu, fv = _corners(off, nx, ny, ox, oy, inv_res, qx, qy)
                    if base < 0:
                        continue
                    val = _interpolate(grid, base, ny, fu, fv)
                    if not val < best[b]:
                        continue
                    gqx, gqy = _slope(grid, base, ny, fu, fv, inv_res)
                else:
                    val, gqx, gqy = _lookup(grid, gint, off, nb, nx, ny, ox, oy, inv_res, qx,
                                            qy, li[b] if use_i else 0.0, alpha, cut2, best[b],
                                            grad)
                if val < best[b]:
                    best[b] = val
                    bgx[b] = ck * gqx - sk * gqy
                    bgy[b] = sk * gqx + ck * gqy
    total = 0.0
    inl = 0
    if grad:
        h[:, :] = 0.0
        g[:] = 0.0
    for b in range(n_b):
        rb = best[b]
        total += rb
        if rb < cut2:
            inl += 1
            if grad:
                e = math.sqrt(rb)
                if e > 1e-6:
                    f = 0.5 / e
                    j0 = bgx[b] * f
                    j1 = bgy[b] * f
                    j2 = (bgx[b] * (y - wy[b]) + bgy[b] * (wx[b] - x)) * f
                    h[0, 0] += j0 * j0
                    h[0, 1] += j0 * j1
                    h[0, 2] += j0 * j2
                    h[1, 1] += j1 * j1
                    h[1, 2] += j1 * j2
                    h[2, 2] += j2 * j2
                    g[0] += j0 * e
                    g[1] += j1 * e
                    g[2] += j2 * e
    if grad:
        h[1, 0] = h[0, 1]
        h[2, 0] = h[0, 2]
        h[2, 1] = h[1, 2]
    return total, inl


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
def _solve3(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> bool:
    """``out = a^-1 b`` for a 3x3 (cofactors); False when (nearly) singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    scale = abs(a[0, 0] * a[1, 1] * a[2, 2]) + 1e-300
    if not abs(det) > 1e-12 * scale:
        return False
    c10 = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    c11 = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    c12 = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    c20 = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    c21 = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    c22 = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    out[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True


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
def _energy(cost: float, x: float, y: float, t: float, inv_2s2: float, prior: np.ndarray,
            ) -> float:
    """``-log τ`` up to a constant: ``Σ_b ρ_b / (2σ²)`` plus the motion model's
    ``½ Σ_i ((x_i - x'_i) / σ_i)²``; ``prior (2, 3)`` = x' and 1/σ² (zeros: no prior)."""
    dt = wrap_scalar(t - prior[0, 2])
    return cost * inv_2s2 + 0.5 * (prior[1, 0] * (x - prior[0, 0]) ** 2
                                   + prior[1, 1] * (y - prior[0, 1]) ** 2
                                   + prior[1, 2] * dt * dt)


@njit(cache=True, nogil=True)
def _lm(pose: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float, grid: np.ndarray,
        gint: np.ndarray, meta: np.ndarray, origins: np.ndarray, inv_res: float,
        kpose: np.ndarray, cut2: float, max_iter: int, cand: np.ndarray, work: np.ndarray,
        iwork: np.ndarray, inv_2s2: float, prior: np.ndarray) -> None:
    """Levenberg-Marquardt on :func:`_energy` from ``pose`` (updated in place), evaluating
    only each beam's candidate keyframes ``cand`` (mode 2 of :func:`_score`)."""
    h = np.zeros((3, 3))
    g = np.zeros(3)
    hn = np.zeros((3, 3))
    gn = np.zeros(3)
    a = np.zeros((3, 3))
    rhs = np.zeros(3)
    step = np.zeros(3)
    x, y, t = pose[0], pose[1], pose[2]
    cost, inl = _score(x, y, t, pts, li, alpha, grid, gint, meta, origins, inv_res, kpose,
                       cut2, True, h, g, cand, 2, work, iwork)
    e = _energy(cost, x, y, t, inv_2s2, prior)
    lam = 1e-3
    k2 = 2.0 * inv_2s2
    for _ in range(max_iter):
        if inl < 3:
            break
        d = (x - prior[0, 0], y - prior[0, 1], wrap_scalar(t - prior[0, 2]))
        for r in range(3):
            for q in range(3):
                a[r, q] = k2 * h[r, q]
            a[r, r] += prior[1, r]
            a[r, r] += lam * a[r, r] + 1e-9
            rhs[r] = -(k2 * g[r] + prior[1, r] * d[r])
        if not _solve3(a, rhs, step):
            break
        # a trust region: Gauss-Newton on a truncated cost can jump into another basin
        f = max(math.hypot(step[0], step[1]) / _MAX_STEP_M, abs(step[2]) / _MAX_STEP_RAD)
        if f > 1.0:
            step /= f
        nx, ny, nt = x + step[0], y + step[1], t + step[2]
        c2, i2 = _score(nx, ny, nt, pts, li, alpha, grid, gint, meta, origins, inv_res,
                        kpose, cut2, True, hn, gn, cand, 2, work, iwork)
        e2 = _energy(c2, nx, ny, nt, inv_2s2, prior)
        if e2 < e:
            x, y, t, e, inl = nx, ny, nt, e2, i2
            h[:, :] = hn
            g[:] = gn
            lam = max(lam * 0.3, 1e-7)
            if abs(step[0]) < 1e-4 and abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
                break
        else:
            lam *= 10.0
            if lam > 1e4:
                break
    pose[0] = x
    pose[1] = y
    pose[2] = t


@njit(cache=True, nogil=True)
def scan_match(start: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float,
               grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
               inv_res: float, kpose: np.ndarray, cut2: float, max_iter: int,
               cand: np.ndarray, h: np.ndarray, work: np.ndarray, iwork: np.ndarray,
               inv_2s2: float, prior: np.ndarray) -> tuple[np.ndarray, float, int]:
    """Step 1: x̂ = argmax_x p(z|m,x) p(x|x_{t-1},u) (:func:`_energy`; ``prior`` all zero:
    argmax p(z|m,x) alone) from ``start``: rounds of a full evaluation (which records
    each beam's two best keyframes in ``cand`` and the Gauss-Newton ``J^T J`` in ``h``)
    followed by Levenberg-Marquardt on those candidates, until a round moves the pose
    by less than half a grid cell and 0.01 rad (at most three rounds). Returns x̂ and
    Σ_b ρ_b and the inlier count of the last full evaluation (less than that much away
    from x̂, as are ``cand`` and ``h``)."""
    pose = start.copy()
    g = np.zeros(3)
    tol = 0.5 / inv_res
    cost = 0.0
    inl = 0
    for _ in range(3):
        cost, inl = _score(pose[0], pose[1], pose[2], pts, li, alpha, grid, gint, meta,
                           origins, inv_res, kpose, cut2, True, h, g, cand, 1, work, iwork)
        x0, y0, t0 = pose[0], pose[1], pose[2]
        _lm(pose, pts, li, alpha, grid, gint, meta, origins, inv_res, kpose, cut2, max_iter,
            cand, work, iwork, inv_2s2, prior)
        if abs(pose[0] - x0) < tol and abs(pose[1] - y0) < tol and abs(pose[2] - t0) < 0.01:
            break
    pose[2] = wrap_scalar(pose[2])
    return pose, cost, inl


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
        if _solve3(a, e, col) and col[i] > 0.0:
            out[i] = max(math.sqrt(col[i]), floor[i])
        else:
            out[i] = max(sig[i], floor[i])


@njit(cache=True, nogil=True)
def _kposes(kf_pose: np.ndarray, p: int, out: np.ndarray) -> None:
    for k in range(kf_pose.shape[0]):
        out[k, 0] = math.cos(kf_pose[k, p, 2])
        out[k, 1] = math.sin(kf_pose[k, p, 2])
        out[k, 2] = kf_pose[k, p, 0]
        out[k, 3] = kf_pose[k, p, 1]


@njit(cache=True, nogil=True)
def robust_increment(x0: np.ndarray, u: np.ndarray, sig: np.ndarray, pts: np.ndarray,
                     li: np.ndarray, alpha: float, grid: np.ndarray, gint: np.ndarray,
                     meta: np.ndarray, origins: np.ndarray, inv_res: float,
                     kf_pose: np.ndarray, cut2: float, inv_2s2: float, max_iter: int,
                     headings: np.ndarray, margin: float, use_prior: bool,
                     shifts: np.ndarray) -> tuple[np.ndarray, int]:
    """The increment from ``x0`` (one particle, ``kf_pose (K, 1, 3)`` its map) to the best
    of several scan matches started at ``x0 (+) u`` turned by each of ``headings`` (rad)
    or moved along its heading by each of ``shifts`` (m), best by ``log p(z|m,x) +
    log p(x|x0,u)``; a start other than the first wins only by more than ``margin`` (the
    likelihood field is sharp and, without free-space evidence, ambiguous: small
    differences favour wrong alignments as often as right ones). Odometry headings can
    be off by more than the matcher's basin during fast turns, and odometry can read
    forward while the robot backs up (fr079 at 300 s: 0.5 m off, beyond the field's
    cutoff), so the shifted starts are matched on the scan alone, the motion model
    (sure of the wrong odometry) only scoring the result. The particles being close,
    one robust start serves them all. Also
    returns which start won (0: the odometry's own)."""
    kpose = np.empty((kf_pose.shape[0], 4))
    _kposes(kf_pose, 0, kpose)
    cand = np.full((pts.shape[0], 2), -1, dtype=np.int64)
    work = np.empty((6, pts.shape[0]))
    iwork = np.empty((2, pts.shape[0]), dtype=np.int64)
    h = np.zeros((3, 3))
    c0 = math.cos(x0[2])
    s0 = math.sin(x0[2])
    start = np.empty(3)
    best = -np.inf
    out = u.copy()
    won = 0
    prior = _prior(x0, u, sig, use_prior)
    free = _prior(x0, u, sig, False)
    ns = headings.shape[0]
    for q in range(ns + shifts.shape[0]):
        start[:] = prior[0]  # x0 (+) u, turned by a heading or moved along it by a shift
        if q < ns:
            start[2] += headings[q]
        else:
            start[0] += shifts[q - ns] * math.cos(prior[0, 2])
            start[1] += shifts[q - ns] * math.sin(prior[0, 2])
        # a shifted start is matched on the scan alone: the motion model, sure of the
        # odometry, would pull it back to the odometry's (wrong) place
        hat, cost, _ = scan_match(start, pts, li, alpha, grid, gint, meta, origins, inv_res,
                                  kpose, cut2, max_iter, cand, h, work, iwork, inv_2s2,
                                  prior if q < ns else free)
        score = -cost * inv_2s2 + _motion_logp(x0, u, sig, hat[0], hat[1], hat[2])
        if best == -np.inf:
            score += margin
        if score > best:
            best = score
            won = q
            dx = hat[0] - x0[0]
            dy = hat[1] - x0[1]
            out[0] = c0 * dx + s0 * dy
            out[1] = -s0 * dx + c0 * dy
            out[2] = wrap_scalar(hat[2] - x0[2])
    return out, won


@njit(cache=True, nogil=True)
def count_inliers(pose: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float,
                  grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
                  inv_res: float, kf_pose: np.ndarray, inlier2: float) -> int:
    """How many beams at ``pose`` lie within ``sqrt(inlier2)`` of the map ``kf_pose
    (K, 1, 3)`` (the minimum over its keyframes)."""
    kpose = np.empty((kf_pose.shape[0], 4))
    _kposes(kf_pose, 0, kpose)
    cand = np.zeros((1, 2), dtype=np.int64)
    work = np.empty((6, pts.shape[0]))
    iwork = np.empty((2, pts.shape[0]), dtype=np.int64)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    _, inl = _score(pose[0], pose[1], pose[2], pts, li, alpha, grid, gint, meta, origins,
                    inv_res, kpose, inlier2, False, h, g, cand, 0, work, iwork)
    return inl


def loop_search(center: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float,
                grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
                inv_res: float, kf_pose: np.ndarray, cut2: float, coarse2: float,
                inlier2: float, inv_2s2: float, max_iter: int, radius: float, step: float,
                half_angle: float, angle_step: float, n_refine: int, min_sep: float,
                threads: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wide search of the scan against one map ``kf_pose (K, 1, 3)`` (the old
    keyframes of a loop): a correlative grid of poses ``center`` + (±``radius`` in
    ``step``, ±``half_angle`` in ``angle_step``) scored by Σ_b min(ρ_b, ``coarse2``);
    ``center`` itself and the ``n_refine`` best, at least ``min_sep`` apart from each
    other and from ``center``, refined by :func:`scan_match` on the scan alone (residual
    cap ``cut2``). Returns the refined poses ``(M, 3)`` (the first refined from
    ``center``), their beams within ``sqrt(inlier2)`` of the map ``(M,)`` and the
    smallest eigenvalue of the position block of ``J^T J`` at each ``(M,)`` (about the
    number of beams that pin the position down in its weakest direction; ~0 along a
    corridor). The grid's headings are split over ``threads`` (the same scores in the
    same order whatever their number)."""
    na = int(round(half_angle / angle_step))
    headings = np.arange(-na, na + 1)
    kpose = np.empty((kf_pose.shape[0], 4))
    _kposes(kf_pose, 0, kpose)
    maps = (pts, li, alpha, grid, gint, meta, origins, inv_res, kpose)

    def part(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _loop_grid(center, *maps, coarse2, radius, step, angle_step, int(a[0]),
                          int(a[-1]) + 1)

    parts = np.array_split(headings, max(1, min(threads, len(headings))))
    done = thread_map(part, parts, threads)
    poses = np.concatenate([d[0] for d in done])
    cost = np.concatenate([d[1] for d in done])
    return _loop_refine(center, poses, cost, *maps, cut2, inlier2, inv_2s2, max_iter,
                        n_refine, min_sep)


@njit(cache=True, nogil=True)
def _loop_grid(center: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float,
               grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
               inv_res: float, kpose: np.ndarray, coarse2: float, radius: float, step: float,
               angle_step: float, a_from: int, a_to: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`loop_search`'s grid for the heading indices ``a_from .. a_to - 1``: its
    poses ``(N, 3)`` (heading, then x, then y) and their capped costs ``(N,)``."""
    n_b = pts.shape[0]
    cand = np.full((n_b, 2), -1, dtype=np.int64)
    work = np.empty((6, n_b))
    iwork = np.empty((2, n_b), dtype=np.int64)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    nxy = int(round(radius / step))
    n = (2 * nxy + 1) * (2 * nxy + 1) * (a_to - a_from)
    poses = np.empty((n, 3))
    cost = np.empty(n)
    q = 0
    for a in range(a_from, a_to):
        for i in range(-nxy, nxy + 1):
            for j in range(-nxy, nxy + 1):
                poses[q, 0] = center[0] + i * step
                poses[q, 1] = center[1] + j * step
                poses[q, 2] = center[2] + a * angle_step
                cost[q], _ = _score(poses[q, 0], poses[q, 1], poses[q, 2], pts, li, alpha,
                                    grid, gint, meta, origins, inv_res, kpose, coarse2,
                                    False, h, g, cand, 0, work, iwork)
                q += 1
    return poses, cost


@njit(cache=True, nogil=True)
def _loop_refine(center: np.ndarray, poses: np.ndarray, cost: np.ndarray, pts: np.ndarray,
                 li: np.ndarray, alpha: float, grid: np.ndarray, gint: np.ndarray,
                 meta: np.ndarray, origins: np.ndarray, inv_res: float, kpose: np.ndarray,
                 cut2: float, inlier2: float, inv_2s2: float, max_iter: int, n_refine: int,
                 min_sep: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`loop_search`'s refinement of ``center`` and of the best grid poses."""
    n_b = pts.shape[0]
    cand = np.full((n_b, 2), -1, dtype=np.int64)
    work = np.empty((6, n_b))
    iwork = np.empty((2, n_b), dtype=np.int64)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    order = np.argsort(cost)
    kept = np.empty((n_refine + 1, 3))
    kept[0] = center  # the current estimate, refined too: the rival every mode must beat
    m = 1
    for q in order:
        far = True
        for r in range(m):
            if math.hypot(poses[q, 0] - kept[r, 0], poses[q, 1] - kept[r, 1]) < min_sep:
                far = False
                break
        if far:
            kept[m] = poses[q]
            m += 1
            if m == n_refine + 1:
                break
    free = np.zeros((2, 3))
    out = np.empty((m, 3))
    inl = np.empty(m, dtype=np.int64)
    eig = np.empty(m)
    for r in range(m):
        hat, _, _ = scan_match(kept[r], pts, li, alpha, grid, gint, meta, origins, inv_res,
                               kpose, cut2, max_iter, cand, h, work, iwork, inv_2s2, free)
        out[r] = hat
        tr = h[0, 0] + h[1, 1]
        det = h[0, 0] * h[1, 1] - h[0, 1] * h[0, 1]
        eig[r] = 0.5 * tr - math.sqrt(max(0.25 * tr * tr - det, 0.0))
        _, inl[r] = _score(hat[0], hat[1], hat[2], pts, li, alpha, grid, gint, meta, origins,
                           inv_res, kpose, inlier2, False, h, g, cand, 0, work, iwork)
    return out, inl, eig


@njit(cache=True, nogil=True)
def score_offsets(hat: np.ndarray, offs: np.ndarray, pts: np.ndarray, li: np.ndarray,
                  alpha: float, grid: np.ndarray, gint: np.ndarray, meta: np.ndarray,
                  origins: np.ndarray, inv_res: float, kpose: np.ndarray, cut2: float,
                  cand: np.ndarray, out: np.ndarray) -> None:
    """``out[j]`` = Σ_b ρ_b at the pose ``hat + offs[j]`` on each beam's candidate
    keyframes ``cand``: what :func:`_score` gives in mode 2 for each pose, to the bit
    (the same sums in the same order), but beam by beam -- one beam's lookups at the
    nearby poses read the same few cells, and its keyframe's constants are loaded once."""
    n = offs.shape[0]
    xs = np.empty(n)
    ys = np.empty(n)
    cs = np.empty(n)
    sn = np.empty(n)
    best = np.empty(n)
    for j in range(n):
        xs[j] = hat[0] + offs[j, 0]
        ys[j] = hat[1] + offs[j, 1]
        t = hat[2] + offs[j, 2]
        cs[j] = math.cos(t)
        sn[j] = math.sin(t)
        out[j] = 0.0
    use_i = alpha > 0.0
    for b in range(pts.shape[0]):
        px = pts[b, 0]
        py = pts[b, 1]
        lb = li[b] if use_i else 0.0
        for j in range(n):
            best[j] = cut2
        for m in range(cand.shape[1]):
            k = cand[b, m]
            if k < 0:
                continue
            ck, sk, tx, ty, off, nb, nx, ny, ox, oy = _keyframe(kpose, meta, origins, k)
            geo = nb == 1 and not use_i
            for j in range(n):
                # the world point as _score forms it (x + c px - s py), then its frame
                qx, qy = _to_keyframe(ck, sk, tx, ty, xs[j] + cs[j] * px - sn[j] * py,
                                      ys[j] + sn[j] * px + cs[j] * py)
                if geo:
                    base, fu, fv = _corners(off, nx, ny, ox, oy, inv_res, qx, qy)
                    if base < 0:
                        continue
                    val = _interpolate(grid, base, ny, fu, fv)
                else:
                    val, _, _ = _lookup(grid, gint, off, nb, nx, ny, ox, oy, inv_res, qx, qy,
                                        lb, alpha, cut2, best[j], False)
                if val < best[j]:
                    best[j] = val
        for j in range(n):
            out[j] += best[j]


@njit(cache=True, nogil=True)
def propose_all(x_prev: np.ndarray, u: np.ndarray, u_start: np.ndarray, sig: np.ndarray,
                pts: np.ndarray,
                li: np.ndarray, alpha: float, grid: np.ndarray, gint: np.ndarray,
                meta: np.ndarray, origins: np.ndarray, inv_res: float, kf_pose: np.ndarray,
                cut2: float, inv_2s2: float, min_delta: np.ndarray, max_iter: int,
                min_inliers: int, use_prior: bool,
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
    grid27 = np.zeros((27, 3))
    j = 0
    for a in range(-1, 2):
        for b in range(-1, 2):
            for c in range(-1, 2):
                grid27[j, 0] = a
                grid27[j, 1] = b
                grid27[j, 2] = c
                j += 1
    offs = np.zeros((27, 3))
    delta = np.zeros(3)
    floor = np.empty(3)
    kpose = np.empty((kf_pose.shape[0], 4))
    cand = np.full((pts.shape[0], 2), -1, dtype=np.int64)
    work = np.empty((6, pts.shape[0]))
    iwork = np.empty((2, pts.shape[0]), dtype=np.int64)
    h = np.zeros((3, 3))
    log_tau = np.empty(27)
    costs = np.empty(27)
    start = np.empty(3)
    for p in range(n_u):
        _kposes(kf_pose, p, kpose)
        x0 = x_prev[p]
        compose_into(x0, u_start, start)  # x' = x_{t-1} (+) u
        hat, _, inl = scan_match(start, pts, li, alpha, grid, gint, meta, origins, inv_res,
                                 kpose, cut2, max_iter, cand, h, work, iwork, inv_2s2,
                                 _prior(x0, u, sig, use_prior))
        xhat[p] = hat
        if inl < min_inliers:
            continue
        sample_steps(h, 2.0 * inv_2s2, sig, min_delta, delta)
        for j in range(27):
            for a in range(3):
                offs[j, a] = grid27[j, a] * delta[a]
        score_offsets(hat, offs, pts, li, alpha, grid, gint, meta, origins, inv_res, kpose,
                      cut2, cand, costs)
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
def loglik_all(poses: np.ndarray, pts: np.ndarray, li: np.ndarray, alpha: float,
               grid: np.ndarray, gint: np.ndarray, meta: np.ndarray, origins: np.ndarray,
               inv_res: float, kf_pose: np.ndarray, cut2: float,
               inv_2s2: float) -> np.ndarray:
    """``log p(z | m, x) = -Σ_b ρ_b / (2σ²)`` of each pose ``(P, 3)`` against its own map
    ``kf_pose (K, P, 3)`` (the weight of a particle drawn from the motion model)."""
    n_p = poses.shape[0]
    out = np.empty(n_p)
    kpose = np.empty((kf_pose.shape[0], 4))
    cand = np.zeros((1, 2), dtype=np.int64)
    work = np.empty((6, pts.shape[0]))
    iwork = np.empty((2, pts.shape[0]), dtype=np.int64)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    for p in range(n_p):
        _kposes(kf_pose, p, kpose)
        cost, _ = _score(poses[p, 0], poses[p, 1], poses[p, 2], pts, li, alpha, grid, gint,
                         meta, origins, inv_res, kpose, cut2, False, h, g, cand, 0, work,
                         iwork)
        out[p] = -cost * inv_2s2
    return out
