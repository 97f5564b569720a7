/*  Qualitative relations (Morizane, Yamada, Toyoda: "Qualitative navigation
    of a mobile robot by spatial reasoning", §3-4).

    An observation at landmark L gives rec/2 and frec/3 (qualitative) and
    angle/4, distance/3 (quantitative).  observe/5 asserts them, converts
    the angles into lr/3 and align/4, and then drops every quantity, as the
    paper insists: after conversion only qualitative relations remain.

    Angle convention.  angle(L1, L2, L3, D): D = ∠L1L2L3, the signed angle at
    the vertex L2 from the ray L2->L3 to the ray L2->L1, counter-clockwise
    positive, wrapped to (-pi, pi].  Hence lr(L1, L2, L3) ("from L1, L2 is
    left of L3") holds when ∠L2L1L3 is in (0, pi).

    Conversion with tolerance eps = align_tolerance_rad:
        |D| < eps            -> align(L1, L2, L3, same)
        |D| > pi - eps       -> align(L1, L2, L3, not_same)
        eps =< D =< pi-eps   -> lr(L1, L2, L3)
        otherwise            -> lr(L1, L3, L2)
    so each observed pair yields exactly one relation.  Distances have no
    qualitative counterpart in the paper; they are dropped unused.

    Probabilities.  Observed relations have P = 1.  A rule
    head :- b1, ..., bn with conditional probability r = P(head | body)
    gives P(head) = r * prod P(bi).  When a relation has several
    derivations we keep the MAXIMUM.  Because every r =< 1, going round a
    cycle of rules can never raise a probability, so the fixpoint exists and
    is reached even on cyclic rule sets.  Derivations whose
    probability falls below min_probability are pruned; this bounds the
    closure on large maps and is the only approximation made.

    The maximum is computed by an explicit fixpoint (generalised Dijkstra,
    see DERIVATION below) rather than mode-directed tabling: tabling made a
    separate table per call pattern of the transitive rules and took ~35 s
    on the 22-landmark demo office; the fixpoint takes milliseconds.  The
    closure is materialised per world (d_lr/4, d_align/5, d_rec/3 in the
    world module) the first time it is needed after a change.
*/
:- module(qualitative,
          [ observe/4,              % +World, +At, +Seen, +Angles
            lr/5,                   % +World, ?L1, ?L2, ?L3, -P
            align/6,                % +World, ?L1, ?L2, ?L3, ?Kind, -P
            rec/4,                  % +World, ?L1, ?L2, -P
            frec/4,                 % +World, ?L1, ?L2, ?Feature
            invalidate/1,           % +World
            ensure_closed/1         % +World
          ]).
:- use_module(world).
:- use_module(params).
:- use_module(library(heaps)).
:- use_module(library(yall)).
:- use_module(library(apply)).
:- use_module(json_args).
:- multifile api:run/3.

%   The facts this module reads and writes in a world (world.pl).
:- multifile world:domain_fact/2, world:derived_fact/1.
world:domain_fact(qualitative, rec/2).      % rec(L1, L2): L2 recognisable from L1
world:domain_fact(qualitative, frec/3).     % frec(L1, L2, Feature)
world:domain_fact(qualitative, lr/3).       % observed lr(L1, L2, L3)
world:domain_fact(qualitative, align/4).    % observed align(L1, L2, L3, same|not_same)
world:domain_fact(qualitative, rea/2).      % rea(L1, L2): L2 was reached from L1
world:derived_fact(angle/4).                % angle(L1, L2, L3, D): transient
world:derived_fact(distance/3).             % distance(L1, L2, D): transient
world:derived_fact(closed/0).               % derived relations are materialised
world:derived_fact(d_lr/4).                 % materialised lr with probability
world:derived_fact(d_align/5).              % materialised align with probability
world:derived_fact(d_rec/3).                % materialised rec with probability

