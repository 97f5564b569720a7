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
    derivations we keep the MAXIMUM (mode-directed tabling, answer
    subsumption on the last argument).  Because every r =< 1, going round a
    cycle of rules can never raise a probability, so the fixpoint exists and
    tabling reaches it even on cyclic rule sets.  Derivations whose
    probability falls below min_probability are pruned; this bounds the
    closure on large maps and is the only approximation made.

    The closure is materialised per world (d_lr/4, d_align/5, d_rec/3 in the
    world module) the first time it is needed after a change, and the
    tables are abolished afterwards.
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
params:default_parameter(min_probability, 0.05).

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
        forall(rec_t(M, A, B, P), assertz(M:d_rec(A, B, P))),
        forall(lr_t(M, A, B, C, P), assertz(M:d_lr(A, B, C, P))),
        forall(align_t(M, A, B, C, K, P), assertz(M:d_align(A, B, C, K, P))),
        abolish_all_tables,
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

:- table rec_t(_, _, _, max).
:- table lr_t(_, _, _, _, max).
:- table align_t(_, _, _, _, _, max).

derived(M, Rule, Ps, P) :-
    rule_probability(M, Rule, R),
    foldl([X, Y0, Y]>>(Y is X*Y0), Ps, R, P),
    parameter(M, min_probability, Min),
    P >= Min.

%   rec: observed, or by symmetry (range and line of sight are symmetric,
%   but recognition from the other side is not guaranteed).
rec_t(M, A, B, 1.0) :- M:rec(A, B).
rec_t(M, B, A, P) :- M:rec(A, B), A \== B, derived(M, rec_symmetry, [1.0], P).

%   lr
lr_t(M, A, B, C, 1.0) :- M:lr(A, B, C).
lr_t(M, D, A, C, P) :-                     % paper: lr(D,A,C) :- lr(A,C,D).
    lr_t(M, A, C, D, P0), derived(M, lr_rot_right, [P0], P).
lr_t(M, B, D, A, P) :-                     % paper: lr(B,D,A) :- lr(A,B,D).
    lr_t(M, A, B, D, P0), derived(M, lr_rot_left, [P0], P).
lr_t(M, A, B, D, P) :-                     % B left of C, C left of D => B left of D
    lr_t(M, A, B, C, P1), lr_t(M, A, C, D, P2), B \== D,
    derived(M, lr_transitive, [P1, P2], P).
lr_t(M, A, B, D, P) :-                     % B in the direction of C, C left of D
    align_t(M, A, B, C, same, P1), lr_t(M, A, C, D, P2), B \== D,
    derived(M, lr_align_same, [P1, P2], P).
lr_t(M, A, D, C, P) :-                     % C opposite B, B left of D => D left of C
    align_t(M, A, B, C, not_same, P1), lr_t(M, A, B, D, P2), D \== C,
    derived(M, lr_align_opposite, [P1, P2], P).

%   align
align_t(M, A, B, C, K, 1.0) :- M:align(A, B, C, K).
align_t(M, A, C, B, K, P) :-               % symmetric in the two seen landmarks
    align_t(M, A, B, C, K, P0), derived(M, align_symmetry, [P0], P).
align_t(M, B, A, C, same, P) :-            % A between B and C: from B, A and C coincide
    align_t(M, A, B, C, not_same, P0), derived(M, align_between, [P0], P).
align_t(M, A, B, D, same, P) :-            % same direction is transitive
    align_t(M, A, B, C, same, P1), align_t(M, A, C, D, same, P2), B \== D,
    derived(M, align_same_transitive, [P1, P2], P).
