"""Viewpoint planning (numeric/viewpoint): appearance model, eq. 5 DP, tables, local
strategies, unknown regions, global plan solvers, grids and the online loop."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest

from chizu.numeric.errors import InvalidInput
from chizu.numeric.viewpoint.appearance import (
    AngleSample,
    AppearanceModel,
    DistanceSample,
    MeasurementTables,
    exp_distance,
    sigmoid_angle,
)
from chizu.numeric.viewpoint.grid import from_occupancy_values, true_grid
from chizu.numeric.viewpoint.plan import (
    GroupCost,
    Loss,
    Problem,
    solve,
    solve_bnb,
    solve_exhaustive,
)
from chizu.numeric.viewpoint.recognition import OBJECT_KINDS, fitted_models
from chizu.numeric.viewpoint.single import min_plus, single_dp
from chizu.numeric.viewpoint.verification import Candidate, Verifier, unknown_region_time
from chizu.numeric.viewpoint.viewpoints import PATTERNS, viewpoint_circles
from chizu.numeric.world import Wall, World, WorldDescription


@pytest.fixture(scope="module")
def models() -> dict[str, AppearanceModel]:
    return fitted_models()


# -- appearance model (§3) ------------------------------------------------------------
def test_fit_recovers_known_parameters() -> None:
    a, b, k, half = (80.0, 60.0, 50.0, 70.0), (0.9, 0.7, 1.1, 0.8), 5.0, 0.7
    d = np.linspace(0.3, 2.5, 12)
    th = np.radians(np.arange(-80, 81, 5))
    tables = MeasurementTables(
        distance=[DistanceSample(face=j, d_m=float(x), matches=float(exp_distance(x, a[j], b[j])))
                  for j in range(4) for x in d],
        angle=[AngleSample(theta_rad=float(t), ratio=float(sigmoid_angle(t, k, half)))
               for t in th])
    m, rep = AppearanceModel.fit(tables)
    assert np.allclose(m.params.a, a, rtol=1e-3) and np.allclose(m.params.b, b, rtol=1e-3)
    assert m.params.k == pytest.approx(k, rel=1e-2)
    assert m.params.theta_half == pytest.approx(half, rel=1e-2)
    assert max(rep.distance_rmse) < 1e-3


def test_fit_needs_two_distances_per_face() -> None:
    rows = [DistanceSample(face=j % 4, d_m=1.0, matches=10.0) for j in range(8)]
    tables = MeasurementTables(distance=rows, angle=[AngleSample(theta_rad=0, ratio=1)] * 3)
    with pytest.raises(InvalidInput) as e:
        AppearanceModel.fit(tables)
    assert e.value.field == "tables.distance"


def test_simulated_fit_is_close_to_the_simulator(models: dict[str, AppearanceModel]) -> None:
    """The model is fitted to simulated measurements; its R_max should be within 25 % of
    the simulator's true reach of the best face."""
    for name, kind in OBJECT_KINDS.items():
        true_reach = kind.d_half_m * np.sqrt(max(kind.features) / 15.0 - 1)
        assert models[name].r_max == pytest.approx(true_reach, rel=0.25)
        assert 0 < models[name].r_min() < models[name].r_max


def test_posterior_peaks_at_the_true_orientation(models: dict[str, AppearanceModel]) -> None:
    m = models["A"]
    robot, obj = np.array([1.0, 0.2]), np.zeros(2)
    for i in range(m.n_theta):
        z = m.predict(robot[None], obj, m.thetas[i:i + 1])[0]
        post = m.posterior(z, robot, obj)
        assert post.sum() == pytest.approx(1.0)
        assert post[i] == post.max()
    with pytest.raises(InvalidInput):
        m.posterior([1.0, np.nan, 0, 0], robot, obj)


def test_p_recog_is_one_inside_r_min_and_zero_beyond_r_max(models: dict[str, AppearanceModel],
                                                          ) -> None:
    m = models["B"]
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    assert np.allclose(m.p_recog(0.95 * m.r_min() * ring, np.zeros(2)), 1.0)
    assert np.allclose(m.p_recog(1.05 * m.r_max * ring, np.zeros(2)), 0.0)
    mid = m.p_recog(0.5 * (m.r_min() + m.r_max) * ring, np.zeros(2))
    assert np.all((mid > 0) & (mid < 1))


