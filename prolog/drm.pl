/*  Direct Reachability Map (paper §5).

    reachable(From, To) is derived from the qualitative relations; each
    derivation names the movement method written in its rule body:

      move1    go to a landmark that was already reached (rea) or is
               directly recognised (rec)                         [paper]
      move2    pass between two recognised landmarks B and D that lie on
               opposite sides of the line From-To, then head for To once
               it is recognised (the paper's Fig. 1 rule)         [paper]
      move3    go to a recognised landmark B from which From and To are
               seen in opposite directions (B lies on the segment
               From-To), keep straight on past B until To is recognised
      retrace  drive back along a route that was driven before (rea in
               the other direction)

    move3 and retrace are geometrically sound: move3 follows a straight line
    that provably contains To; retrace repeats a route known to be free.

    P(reachable) = P(rule) * prod P(body_i) (paper, §5); the DRM keeps, for
    each ordered pair, the derivation with the highest probability.

    Experience both ways: every arc the robot drove (record_reached/3) or
    failed to drive (record_failed/3) is counted in arc_outcomes(From, To,
    Succeeded, Failed).  The edge's probability is the posterior mean of a
    Beta prior whose mean is the derivation's P and whose weight is
    experience_weight pseudo-trials:

        P' = (w * P + Succeeded) / (w + Succeeded + Failed)

    so an arc that failed once weighs about 2/3 of what it did (w = 2), one
    that keeps failing tends to 0, and successes raise it towards 1.
*/
:- module(drm,
          [ reachable/5,            % +World, ?From, ?To, -P, -Method
            reachable/6,            % +World, ?From, ?To, -P, -Method, -Via
            drm_edge/6,             % +World, ?From, ?To, -P, -Method, -Via
            drm_edges/2,            % +World, -Edges
            record_reached/3,       % +World, +From, +To
            record_failed/3,        % +World, +From, +To
            arc_outcomes/5          % +World, ?From, ?To, -Succeeded, -Failed
          ]).
:- use_module(world).
:- use_module(params).
:- use_module(qualitative).
:- use_module(json_args).
:- multifile api:run/3.

:- multifile world:domain_fact/2.
world:domain_fact(qualitative, arc_outcomes/4).  % arcs driven and failed, counted

%   How many trials the rules' probability weighs against the robot's own
%   outcomes of an arc (the Beta prior's weight, above).
params:default_parameter(experience_weight, 2.0).

params:default_rule_probability(reach_rea, 0.99).
params:default_rule_probability(reach_rec, 0.95).
params:default_rule_probability(move2, 0.95).     % geometrically guaranteed shortcut
params:default_rule_probability(move3, 0.85).
params:default_rule_probability(retrace, 0.9).

%!  reachable(+World, ?From, ?To, -P, -Method) is nondet.
%!  reachable(+World, ?From, ?To, -P, -Method, -Via) is nondet.
%
%   One derivation of reachable(From, To) with its probability and movement
%   method; Via lists the landmarks the method steers by.
reachable(W, A, B, P, Method) :-
    reachable(W, A, B, P, Method, _).

reachable(W, A, B, P, Method, Via) :-
    ensure_closed(W),
    world_module(W, M),
    reachable_(M, A, B, P, Method, Via).

%   The closure is materialised in the world module (d_rec/3, d_lr/4,
%   d_align/5); bodies are ordered so that every lookup is indexed.
reachable_(M, A, B, P, move1, []) :-       % reachable :- rea.   [move1]
    M:rea(A, B),
    rp(M, reach_rea, [1.0], P).
reachable_(M, A, B, P, move1, []) :-       % reachable :- rec.   [move1]
    M:d_rec(A, B, P0), A \== B,
    rp(M, reach_rec, [P0], P).
reachable_(M, A, C, P, move2, [B, D]) :-   % Fig. 1              [move2]
    M:d_rec(B, A, P4), M:d_rec(B, C, P5), C \== A,
    M:d_lr(B, C, A, P2),
    M:d_lr(A, B, D, P1), D \== C,
    M:d_lr(D, A, C, P3),
    M:d_rec(D, A, P6), M:d_rec(D, C, P7),
    rp(M, move2, [P1, P2, P3, P4, P5, P6, P7], P).
reachable_(M, A, C, P, move3, [B]) :-      % straight on through B
    M:d_rec(A, B, P1),
    M:d_align(B, A, C, not_same, P2), C \== A,
    M:d_rec(B, C, P3),
    rp(M, move3, [P1, P2, P3], P).
reachable_(M, B, A, P, retrace, []) :-     % back along a driven route
    M:rea(A, B), A \== B,
    rp(M, retrace, [1.0], P).

rp(M, Rule, Ps, P) :-
    rule_probability(M, Rule, R),
    foldl([X, Y0, Y]>>(Y is X*Y0), Ps, R, P).

%!  drm_edge(+World, ?From, ?To, -P, -Method, -Via) is nondet.
%
%   The DRM's edge From->To: the derivation of highest probability (ties:
%   the first in the order of the rules above).
drm_edge(W, A, B, P, Method, Via) :-
    drm_edges(W, Edges),
    member(edge(A, B, P, Method, Via), Edges).