%   Rule probabilities P(head | body), named after the rules below.
params:default_rule_probability(lr_rot_right, 0.95).      % paper: lr(D,A,C) :- lr(A,C,D)
params:default_rule_probability(lr_rot_left, 0.95).       % paper: lr(B,D,A) :- lr(A,B,D)
params:default_rule_probability(lr_transitive, 0.6).      % not guaranteed: angles may sum past pi
params:default_rule_probability(lr_align_same, 0.9).
params:default_rule_probability(lr_align_opposite, 0.9).
params:default_rule_probability(align_symmetry, 0.99).
params:default_rule_probability(align_between, 0.9).
params:default_rule_probability(align_same_transitive, 0.85).
params:default_rule_probability(rec_symmetry, 0.8).

params:default_parameter(align_tolerance_rad, 0.0873).    % 5 degrees
%   A relation below 0.5 is more likely false than true; planning on it makes
%   no sense, and the cut keeps the closure small: on the 102-landmark office
%   0.2 gave 53 762 lr relations in 2.4 s, 0.5 gives 5 968 in 0.1 s with the
%   same DRM edges.
params:default_parameter(min_probability, 0.5).

%!  observe(+World, +At, +Seen, +Angles) is det.
%
%   Replaces what is known from landmark At by one panoramic observation.
%   Seen is a list of seen(L, Features); Angles a list of angle(L1, At, L2, D)
%   (radians) and distance(At, L, D) (metres) terms.  All ids must be atoms
%   of known landmarks (checked by the caller, api.pl).  Runs in a
%   transaction: either the whole observation lands or nothing does.
observe(World, At, Seen, Quantities) :-
    world_module(World, M),
    transaction(observe_(M, At, Seen, Quantities)),
    invalidate(World).

observe_(M, At, Seen, Quantities) :-
    retractall(M:rec(At, _)),
    retractall(M:frec(At, _, _)),
    retractall(M:lr(At, _, _)),
    retractall(M:align(At, _, _, _)),
    forall(member(seen(L, Fs), Seen),
           ( assertz(M:rec(At, L)),
             forall(member(F, Fs), assertz(M:frec(At, L, F))) )),
    forall(member(Q, Quantities), assertz(M:Q)),
    convert_quantities(M),
    retractall(M:angle(_, _, _, _)),
    retractall(M:distance(_, _, _)).

%!  convert_quantities(+M) is det.
%
%   The paper's conversion rules lr :- rec, rec, angle_0_180 and
%   align :- rec, rec, angle_0_e / angle_180_e, applied to every angle fact.
convert_quantities(M) :-
    parameter(M, align_tolerance_rad, Eps),
    forall(( M:angle(L2, L1, L3, D),
             M:rec(L1, L2), M:rec(L1, L3) ),
           ( angle_relation(D, Eps, L1, L2, L3, Rel),
             assertz(M:Rel) )).

angle_relation(D, Eps, L1, L2, L3, align(L1, L2, L3, same)) :-
    abs(D) < Eps, !.
angle_relation(D, Eps, L1, L2, L3, align(L1, L2, L3, not_same)) :-
    abs(D) > pi - Eps, !.
angle_relation(D, _, L1, L2, L3, lr(L1, L2, L3)) :-
    D > 0, !.
angle_relation(_, _, L1, L2, L3, lr(L1, L3, L2)).

%!  invalidate(+World) is det.
%
%   Forget the materialised closure of World (after any change).
invalidate(World) :-
    world_module(World, M),
    retractall(M:closed),
    retractall(M:d_lr(_, _, _, _)),
    retractall(M:d_align(_, _, _, _, _)),
    retractall(M:d_rec(_, _, _)).

%!  ensure_closed(+World) is det.
%
%   Materialise the maximum-probability closure of rec, lr and align.
ensure_closed(World) :-
    world_module(World, M),
    (   M:closed
    ->  true
    ;   invalidate(World),
        closure(M),
        assertz(M:closed)
    ).

%!  rec(+World, ?L1, ?L2, -P) is nondet.
%!  lr(+World, ?L1, ?L2, ?L3, -P) is nondet.
%!  align(+World, ?L1, ?L2, ?L3, ?Kind, -P) is nondet.
%
%   The relation with its maximum derivation probability.
rec(World, A, B, P) :-
    ensure_closed(World), world_module(World, M), M:d_rec(A, B, P).