# -- eq. 5 ----------------------------------------------------------------------------
def _eq5_by_recursion(points: np.ndarray, recog: np.ndarray, belief: np.ndarray,
                      start: np.ndarray, goal: np.ndarray, speed: float, tv: float) -> float:
    """The paper's recursion over the remaining viewpoint set S - {X}, with eq. 4's
    indicator conditioned on the orientations not yet ruled out."""

    @functools.cache
    def t(pos: int, remaining: frozenset[int], mask: int) -> float:
        at = start if pos < 0 else points[pos]
        best = np.inf
        bits = np.array([(mask >> i) & 1 for i in range(len(belief))], dtype=bool)
        mass = belief[bits].sum()
        for v in remaining:
            p = belief[bits & recog[v]].sum() / mass if mass > 0 else 0.0
            if p == 0:
                continue
            nxt = mask & ~sum(1 << i for i in np.nonzero(recog[v])[0])
            rest = t(v, remaining - {v}, nxt) if p < 1 else 0.0
            cost = (np.hypot(*(at - points[v])) / speed + tv
                    + p * np.hypot(*(points[v] - goal)) / speed + (1 - p) * rest)
            best = min(best, cost)
        return float(np.hypot(*(at - goal)) / speed) if not np.isfinite(best) else best

    return t(-1, frozenset(range(len(points))), (1 << len(belief)) - 1)


