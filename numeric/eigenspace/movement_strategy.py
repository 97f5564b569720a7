"""Movement strategy (paper §3.5, eqs. 8-11).

Poses s^(i) (Monte Carlo samples of where the robot may be) carry a distribution
over the states X, Y^(1..M), Z.  An action a = (alpha, l, beta) turns by alpha,
drives l (stopping ``clearance_m`` short of a wall) and turns by beta; at the new
pose every region l is entered with P(R^(l)|s) of eq. 7, and the state moves by
eq. 9 (from X), eq. 10 (from Y^(m)) and eq. 11 (from Z).  Q(Z) of an action is the
sample-weighted P(Z) after it (eq. 8); the strategy picks the action with the
largest Q(Z) (ties: the shorter turn, then the shorter drive).

Eq. 9's ``Y^(m)`` term multiplies in ``1 - P(R_Y^(m'))`` for the other sets m' (the
"M = {1..m-1, m+1..M}" of the paper); eq. 10 keeps Y^(m) only if neither a Z region
nor another set is entered (entering another set narrows to their common element, Z).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial import cKDTree

from chizu.numeric.eigenspace.localization import Session
from chizu.numeric.eigenspace.regions import EntryModel
from chizu.numeric.geometry import compose, free_distance, heading_bin, wrap_angle

Angle = Annotated[float, Field(ge=-2 * np.pi, le=2 * np.pi, allow_inf_nan=False)]
Length = Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)]


class StrategyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_samples: int = Field(400, ge=10, le=100_000, description="I initial poses of eq. 8")
    #: the action grid (alpha, l, beta) of eq. 8: turn, drive, turn; at most 64 values
    #: each (the grid is their product), finite
    alphas_rad: list[Angle] = Field(
        default_factory=lambda: [float(a) for a in np.deg2rad(np.arange(-135, 181, 45))],
        min_length=1, max_length=64)
    lengths_m: list[Length] = Field(default_factory=lambda: [0.5, 1.0, 2.0, 3.0, 4.0],
                                    min_length=1, max_length=64)
    betas_rad: list[Angle] = Field(default_factory=lambda: [0.0, float(np.pi / 2),
                                                           float(np.pi), float(-np.pi / 2)],
                                   min_length=1, max_length=64)
    clearance_m: float = Field(0.3, ge=0.0, le=10.0)
    appearance_tau: float | None = Field(
        0.05, gt=0.0, le=10.0,
        description="while no region has been entered, weigh where the robot may be by "
        "how well the learning images explain its turns (appearance_scores), with "
        "this temperature as a share of each turn's spread of f_d; null: the paper's eq. "
        "8 alone (every pose that has entered no region is alike)")
    appearance_samples: int = Field(4000, ge=10, le=100_000,
                                    description="poses drawn to weigh by appearance, "
                                    "resampled to n_samples")

    @property
    def initial_sample_count(self) -> int:
        """How many poses of stop 0 to draw: more when the turns' appearance weighs them
        (they are resampled to ``n_samples``)."""
        return self.n_samples if self.appearance_tau is None else self.appearance_samples

    @model_validator(mode="after")
    def _grid_size(self) -> StrategyConfig:
        n = len(self.alphas_rad) * len(self.lengths_m) * len(self.betas_rad)
        if n > 4096:
            raise ValueError(f"the action grid (alphas x lengths x betas) has {n} actions; "
                             "at most 4096")
        return self
    chunks: int = Field(4, ge=1, le=256, description="action-grid chunks for the executor")

    def actions(self) -> np.ndarray:
        """The action grid ``(A, 3)``: (alpha, l, beta), ordered so ties prefer small
        turns and short drives."""
        grid = np.array([(a, d, b) for a in self.alphas_rad for d in self.lengths_m
                         for b in self.betas_rad], dtype=float)
        order = np.lexsort((np.abs(wrap_angle(grid[:, 2])), grid[:, 1],
                            np.abs(wrap_angle(grid[:, 0]))))
        return grid[order]


@dataclass
class RegionLayout:
    """What eqs. 9-11 need: the entry model, the learning points of each region
    ``(T, 3, 2)`` and the candidate-multiple set of each region (``-1``: none, else
    0..M-1)."""

    entry: EntryModel
    points: np.ndarray
    set_of: np.ndarray
    walls: tuple[np.ndarray, np.ndarray]
    #: the learning points ``(Nw, 2)`` (for :func:`appearance_scores`), if known
    learning_points: np.ndarray | None = None

    def __post_init__(self) -> None:
        # the regions share learning points: distances to the distinct points, then the
        # smallest over each triplet's three (a tenth of the square roots in room A)
        flat = np.asarray(self.points, dtype=float).reshape(-1, 2)
        self._sites, inv = np.unique(flat, axis=0, return_inverse=True)
        self._member = inv.reshape(-1, 3)

    @property
    def n_sets(self) -> int:
        return int(self.set_of.max()) + 1 if len(self.set_of) else 0

    def entry_probabilities(self, xy: np.ndarray) -> np.ndarray:
        """P(R^(l)|s) ``(I, T)`` for positions ``(I, 2)`` (eq. 7 with D(s) of §3.2)."""
        if len(self.points) == 0:
            return np.zeros((len(xy), 0))
        to_site = np.hypot(xy[:, None, 0] - self._sites[None, :, 0],
                           xy[:, None, 1] - self._sites[None, :, 1])  # (I, sites)
        d = to_site[:, self._member].min(axis=2)
        return self.entry.probability(d)

    def p_any(self, xy: np.ndarray) -> np.ndarray:
        """Probability ``(I,)`` that one observation at ``xy`` enters some region."""
        return 1.0 - np.prod(1.0 - self.entry_probabilities(xy), axis=1)


@dataclass
class StateBelief:
    """Per-sample state distribution: ``x (I,)``, ``y (I, M)``, ``z (I,)`` and weights."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    weight: np.ndarray

    @staticmethod
    def start(n: int, m: int, weight: np.ndarray | None = None) -> StateBelief:
        w = np.full(n, 1.0 / n) if weight is None else weight / weight.sum()
        return StateBelief(np.ones(n), np.zeros((n, m)), np.zeros(n), w)

    def p_z(self) -> float:
        return float(np.dot(self.weight, self.z))