lr(World, A, B, C, P) :-
    ensure_closed(World), world_module(World, M), M:d_lr(A, B, C, P).
align(World, A, B, C, K, P) :-
    ensure_closed(World), world_module(World, M), M:d_align(A, B, C, K, P).

%!  frec(+World, ?L1, ?L2, ?Feature) is nondet.
%
%   Observed directional features (probability 1; no rules derive them).
frec(World, A, B, F) :-
    world_module(World, M), M:frec(A, B, F).

		 /*******************************
		 *          DERIVATION          *
		 *******************************/

%   The rules, written as "when fact F becomes final, these heads follow".
%   Each rule appears once per body position, joined with facts that are
%   already final.  Rule names match the default_rule_probability/2 facts.
%
%   rec_symmetry      rec(B,A)        :- rec(A,B).               (observed rec only)
%   lr_rot_right      lr(D,A,C)       :- lr(A,C,D).              paper
%   lr_rot_left       lr(B,D,A)       :- lr(A,B,D).              paper
%   lr_transitive     lr(A,B,D)       :- lr(A,B,C), lr(A,C,D).   not guaranteed (sum of angles may pass pi)
%   lr_align_same     lr(A,B,D)       :- align(A,B,C,same), lr(A,C,D).
%   lr_align_opposite lr(A,D,C)       :- align(A,B,C,not_same), lr(A,B,D).
%   align_symmetry    align(A,C,B,K)  :- align(A,B,C,K).
%   align_between     align(B,A,C,same) :- align(A,B,C,not_same).   A lies between B and C
%   align_same_transitive align(A,B,D,same) :- align(A,B,C,same), align(A,C,D,same).
%
%   Closure by a generalised Dijkstra (Knuth 1977): facts leave a priority
%   queue in order of decreasing probability; the first time a fact leaves
%   it, its probability is the maximum over all derivations, because every
%   rule multiplies by factors =< 1.  Each fact is expanded once, so cyclic
%   rule sets terminate and the result is exact (up to the min_probability
%   cut-off).

closure(M) :-
    parameter(M, min_probability, Min),
    findall(NP-F, ( base_fact(M, F), NP = -1.0 ), Seeds),
    list_to_heap(Seeds, H0),
    drain(M, Min, H0).

base_fact(M, rec(A, B)) :- M:rec(A, B).
base_fact(M, lr(A, B, C)) :- M:lr(A, B, C).
base_fact(M, align(A, B, C, K)) :- M:align(A, B, C, K).

drain(M, Min, H0) :-
    (   get_from_heap(H0, NP, F, H1)
    ->  P is -NP,
        (   final(M, F, _)
        ->  H = H1
        ;   assert_final(M, F, P),
            findall(NQ-G,
                    ( consequence(M, F, P, G, Q), Q >= Min, \+ final(M, G, _), NQ is -Q ),
                    New),
            foldl([K-V, Hi, Ho]>>add_to_heap(Hi, K, V, Ho), New, H1, H)
        ),
        drain(M, Min, H)
    ;   true
    ).

final(M, rec(A, B), P) :- M:d_rec(A, B, P).
final(M, lr(A, B, C), P) :- M:d_lr(A, B, C, P).
final(M, align(A, B, C, K), P) :- M:d_align(A, B, C, K, P).

assert_final(M, rec(A, B), P) :- assertz(M:d_rec(A, B, P)).
assert_final(M, lr(A, B, C), P) :- assertz(M:d_lr(A, B, C, P)).
assert_final(M, align(A, B, C, K), P) :- assertz(M:d_align(A, B, C, K, P)).

%!  consequence(+M, +Fact, +P, -Head, -Q) is nondet.
%
%   Head follows with probability Q from the newly final Fact (probability P)
%   and facts that are already final.
consequence(M, rec(A, B), P, rec(B, A), Q) :-
    M:rec(A, B), A \== B,
    r(M, rec_symmetry, R), Q is R*P.
consequence(M, lr(A, C, D), P, lr(D, A, C), Q) :-
    r(M, lr_rot_right, R), Q is R*P.