%!  drm_edges(+World, -Edges) is det.
%
%   Edges is the list of edge(From, To, P, Method, Via), one per ordered
%   pair, sorted by From and To.
drm_edges(W, Edges) :-
    qualitative:ensure_closed(W),
    findall((A-B)-(P-Method-Via), reachable(W, A, B, P, Method, Via), Pairs),
    keysort(Pairs, Sorted),                 % stable: rule order kept per pair
    group_pairs_by_key(Sorted, Groups),
    world_module(W, M),
    maplist(best_edge(M), Groups, Edges).

%   The derivation's P0 weighed with the arc's outcomes (the Beta posterior
%   mean of the header).
experienced(M, A, B, P0, P) :-
    (   M:arc_outcomes(A, B, S, F)
    ->  parameter(M, experience_weight, Wt),
        P is (Wt*P0 + S) / (Wt + S + F)
    ;   P = P0
    ).

best_edge(M, (A-B)-[D|Ds], edge(A, B, P, Method, Via)) :-
    foldl(better, Ds, D, P0-Method-Via),
    experienced(M, A, B, P0, P).

better(P-M-V, P0-_-_, P-M-V) :- P > P0, !.
better(_, Best, Best).

%!  record_reached(+World, +From, +To) is det.
%
%   Bookkeeping of the paper's rea/2: the robot drove From -> To (and one
%   more success of the arc).
record_reached(W, A, B) :-
    world_module(W, M),
    (   M:rea(A, B)
    ->  true
    ;   assertz(M:rea(A, B))
    ),
    count_outcome(M, A, B, 1, 0).

%!  record_failed(+World, +From, +To) is det.
%
%   The robot set out on the DRM's arc From -> To and did not arrive: one
%   more failure of the arc, which lowers the edge's probability.
record_failed(W, A, B) :-
    world_module(W, M),
    count_outcome(M, A, B, 0, 1).

count_outcome(M, A, B, DS, DF) :-
    (   retract(M:arc_outcomes(A, B, S0, F0))
    ->  true
    ;   S0 = 0, F0 = 0
    ),
    S is S0 + DS, F is F0 + DF,
    assertz(M:arc_outcomes(A, B, S, F)).

%!  arc_outcomes(+World, ?From, ?To, -Succeeded, -Failed) is nondet.
%
%   How often the robot drove the arc From -> To, and how often it failed.
arc_outcomes(W, A, B, S, F) :-
    world_module(W, M),
    M:arc_outcomes(A, B, S, F).


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

api:run(reached, Args, Out) :-
    arc_outcome(record_reached, Args, Out).
api:run(failed, Args, Out) :-
    arc_outcome(record_failed, Args, Out).

%   {world, from, to}: Record(World, From, To) in a transaction; the arc's
%   outcomes so far.
arc_outcome(Record, Args, _{world:W, from:A, to:B, succeeded:S, failed:F}) :-
    existing_world(Args, W),
    arg_(from, Args, AT), known_landmark(W, AT, from, A),
    arg_(to, Args, BT), known_landmark(W, BT, to, B),
    transaction(call(Record, W, A, B)),
    arc_outcomes(W, A, B, S, F).

api:run(relations, Args, Rs) :-
    existing_world(Args, W),
    arg_(kind, Args, KT), atom_string(K, KT),
    (   relation_kind(K) -> true ; throw(chizu_error(unknown_kind(KT), kind)) ),
    findall(R, relation(K, W, R), Rs).

api:run(drm, Args, _{nodes:Ns, edges:Es}) :-
    existing_world(Args, W), world_module(W, M),
    findall(L, M:landmark(L), Ns),
    drm_edges(W, Edges),
    maplist(edge_dict(M), Edges, Es).

edge_dict(M, edge(A, B, P, Me, V),
          _{from:A, to:B, p:P, method:Me, via:V, succeeded:S, failed:F}) :-
    (   M:arc_outcomes(A, B, S, F) -> true ; S = 0, F = 0 ).

relation_kind(rec).
relation_kind(frec).
relation_kind(lr).
relation_kind(align).
relation_kind(rea).
relation_kind(reachable).

relation(rec, W, _{from:A, to:B, p:P}) :- rec(W, A, B, P).
relation(frec, W, _{from:A, to:B, feature:F, p:1.0}) :- frec(W, A, B, F).
relation(lr, W, _{at:A, left:B, right:C, p:P}) :- lr(W, A, B, C, P).
relation(align, W, _{at:A, first:B, second:C, kind:K, p:P}) :- align(W, A, B, C, K, P).
relation(rea, W, _{from:A, to:B, p:1.0}) :- world_module(W, M), M:rea(A, B).
relation(reachable, W, _{from:A, to:B, p:P, method:Me, via:V}) :-
    reachable(W, A, B, P, Me, V).