def transition(belief: StateBelief, p: np.ndarray, layout: RegionLayout) -> StateBelief:
    """One observation at poses with entry probabilities ``p (I, T)``: eqs. 9-11."""
    miss = 1.0 - p
    in_z = layout.set_of < 0
    q_no_z = np.prod(miss[:, in_z], axis=1)  # prod_k (1 - P(R_Z^k))
    m = layout.n_sets
    q_no_y = np.ones((len(p), m))
    for k in range(m):
        q_no_y[:, k] = np.prod(miss[:, layout.set_of == k], axis=1)
    p_y = 1.0 - q_no_y  # P(R_Y^(m)): one or more regions of set m
    others_no_y = np.ones((len(p), m))  # prod over m' != m of (1 - P(R_Y^(m')))
    for k in range(m):
        others_no_y[:, k] = np.prod(np.delete(q_no_y, k, axis=1), axis=1)
    q_x = np.prod(miss, axis=1)                                   # eq. 9, W_n = X
    q_y_from_x = p_y * others_no_y * q_no_z[:, None]              # eq. 9, W_n = Y^(m)
    stay_y = others_no_y * q_no_z[:, None]                        # eq. 10, W_n = Y^(m)
    x = belief.x * q_x
    y = belief.x[:, None] * q_y_from_x + belief.y * stay_y
    z = 1.0 - x - y.sum(axis=1)                                   # eqs. 9-11, W_n = Z
    return StateBelief(x, y, np.clip(z, 0.0, 1.0), belief.weight)


def apply_action(poses: np.ndarray, action: np.ndarray, walls: tuple[np.ndarray, np.ndarray],
                 clearance_m: float) -> np.ndarray:
    """s (+) a of §3.4 for poses ``(I, 3)``; a drive stops ``clearance_m`` before a wall."""
    alpha, length, beta = (float(v) for v in action)
    heading = poses[:, 2] + alpha
    room = free_distance(poses[:, :2], heading, walls[0], walls[1]) - clearance_m
    ell = np.clip(np.minimum(length, room), 0.0, None)
    out = np.empty_like(poses)
    out[:, 0] = poses[:, 0] + ell * np.cos(heading)
    out[:, 1] = poses[:, 1] + ell * np.sin(heading)
    out[:, 2] = wrap_angle(heading + beta)
    return out