consequence(M, lr(A, B, D), P, lr(B, D, A), Q) :-
    r(M, lr_rot_left, R), Q is R*P.
consequence(M, lr(A, B, C), P, lr(A, B, D), Q) :-           % as first body
    M:d_lr(A, C, D, P2), D \== B,
    r(M, lr_transitive, R), Q is R*P*P2.
consequence(M, lr(A, C, D), P, lr(A, B, D), Q) :-           % as second body
    M:d_lr(A, B, C, P1), B \== D,
    r(M, lr_transitive, R), Q is R*P1*P.
consequence(M, lr(A, C, D), P, lr(A, B, D), Q) :-           % lr_align_same, second body
    M:d_align(A, B, C, same, P1), B \== D,
    r(M, lr_align_same, R), Q is R*P1*P.
consequence(M, lr(A, B, D), P, lr(A, D, C), Q) :-           % lr_align_opposite, second body
    M:d_align(A, B, C, not_same, P1), D \== C,
    r(M, lr_align_opposite, R), Q is R*P1*P.
consequence(M, align(A, B, C, K), P, align(A, C, B, K), Q) :-
    r(M, align_symmetry, R), Q is R*P.
consequence(M, align(A, B, C, not_same), P, align(B, A, C, same), Q) :-
    r(M, align_between, R), Q is R*P.
consequence(M, align(A, B, C, same), P, align(A, B, D, same), Q) :-   % first body
    M:d_align(A, C, D, same, P2), B \== D,
    r(M, align_same_transitive, R), Q is R*P*P2.
consequence(M, align(A, C, D, same), P, align(A, B, D, same), Q) :-   % second body
    M:d_align(A, B, C, same, P1), B \== D,
    r(M, align_same_transitive, R), Q is R*P1*P.
consequence(M, align(A, B, C, same), P, lr(A, B, D), Q) :-           % lr_align_same, first body
    M:d_lr(A, C, D, P2), B \== D,
    r(M, lr_align_same, R), Q is R*P*P2.
consequence(M, align(A, B, C, not_same), P, lr(A, D, C), Q) :-       % lr_align_opposite, first
    M:d_lr(A, B, D, P2), D \== C,
    r(M, lr_align_opposite, R), Q is R*P*P2.

r(M, Rule, R) :- rule_probability(M, Rule, R).


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

api:run(observe, Args, _{world:W, at:At, relations:N}) :-
    existing_world(Args, W),
    arg_(at, Args, AtText), known_landmark(W, AtText, at, At),
    arg_(seen, Args, Seen0),
    foldl(seen_item(W, At), Seen0, Seen, 0, _),
    arg_(angles, Args, Angles0),
    maplist(angle_item(W, At), Angles0, Angles),
    arg_(distances, Args, Dists0),
    maplist(distance_item(W, At), Dists0, Dists),
    append(Angles, Dists, Quantities),
    observe(W, At, Seen, Quantities),
    world_module(W, M),
    aggregate_all(count, ( M:lr(At, _, _) ; M:align(At, _, _, _) ), N).

seen_item(W, At, S, seen(L, Fs), I0, I) :-
    I is I0 + 1,
    field("seen[~d].landmark", [I0], F),
    arg_(landmark, S, LT), known_landmark(W, LT, F, L),
    (   L == At -> throw(chizu_error(self_observation(L), F)) ; true ),
    (   get_dict(features, S, Fs0) -> true ; Fs0 = [] ),
    field("seen[~d].features", [I0], FF),
    maplist(feature_id(FF), Fs0, Fs).

%   Not a yall lambda: a compiled lambda would not see the bound FF.
feature_id(Field, Text, Id) :- id_field(Text, Field, Id).

angle_item(W, At, [T1, T2, D], angle(L1, At, L2, D)) :-
    known_landmark(W, T1, angles, L1), known_landmark(W, T2, angles, L2),
    (   number(D) -> true ; throw(chizu_error(invalid_angle(D), angles)) ).
distance_item(W, At, [T, D], distance(At, L, D)) :-
    known_landmark(W, T, distances, L),
    (   number(D) -> true ; throw(chizu_error(invalid_distance(D), distances)) ).

