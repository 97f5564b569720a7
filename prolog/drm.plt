/*  Expected outcomes of the reachable rules (defaults from drm.pl).  */
:- begin_tests(drm).
:- use_module(world).
:- use_module(qualitative).
:- use_module(drm).

w(Name, Facts) :-
    create_world(Name), world_module(Name, M),
    forall(member(F, Facts), assertz(M:F)),
    invalidate(Name).
close_to(X, Y) :- abs(X - Y) < 1.0e-9.

%   The paper's Fig. 1: A=(0,0), C=(0,10), B=(-1,5), D=(1,5).
fig1([ rec(a, b), rec(a, d), lr(a, b, d),
       rec(b, a), rec(b, c), lr(b, c, a),
       rec(d, a), rec(d, c), lr(d, a, c) ]).

test(move1_rec, [nondet, cleanup(drop_world(d1)), true(close_to(P, 0.95))]) :-
    w(d1, [rec(a, b)]), reachable(d1, a, b, P, move1).
test(move1_rea, [nondet, cleanup(drop_world(d2)), true(close_to(P, 0.99))]) :-
    w(d2, [rea(a, b)]), reachable(d2, a, b, P, move1).
test(retrace, [nondet, cleanup(drop_world(d3)), true(close_to(P, 0.9))]) :-
    w(d3, [rea(a, b)]), reachable(d3, b, a, P, retrace).
test(move2_fig1, [nondet, cleanup(drop_world(d4)), true(Via == [b, d])]) :-
    fig1(F), w(d4, F),
    reachable(d4, a, c, P, move2, Via),
    close_to(P, 0.95).
test(move2_needs_every_body_fact, [nondet, cleanup(drop_world(d5))]) :-
    fig1(F0), select(lr(d, a, c), F0, F1), select(rec(d, c), F1, F),
    w(d5, F),
    \+ reachable(d5, a, c, _, move2, _).
test(move3_through_b, [nondet, cleanup(drop_world(d6)), true(close_to(P, 0.85))]) :-
    %  from b, a and c in opposite directions: b is on the segment a-c
    w(d6, [rec(a, b), rec(b, c), rec(b, a), align(b, a, c, not_same)]),
    reachable(d6, a, c, P, move3, [b]).
test(drm_keeps_best_derivation, [nondet, cleanup(drop_world(d7))]) :-
    w(d7, [rec(a, b), rea(a, b)]),
    drm_edge(d7, a, b, P, move1, []),
    close_to(P, 0.99).
test(drm_one_edge_per_pair, [nondet, cleanup(drop_world(d8))]) :-
    fig1(F), w(d8, [rea(a, b)|F]),
    drm_edges(d8, Es),
    findall(A-B, member(edge(A, B, _, _, _), Es), Pairs),
    sort(Pairs, Set), length(Pairs, N), length(Set, N).
test(record_reached_idempotent, [nondet, cleanup(drop_world(d9))]) :-
    w(d9, []), record_reached(d9, a, b), record_reached(d9, a, b),
    world_module(d9, M), aggregate_all(count, M:rea(a, b), 1).

test(failure_lowers_edge, [nondet, cleanup(drop_world(d10))]) :-
    %  the rule's 0.95 weighs as two trials: one failure gives 2*0.95/3
    w(d10, [rec(a, b)]),
    record_failed(d10, a, b),
    drm_edge(d10, a, b, P1, move1, []),
    close_to(P1, 2*0.95/3),
    record_failed(d10, a, b),
    drm_edge(d10, a, b, P2, move1, []),
    close_to(P2, 2*0.95/4),
    arc_outcomes(d10, a, b, 0, 2).
test(success_raises_edge, [nondet, cleanup(drop_world(d11))]) :-
    %  reached once: rea's 0.99, weighed with one success
    w(d11, [rec(a, b)]),
    record_reached(d11, a, b), record_reached(d11, a, b),
    arc_outcomes(d11, a, b, 2, 0),
    drm_edge(d11, a, b, P, move1, []),
    close_to(P, (2*0.99 + 2)/4).
test(failure_only_that_arc, [nondet, cleanup(drop_world(d12))]) :-
    %  the way back keeps its probability
    w(d12, [rec(a, b), rec(b, a)]),
    record_failed(d12, a, b),
    drm_edge(d12, b, a, P, move1, []),
    close_to(P, 0.95).
test(experience_weight_per_world, [nondet, cleanup(drop_world(d13))]) :-
    w(d13, [rec(a, b), parameter(experience_weight, 8.0)]),
    record_failed(d13, a, b),
    drm_edge(d13, a, b, P, move1, []),
    close_to(P, 8*0.95/9).
test(failure_reroutes_path, [nondet, cleanup(drop_world(d14))]) :-
    %  a -> c directly (0.95) or through b (0.95 * 0.95): after two failures of
    %  a -> c the path through b is the better one
    w(d14, [rec(a, c), rec(a, b), rec(b, c)]),
    drm_edge(d14, a, c, P0, _, _), P0 > 0.95*0.95,
    record_failed(d14, a, c), record_failed(d14, a, c),
    drm_edge(d14, a, c, P1, _, _), P1 < 0.95*0.95.

:- end_tests(drm).