def _q_z_chunk(args: tuple[np.ndarray, StateBelief, np.ndarray, RegionLayout, float]
               ) -> np.ndarray:
    poses, belief, actions, layout, clearance = args
    out = np.empty(len(actions))
    for i, a in enumerate(actions):
        moved = apply_action(poses, a, layout.walls, clearance)
        out[i] = transition(belief, layout.entry_probabilities(moved[:, :2]), layout).p_z()
    return out


def q_z_of_actions(poses: np.ndarray, belief: StateBelief, actions: np.ndarray,
                   layout: RegionLayout, config: StrategyConfig,
                   executor: Executor | None = None) -> np.ndarray:
    """Q(Z) (eq. 8) of every action ``(A, 3)``; chunks run on ``executor`` when given
    (a ProcessPoolExecutor parallelises over cores), in-process otherwise."""
    chunks = [c for c in np.array_split(actions, config.chunks) if len(c)]
    jobs = [(poses, belief, c, layout, config.clearance_m) for c in chunks]
    mapper: Callable[[Any, Iterable[Any]], Iterator[Any]] = (
        executor.map if executor is not None else map)  # type: ignore[assignment]
    return np.concatenate(list(mapper(_q_z_chunk, jobs)))


@dataclass
class Decision:
    action: np.ndarray  # (alpha, l, beta)
    q_z: float


def choose_action(poses: np.ndarray, belief: StateBelief, layout: RegionLayout,
                  config: StrategyConfig, executor: Executor | None = None) -> Decision:
    """The action of the grid with the largest Q(Z) (first in grid order on ties)."""
    actions = config.actions()
    q = q_z_of_actions(poses, belief, actions, layout, config, executor)
    best = int(np.argmax(q >= q.max() - 1e-12))
    return Decision(actions[best], float(q[best]))


def initial_samples(sample_free: Callable[[int, np.random.Generator], np.ndarray], n: int,
                    rng: np.random.Generator) -> np.ndarray:
    """I initial poses: positions from ``sample_free``, headings uniform."""
    xy = sample_free(n, rng)
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, len(xy))])


def p_z_curve(poses: np.ndarray, layout: RegionLayout, config: StrategyConfig,
              n_observations: int, executor: Executor | None = None
              ) -> tuple[list[float], list[np.ndarray]]:
    """P(Z) after 1..n observations when every move follows the strategy (§4.1), and
    the chosen actions.  The first observation is at the initial poses."""
    belief = StateBelief.start(len(poses), layout.n_sets)
    belief = transition(belief, layout.entry_probabilities(poses[:, :2]), layout)
    curve, acts = [belief.p_z()], []
    for _ in range(n_observations - 1):
        dec = choose_action(poses, belief, layout, config, executor)
        poses = apply_action(poses, dec.action, layout.walls, config.clearance_m)
        belief = transition(belief, layout.entry_probabilities(poses[:, :2]), layout)
        curve.append(belief.p_z())
        acts.append(dec.action)
    return curve, acts


def appearance_scores(points: np.ndarray, appearance: np.ndarray, xy: np.ndarray,
                      radius_m: float, tau: float) -> np.ndarray:
    """How well a turn that started at each of the positions ``xy (I, 2)``, facing
    each learned direction 2 pi m / n, agrees with what was seen: ``(I, n)`` in (0, 1].
    The learning points near a position (Gaussian weights of ``radius_m``) vote with
    ``exp(-(A[i, m] - min A) / (tau * spread))``, where ``A`` is the turn's
    :func:`~chizu.numeric.eigenspace.localization.turn_appearance` and the spread is its
    median minus its minimum.

    Beyond Maeda & Shirai: eq. 8 weighs the initial poses s_0^(i) by
    P(s_0^(i)|a_1..a_n), which §3.5 leaves uniform over the poses that entered no
    region. A turn that enters no region still shows roughly where the robot is and
    which way it faces (the nearest learning image, Table 2's baseline, is about 0.6 m
    off in room A); without it every heading is alike, and the turn alpha of an action
    cannot matter while the state is X."""
    pts = np.asarray(points, dtype=float)
    d2 = (xy[:, None, 0] - pts[None, :, 0]) ** 2 + (xy[:, None, 1] - pts[None, :, 1]) ** 2
    near = np.exp(-d2 / (2.0 * radius_m ** 2))  # (I, Nw)
    near /= np.maximum(near.sum(axis=1, keepdims=True), 1e-300)
    a = np.asarray(appearance, dtype=float)
    spread = max(float(np.median(a) - a.min()), 1e-12)
    return np.asarray(near @ np.exp(-(a - a.min()) / (tau * spread)))