@pytest.mark.parametrize("seed", range(6))
def test_single_dp_equals_the_recursion_of_eq5(models: dict[str, AppearanceModel],
                                               seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = models["ABC"[seed % 3]]
    radii = m.radii(0.5)
    pts = viewpoint_circles(np.zeros(2), radii)[rng.choice(24, 7, replace=False)]
    rec = m.recognisable(pts, np.zeros(2))
    belief = rng.dirichlet(np.ones(m.n_theta))
    if seed >= 3:  # some orientations already ruled out
        belief[rng.choice(m.n_theta, seed - 1, replace=False)] = 0.0
        belief /= belief.sum()
    start, goal = np.array([3.0, -1.0]), np.array([-2.0, 2.5])
    q, ok = single_dp(pts, rec, belief, goal[None], 0.4, 2.0)
    assert ok
    dp = float(np.min(np.hypot(*(pts - start).T) / 0.4 + q[0]))
    assert dp == pytest.approx(_eq5_by_recursion(pts, rec, belief, start, goal, 0.4, 2.0))


def test_table_mode_matches_exact_in_open_space(models: dict[str, AppearanceModel]) -> None:
    c = Candidate("c", "A", np.array([2.0, 1.0]), models["A"])
    s, g = np.array([[0.0, 0.0], [5.0, 3.0]]), np.array([[0.0, 0.0], [1.0, 4.0]])
    exact = Verifier(None, 0.4, 2.0, use_table=False).single(c, s, g)
    table = Verifier(None, 0.4, 2.0, use_table=True).single(c, s, g)
    assert np.all(table >= exact - 1e-9)        # eq. 6 routes through a table end point
    assert np.all(table <= exact * 1.15)


def _box_world(objects: list[tuple[float, float]] = ()) -> World:  # type: ignore[assignment]
    w, h = 6.0, 5.0
    walls = [Wall(a=(0, 0), b=(w, 0)), Wall(a=(w, 0), b=(w, h)), Wall(a=(w, h), b=(0, h)),
             Wall(a=(0, h), b=(0, 0))]
    return World(WorldDescription(name="box", walls=walls))


def test_a_wall_removes_viewpoints_and_costs_time(models: dict[str, AppearanceModel]) -> None:
    grid = true_grid(_box_world())
    v = Verifier(grid, 0.4, 2.0)
    free = Candidate("free", "A", np.array([3.0, 2.5]), models["A"])
    wall = Candidate("wall", "A", np.array([3.0, 0.45]), models["A"])
    assert v.viewpoints(free).pattern == "open"
    assert v.viewpoints(wall).pattern in ("wall", "corner", "front")
    assert grid.free(v.viewpoints(wall).points, 0.25).all()
    s = np.array([[3.0, 2.0]])
    assert v.single(wall, s, s)[0, 0] > v.single(free, s, s)[0, 0]
    assert set(PATTERNS) == {"open", "three_quarter", "wall", "corner", "front"}


def test_pattern_tables_are_reused_across_objects_of_a_type(models: dict[str, AppearanceModel],
                                                           ) -> None:
    v = Verifier(None, 0.4, 2.0)
    s = np.zeros((1, 2))
    for k in range(5):
        v.single(Candidate(f"c{k}", "A", np.array([k, 2.0 * k]), models["A"]), s, s)
    assert v.tables.builds == 1 and v.tables.hits == 4


def test_a_turned_pattern_table_is_the_unturned_one_with_the_belief_rolled(
        models: dict[str, AppearanceModel]) -> None:
    """Every rotation's table, built from rotation 0 with the belief rolled, equals the
    DP of eq. 5 run directly on the turned viewpoints with the original belief; a
    uniform belief builds one table for all eight rotations."""
    from chizu.numeric.viewpoint.single import TableCache
    from chizu.numeric.viewpoint.viewpoints import pattern_indices

    rng = np.random.default_rng(3)
    m = models["B"]
    radii = m.radii(0.5)
    for belief in (m.uniform_prior(), rng.dirichlet(np.ones(m.n_theta)),
                   np.r_[1.0, np.zeros(m.n_theta - 1)]):
        cache = TableCache()
        for pattern in ("wall", "three_quarter"):
            for rot in range(8):
                tab = cache.get(m, radii, pattern, rot, belief, 0.4, 2.0)
                pts = viewpoint_circles(np.zeros(2), radii)[pattern_indices(pattern, rot)]
                q, ok = single_dp(pts, m.recognisable(pts, np.zeros(2)), belief, pts, 0.4, 2.0)
                assert tab.feasible == ok
                assert np.allclose(tab.points, pts)
                direct = min_plus(q, np.hypot(*(pts[:, None] - pts[None]).T).T / 0.4)
                if ok:
                    assert np.allclose(tab.times, direct)
        if np.allclose(belief, m.uniform_prior()):
            assert cache.builds == 2 and cache.hits == 14


def test_parallel_beats_sequential_for_objects_side_by_side(models: dict[str, AppearanceModel],
                                                           ) -> None:
    v = Verifier(None, 0.4, 2.0)
    a = Candidate("a", "A", np.array([2.0, 2.0]), models["A"])
    b = Candidate("b", "B", np.array([2.6, 2.0]), models["B"])
    c = Candidate("c", "C", np.array([2.3, 2.5]), models["C"])
    s = np.array([[0.0, 0.0]])
    two = v.group([a, b], s, s)[0]
    assert two.t_par_s is not None and two.t_seq_s is not None
    assert two.strategy == "par" and two.t_par_s < two.t_seq_s
    three = v.group([a, b, c], s, s)[0]
    assert np.isfinite(three.time_s) and set(three.order) == {"a", "b", "c"}
    assert three.time_s > two.time_s


def test_sequential_order_prefers_the_near_object_first(models: dict[str, AppearanceModel],
                                                       ) -> None:
    v = Verifier(None, 0.4, 2.0)
    near = Candidate("near", "A", np.array([1.5, 0.0]), models["A"])
    far = Candidate("far", "A", np.array([6.0, 0.0]), models["A"])
    t, order_of, exact = v.sequential([far, near], np.zeros((1, 2)), np.array([[8.0, 0.0]]))
    assert exact and order_of(0, 0) == ("near", "far")
    rev, _, _ = v.sequential([far, near], np.zeros((1, 2)), np.array([[-2.0, 0.0]]))
    assert np.isfinite(rev[0, 0])


def cluster(models: dict[str, AppearanceModel], k: int, seed: int = 1) -> list[Candidate]:
    """k objects of mixed types scattered over a 3 m x 3 m patch."""
    rng = np.random.default_rng(seed)
    types = list(OBJECT_KINDS)
    return [Candidate(f"o{i}", types[i % len(types)], rng.uniform(2.0, 5.0, 2),
                      models[types[i % len(types)]]) for i in range(k)]


def chain_time(v: Verifier, order: tuple[Candidate, ...], start: np.ndarray,
               goal: np.ndarray) -> float:
    """Eq. 7 along one order, over every hand-over viewpoint (the permutation form)."""
    if len(order) == 1:
        return float(v.single(order[0], start, goal)[0, 0])
    pts = [v.viewpoints(c).points for c in order]
    vec = v.single(order[0], start, pts[0])
    for i in range(1, len(order) - 1):
        vec = min_plus(vec, v.single(order[i], pts[i - 1], pts[i]))
    return float(min_plus(vec, v.single(order[-1], pts[-2], goal))[0, 0])


def test_sequential_dp_equals_every_order(models: dict[str, AppearanceModel]) -> None:
    """The DP over subsets finds eq. 7's minimum over all k! orders and hand-overs, and
    the order it reports attains it."""
    v = Verifier(None, 0.4, 2.0)
    cands = cluster(models, 4)
    s, g = np.array([[0.0, 0.0]]), np.array([[7.0, 1.0]])
    t, order_of, exact = v.sequential(cands, s, g)
    brute = [chain_time(v, o, s, g) for o in itertools.permutations(cands)]
    assert exact and t[0, 0] == pytest.approx(min(brute), rel=1e-9)
    by_id = {c.id: c for c in cands}
    assert chain_time(v, tuple(by_id[i] for i in order_of(0, 0)), s, g) == pytest.approx(
        t[0, 0], rel=1e-9)


def test_parallel_sums_every_failure_set(models: dict[str, AppearanceModel]) -> None:
    """Eq. 8 generalised: the expected rest after a joint observation is the sum over the
    2^k failure sets of P(F) times eq. 7 over F, computed once for all F."""
    v = Verifier(None, 0.4, 2.0)
    cands = cluster(models, 3)
    g = np.array([[0.0, 0.0]])
    x = np.array([[3.5, 3.5], [3.0, 4.0]])
    p = np.array([[0.3, 0.6, 0.8], [0.5, 0.2, 0.9]])
    tab = v.handover_table(cands, g)
    want = np.zeros(len(x))
    for mask in range(8):
        failed = [c for i, c in enumerate(cands) if mask >> i & 1]
        prob = np.prod([1 - p[:, i] if mask >> i & 1 else p[:, i] for i in range(3)], axis=0)
        if not failed:
            rest = np.hypot(*x.T) / 0.4
        else:
            rest = np.array([min(chain_time(v, o, xi[None], g)
                                 for o in itertools.permutations(failed)) for xi in x])
        want += prob * rest
    np.testing.assert_allclose(tab.expected_rest(x, p)[:, 0], want, rtol=1e-9)


def test_large_groups_are_bounded_and_fast(models: dict[str, AppearanceModel],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Past EXACT_GROUP objects every object hands over at one viewpoint: the time of a
    policy the robot can follow, never below the exact minimum; its t_par expectation
    in closed form equals the sum over the failure sets for that fixed order."""
    import chizu.numeric.viewpoint.verification as ver
    from chizu.numeric.viewpoint.sequential import PortChain

    cands = cluster(models, 4)
    s, g = np.array([[0.0, 0.0]]), np.array([[7.0, 1.0]])
    exact = Verifier(None, 0.4, 2.0).sequential(cands, s, g)[0][0, 0]
    monkeypatch.setattr(ver, "EXACT_GROUP", 2)
    v = Verifier(None, 0.4, 2.0)
    t, order_of, is_exact = v.sequential(cands, s, g)
    assert not is_exact and exact <= t[0, 0] < 1.5 * exact
    assert sorted(order_of(0, 0)) == sorted(c.id for c in cands)
    tab = v.handover_table(cands, g)
    assert isinstance(tab, PortChain)
    x = np.array([[3.5, 3.5]])
    p = np.array([[0.3, 0.6, 0.8, 0.5]])
    by_id = {c.id: i for i, c in enumerate(cands)}
    chain = [by_id[c] for c in tab.chain]
    want = 0.0
    for mask in range(16):
        f = [i for i in chain if mask >> i & 1]
        prob = float(np.prod([1 - p[0, i] if mask >> i & 1 else p[0, i] for i in range(4)]))
        if not f:
            cost = float(np.hypot(*(x[0] - g[0])) / 0.4)
        elif len(f) == 1:
            cost = float(v.single(cands[f[0]], x, g)[0, 0])
        else:
            cost = float(v.single(cands[f[0]], x, tab.hand[f[0]][None])[0, 0])
            cost += sum(tab.cs[a, b] for a, b in zip(f[:-2], f[1:-1], strict=True))
            cost += float(tab.last[f[-2], f[-1]][0])
        want += prob * cost
    assert tab.expected_rest(x, p)[0, 0] == pytest.approx(want, rel=1e-9)
    # a 12-object group: the whole local plan, with a bound, in well under a second
    big = cluster(models, 12, seed=3)
    monkeypatch.setattr(ver, "EXACT_GROUP", 6)
    plans = Verifier(None, 0.4, 2.0).group(big, np.array([[0.0, 0.0]]), np.array([[0.0, 0.0]]))
    assert np.isfinite(plans[0].time_s) and not plans[0].exact
    assert sorted(plans[0].order) == sorted(c.id for c in big)


def test_unknown_region_time_eqs_9_10(models: dict[str, AppearanceModel]) -> None:
    v = Verifier(None, 0.4, 2.0)
    e, c = np.array([0.0, 0.0]), np.array([1.5, 1.0])
    assert unknown_region_time(v, models, {"A": 0.0}, c, e, 2.0, 4.0, 5.0, 3.0) == 5.0
    half = unknown_region_time(v, models, {"A": 1.0, "B": 1.0}, c, e, 2.0, 4.0, 5.0, 3.0)
    full = unknown_region_time(v, models, {"A": 1.0, "B": 1.0}, c, e, 4.0, 4.0, 5.0, 3.0)
    assert full - 5.0 == pytest.approx(2 * (half - 5.0))   # scales with A_G / A_U
    assert half > 5.0 + 0.5 * 3.0                           # plus t_dist (sum n - 1)


# -- global plan (§6) -----------------------------------------------------------------
def test_losses_eqs_12_to_14() -> None:
    t = np.array([10.0, 30.0, 32.35])
    assert list(Loss(kind="L1", t_limit_s=30).__call__(t)) == [0.0, np.inf, np.inf]
    assert Loss(kind="L2", t_limit_s=30, k_lim=0.5)(t)[2] == pytest.approx(0.5 * 2.35**2)
    assert not Loss(kind="L3", t_limit_s=30)(t).any()


@pytest.mark.parametrize("n", [1, 2, 4, 6, 7])
@pytest.mark.parametrize("kind", ["L1", "L2", "L3"])
def test_dp_and_exhaustive_find_the_same_optimum(n: int, kind: str) -> None:
    rng = np.random.default_rng(10 * n + len(kind))
    groups = [GroupCost(f"g{i}", "objects", float(rng.uniform(5, 100)), float(rng.uniform(1, 15)),
                        rng.uniform(0, 8, (3, 2))) for i in range(n)]
    p = Problem.build(groups, np.array([0.5, 0.5, 0]), np.array([0.5, 0.5]), 0.4,
                      Loss(kind=kind, t_limit_s=45, k_lim=0.5))  # type: ignore[arg-type]
    ref = solve_exhaustive(p)
    assert len(ref) == 1 + sum(len(list(itertools.permutations(range(n), r)))
                               for r in range(1, n + 1))
    best = solve(p, runner_ups=3)
    assert best[0].utility == pytest.approx(ref[0].utility)
    assert set(best[0].order) == set(ref[0].order)
    assert best[0].time == pytest.approx(ref[0].time)
    # runner-ups: best order of other sets, in the reference's order of those sets
    seen, ref_sets = set(), []
    for plan in ref:
        key = frozenset(plan.order)
        if key not in seen:
            seen.add(key)
            ref_sets.append(plan)
    for got, want in zip(best, ref_sets, strict=False):
        assert got.utility == pytest.approx(want.utility)


def random_problem(n: int, kind: str, seed: int) -> Problem:
    rng = np.random.default_rng(seed)
    groups = [GroupCost(f"g{i}", "objects", float(rng.uniform(5, 100)), float(rng.uniform(1, 15)),
                        rng.uniform(0, 10, (3, 2))) for i in range(n)]
    return Problem.build(groups, np.array([0.5, 0.5, 0]), np.array([0.5, 0.5]), 0.4,
                         Loss(kind=kind, t_limit_s=60, k_lim=0.5))  # type: ignore[arg-type]


@pytest.mark.parametrize("kind", ["L1", "L2", "L3"])
def test_branch_and_bound_finds_the_dp_optimum(kind: str) -> None:
    for n, seed in ((6, 1), (9, 2), (11, 3)):
        p = random_problem(n, kind, seed)
        dp = solve(p, runner_ups=0)[0]
        bb = solve_bnb(p, runner_ups=2, budget_s=30.0)
        assert bb.optimal and not bb.returned_early
        assert bb.plans[0].utility == pytest.approx(dp.utility, abs=1e-9)
        assert bb.plans[0].time == pytest.approx(dp.time)  # the set's fastest tour
        assert bb.upper_bound == pytest.approx(dp.utility, abs=1e-6)


@pytest.mark.parametrize("kind", ["L1", "L2", "L3"])
def test_state_bounds_hold_every_plan_through_the_state(kind: str) -> None:
    """The branch and bound's bound of a partial tour is at least the utility of every
    plan that starts with it (every order of every set of the other groups, by
    enumeration)."""
    from chizu.numeric.viewpoint.plan import evaluate, state_bounds

    for seed in range(4):
        p = random_problem(7, kind, 10 + seed)
        rng = np.random.default_rng(seed)
        for _ in range(6):
            k = int(rng.integers(1, 5))
            prefix = tuple(int(i) for i in rng.permutation(7)[:k])
            head = evaluate(p, prefix)
            t = head.t_move - p.t_exit[prefix[-1]] + head.t_obs   # time at the last group
            rest = [g for g in range(7) if g not in prefix]
            best = max(evaluate(p, prefix + tail).utility
                       for r in range(len(rest) + 1)
                       for tail in itertools.permutations(rest, r))
            b = state_bounds(p, np.array([sum(1 << i for i in prefix)]),
                             np.array([prefix[-1]]), np.array([t]), np.array([head.value]),
                             p.way_in())[0]
            assert b >= best - 1e-9


def test_branch_and_bound_out_of_time_reports_a_true_gap() -> None:
    p = random_problem(14, "L2", 5)
    dp = solve(p, runner_ups=0)[0]
    early = solve_bnb(p, runner_ups=0, budget_s=1e-4)
    assert early.returned_early and not early.optimal
    # the best plan so far is a real plan, and the bound holds the optimum
    assert early.plans[0].utility <= dp.utility + 1e-9 <= early.upper_bound + 1e-6
    assert early.gap == pytest.approx(early.upper_bound - early.plans[0].utility)


def test_too_many_groups_for_the_exact_solver() -> None:
    g = [GroupCost(f"g{i}", "objects", 1.0, 1.0, np.zeros((1, 2))) for i in range(21)]
    p = Problem.build(g, np.zeros(3), np.zeros(2), 0.4, Loss())
    with pytest.raises(InvalidInput):
        solve(p)


# -- grids ----------------------------------------------------------------------------
def test_ros_grid_orientation_and_validation() -> None:
    # 3 wide, 2 high; row-major with x fastest: the cell (x=2, y=1) is occupied
    g = from_occupancy_values(3, 2, 0.5, (1.0, 2.0), [0, 0, -1, 0, 0, 100])
    assert g.state.shape == (3, 2)
    assert g.state[2, 1] == 100 and g.state[2, 0] == -1
    assert not g.free(np.array([[2.3, 2.7]]), 0.0)[0]
    assert g.free(np.array([[1.2, 2.2]]), 0.0)[0]
    with pytest.raises(InvalidInput) as e:
        from_occupancy_values(3, 2, 0.5, (0, 0), [0] * 5)
    assert e.value.field == "grid.data"
    with pytest.raises(InvalidInput):
        from_occupancy_values(3, 2, 0.5, (0, 0), [0] * 5 + [101])


def test_unknown_components_and_entry_points() -> None:
    state = np.zeros((20, 20), dtype=int)
    state[0, :] = state[-1, :] = state[:, 0] = state[:, -1] = 100
    state[5:10, 5:10] = -1     # 25 cells = 0.25 m2 at 0.1 m
    state[12:19, 12:18] = -1   # 42 cells
    g = from_occupancy_values(20, 20, 0.1, (0, 0), state.T.ravel().tolist())
    comps = g.unknown_components()
    assert [round(c.area_m2, 2) for c in comps] == [0.42, 0.25]
    assert len(comps[1].entries) == 16   # the ring of a 5x5 block touching free cells
    assert comps[1].centroid == pytest.approx([0.75, 0.75])


def test_a_requests_own_appearance_does_not_leak_into_the_next() -> None:
    from chizu.numeric.viewpoint.planner import PlanRequest, ViewpointPlanner

    planner = ViewpointPlanner()
    own = {"a": (9.0, 9.0, 9.0, 9.0), "b": (1.0, 1.0, 1.0, 1.0), "k": 5.0, "theta_half": 0.8}
    base = {"robot": (0, 0, 0), "exit": (0, 0)}
    custom = PlanRequest.model_validate(
        {**base, "object_types": [{"name": "A", "appearance": own}]})
    plain = PlanRequest.model_validate({**base, "object_types": [{"name": "A"}]})
    assert planner.models(custom)["A"].params.a == own["a"]
    assert planner.models(plain)["A"].params == fitted_models()["A"].params


def test_replanning_recomputes_only_the_groups_whose_surroundings_changed() -> None:
    """Local plans are cached by the group and the grid near it: the same scene again
    reuses all of them, an obstacle next to one group recomputes that one only, and the
    answer equals a fresh planner's."""
    from chizu.numeric.viewpoint.grid import from_occupancy_values
    from chizu.numeric.viewpoint.planner import GroupSpec, PlanRequest, ViewpointPlanner

    def one_each(cands, regions, min_area):  # type: ignore[no-untyped-def]
        return [GroupSpec(i, "objects", (c["id"],)) for i, c in enumerate(cands)]

    cells = np.zeros((100, 100), dtype=int)             # 10 m x 10 m at 0.1 m, walls
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    req = PlanRequest.model_validate({
        "robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 120,
        "object_types": [{"name": "A", "value": 50}],
        "candidates": [{"id": "near", "type": "A", "x": 2.5, "y": 2.5},
                       {"id": "far", "type": "A", "x": 7.5, "y": 7.5}]})
    grid = from_occupancy_values(100, 100, 0.1, (0.0, 0.0), cells.ravel().tolist())
    planner = ViewpointPlanner()
    first = planner.plan(req, grid, one_each)
    assert planner.local_plans.misses == 2 and planner.local_plans.hits == 0
    again = planner.plan(req, grid, one_each)
    assert planner.local_plans.hits == 2
    assert [g.t_obs for g in again.groups] == [g.t_obs for g in first.groups]
    cells[70:73, 60:63] = 100          # a box next to "far": y 7-7.3 m, x 6-6.3 m
    moved = from_occupancy_values(100, 100, 0.1, (0.0, 0.0), cells.ravel().tolist())
    changed = planner.plan(req, moved, one_each)
    assert planner.local_plans.misses == 3 and planner.local_plans.hits == 3
    fresh = ViewpointPlanner().plan(req, moved, one_each)
    assert [g.t_obs for g in changed.groups] == pytest.approx([g.t_obs for g in fresh.groups])
    # a group whose box runs past the grid's edge still sees changes inside it
    edge = req.model_copy(update={"candidates": [req.candidates[0].model_copy(
        update={"id": "edge", "x": 9.3, "y": 9.3})]})
    planner.plan(edge, moved, one_each)
    cells[85:88, 85:88] = 100                            # a box next to it
    boxed = from_occupancy_values(100, 100, 0.1, (0.0, 0.0), cells.ravel().tolist())
    misses = planner.local_plans.misses
    planner.plan(edge, boxed, one_each)
    assert planner.local_plans.misses == misses + 1


def test_travel_goes_around_walls() -> None:
    """Geodesic travel (eqs. 18-20 along shortest paths): a wall with a door at one end
    makes the way round the door, not through the wall."""
    from chizu.numeric.viewpoint.grid import TravelMap
    from chizu.numeric.viewpoint.planner import geodesic

    cells = np.zeros((100, 100), dtype=int)              # 10 m x 10 m at 0.1 m, [y, x]
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    cells[:85, 50] = 100                                 # a wall at x = 5 m, door at y > 8.5
    grid = from_occupancy_values(100, 100, 0.1, (0.0, 0.0), cells.ravel().tolist())
    dist = geodesic(TravelMap(grid))
    a, b = np.array([[2.5, 2.0]]), np.array([[7.5, 2.0]])
    d = float(dist(a, b)[0])
    around = 2 * float(np.hypot(2.5, 7.0))               # via the door at (5, 9)
    assert 0.95 * around < d < 1.2 * around               # not the 5 m through the wall
    same_side = float(dist(a, np.array([[2.5, 6.0]]))[0])
    assert same_side == pytest.approx(4.0, rel=0.1)
    p = Problem.with_travel([GroupCost("g", "objects", 10.0, 1.0, b)], np.array([*a[0], 0]),
                            a[0], 0.5, Loss(kind="L3"), dist)
    assert p.t_start[0] == pytest.approx(d / 0.5) and p.t_leave == 0.0


def test_travel_fields_equal_skimage_minimum_cost_paths() -> None:
    """The distance fields (one Dijkstra on the map's graph) equal skimage's
    MCP_Geometric on the same costs, including sources on impassable cells."""
    from skimage.graph import MCP_Geometric

    from chizu.numeric.viewpoint.grid import TravelMap

    rng = np.random.default_rng(4)
    for _ in range(3):
        cells = np.where(rng.random((60, 50)) < 0.15, 100, 0)
        cells[rng.random((60, 50)) < 0.1] = -1
        grid = from_occupancy_values(50, 60, 0.1, (0.0, 0.0), cells.ravel().tolist())
        tm = TravelMap(grid)
        src = rng.uniform(0.2, 4.8, (3, 2))
        i, j, _ = tm.cells(src)
        cost = tm.cost.copy()
        starts = [(int(a), int(b)) for a, b in zip(i, j, strict=True)]
        for a, b in starts:
            cost[a, b] = 1.0 if not np.isfinite(cost[a, b]) else cost[a, b]
        ref, _ = MCP_Geometric(cost).find_costs(starts)
        out = tm.field(src)
        reach = np.isfinite(ref)
        assert np.array_equal(reach, np.isfinite(out))
        assert np.allclose(out[reach], ref[reach] * tm.cell_m)


def test_random_rooms_are_valid_and_repeatable() -> None:
    from chizu.numeric.geometry import point_segment_distance
    from chizu.numeric.worlds import (
        ROOM_TEXTURES,
        SUMMARY_ROOM_M,
        _polygon_walls,
        random_summary_room,
    )

    w, h = SUMMARY_ROOM_M
    outline = len(_polygon_walls([(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)], ROOM_TEXTURES, 2.0))
    for seed in range(10):
        d = random_summary_room(seed)
        assert d == random_summary_room(seed)
        assert 2 <= len(d.objects) <= 4
        xy = np.array([[o.x, o.y] for o in d.objects])
        assert (xy > 0.6).all() and (xy < np.array(SUMMARY_ROOM_M) - 0.6).all()
        cabinets = d.walls[outline:]
        assert 1 <= len(cabinets) <= 3
        a = np.array([c.a for c in cabinets])
        b = np.array([c.b for c in cabinets])
        assert point_segment_distance(xy, a, b).min() >= 0.7
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 10 * np.eye(len(xy))
        assert gaps.min() >= 1.0