def learning_spacing(points: np.ndarray) -> float:
    """The median distance from a learning point to its nearest other point [m]."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return 1.0
    return float(np.median(cKDTree(pts).query(pts, k=2)[0][:, 1]))


def session_belief(session: Session, layout: RegionLayout, samples0: np.ndarray,
                   candidate_set: int | None = None, config: StrategyConfig | None = None
                   ) -> tuple[np.ndarray, StateBelief]:
    """Where the robot may be now ``(I, 3)`` and its state distribution, to choose the
    next move of a running localization.

    While no region has been entered (state X): the initial samples ``samples0`` (poses
    of stop 0) moved by the session's odometry, weighted by the chance of having stayed
    in X at every stop so far and, with ``config.appearance_tau`` and the layout's
    learning points, by :func:`appearance_scores` of every stop's turn; those are
    then resampled (systematically, deterministically) to ``config.n_samples``.
    Afterwards: the strongest candidate of every identified group, weighted by its
    votes; with ``candidate_set`` m (1-based, state Y^(m)) the belief starts in Y^(m).
    """
    if not session.pose0:
        logw = np.zeros(len(samples0))
        pts = layout.learning_points
        tau = None if config is None else config.appearance_tau
        score: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
        apps: list[np.ndarray | None] = [None] * session.stops
        if pts is not None and len(pts) and tau is not None:
            radius = learning_spacing(pts) / 2.0
            apps = [a if a is not None and a.shape[0] == len(pts) else None
                    for a in session.appearance[:session.stops]]
            apps += [None] * (session.stops - len(apps))

            def score(app: np.ndarray, xy: np.ndarray) -> np.ndarray:
                return appearance_scores(pts, app, xy, radius, tau)
        if score is not None and apps and apps[0] is not None:
            # stop 0's heading drawn from its appearance given the position (importance
            # sampling: uniform positions, headings from p(theta | xy)); the weight is
            # that conditional's normaliser
            sc = score(apps[0], samples0[:, :2])
            n = sc.shape[1]
            cdf = np.cumsum(sc, axis=1)
            r = np.random.default_rng(0)
            u = r.uniform(0.0, 1.0, len(sc)) * cdf[:, -1]
            m = np.minimum((cdf < u[:, None]).sum(axis=1), n - 1)
            samples0 = samples0.copy()
            samples0[:, 2] = wrap_angle(2.0 * np.pi * (m + r.uniform(-0.5, 0.5, len(m))) / n)
            logw += np.log(np.maximum(sc.mean(axis=1), 1e-300))
        for k, o in enumerate(session.odometry):
            moved = compose(samples0, o)
            stay = np.prod(1.0 - layout.entry_probabilities(moved[:, :2]), axis=1)
            logw += np.log(np.maximum(stay, 1e-300))
            app = apps[k]
            if k > 0 and score is not None and app is not None:
                sc = score(app, moved[:, :2])
                lik = sc[np.arange(len(sc)), heading_bin(moved[:, 2], sc.shape[1])]
                logw += np.log(np.maximum(lik, 1e-300))
        weight = np.exp(logw - logw.max())
        if not np.isfinite(weight).all() or weight.sum() <= 0:
            weight = np.ones(len(samples0))
        now = compose(samples0, session.odometry[-1]) if session.odometry else samples0
        if any(a is not None for a in apps) and config is not None \
                and len(now) > config.n_samples:
            # systematic resampling, fixed offset: the same session gives the same belief
            c = np.cumsum(weight / weight.sum())
            u = (np.arange(config.n_samples) + 0.5) / config.n_samples
            now = now[np.minimum(np.searchsorted(c, u), len(now) - 1)]
            weight = np.ones(len(now))
        return now, StateBelief.start(len(now), layout.n_sets, weight)
    vote = session.vote()
    reps = session.representatives(vote)
    now = np.array([session.current_pose(i) for i in reps])
    belief = StateBelief.start(len(now), layout.n_sets, vote.votes[reps])
    if candidate_set is not None and 1 <= candidate_set <= layout.n_sets:
        belief.x[:] = 0.0
        belief.y[:, candidate_set - 1] = 1.0
    return now, belief
