/*  Localization states of the eigenspace method with several stops (Maeda &
    Shirai, §3.3-3.4 and Fig. 4).

    The numeric analysis (numeric/eigenspace/) learns the eigenspace and
    reports, per world, these facts (asserted only through the api op
    eigenspace_facts, which replaces all of them at once):

      eig_point(I, X, Y)                 learning point I (integer >= 0) at
                                         (X, Y) metres
      eig_triplet(T, [P1,P2,P3], [Th1,Th2,Th3], AreaM2)
                                         localizable triplet T (integer >= 0):
                                         its learning points, their learning
                                         directions (radians), triangle area
      eig_candidate_set(M, T)            triplet T is in the candidate-multiple
                                         set M (integer >= 1); sets are disjoint

    At every stop the numeric side reports which triplets were hit and
    whether voting made the candidates agree (Unique).  stop_outcome/4 names
    what the stop showed:

      none          no triplet was hit
      unique        the candidates agree (voting)
      in_set(M)     every triplet hit is in candidate set M
      across(Ms)    the triplets hit lie in two or more sets Ms (sorted); only
                    what the sets have in common remains, so the place is known
      unlisted      ambiguous, and not all of the triplets are in one known set

    and next_state/3 moves the localization state, Fig. 4:

      x             position unknown
      y(M)          ambiguous within candidate set M (M = unlisted: ambiguous
                    among triplets that are in no known set, or in several)
      z             localized; absorbing

    Prev     none   unique  in_set(M)  in_set(M2\=M)  across  unlisted
    x        x      z       y(M)       y(M2)          z       y(unlisted)
    y(M)     y(M)   z       y(M)       z              z       y(M)
    z        z      z       z          z              z       z

    From y(unlisted) an in_set(M) stop gives y(M): there is no known set to
    intersect with, so the paper's "common element" argument cannot apply
    and claiming z would be unfounded.  The state only moves X -> Y -> Z.
*/
:- module(eigenspace,
          [ stop_outcome/4,         % +World, +Triplets, +Unique, -Outcome
            next_state/3,           % +Prev, +Outcome, -Next
            state_after/3,          % +World, +Stops, -State
            covers/4,               % +World, ?T, +X, +Y
            triplet_distance/5,     % +World, ?T, +X, +Y, -D
            replace_eigenspace_facts/2, % +World, +Facts
            eigenspace_fact/1,      % ?Name/Arity
            localization_state/1,   % @State
            stop_result/1           % @Outcome
          ]).
:- use_module(library(apply)).
:- use_module(library(lists)).
:- use_module(world).
:- use_module(params).
:- use_module(json_args).
:- multifile api:run/3.

%   covers/4: a point this close (metres) outside the triangle still counts.
params:default_parameter(eig_covers_tolerance_m, 0.0).

%!  eigenspace_fact(?PI) is nondet.
%
%   The world facts this module reads (declared per world in world.pl).
eigenspace_fact(PI) :- domain_fact(eigenspace, PI).

:- multifile world:domain_fact/2.
world:domain_fact(eigenspace, eig_point/3).
world:domain_fact(eigenspace, eig_triplet/4).
world:domain_fact(eigenspace, eig_candidate_set/2).

%!  replace_eigenspace_facts(+World, +Facts) is det.
%
%   Replaces every eig_* fact of World by Facts, in a transaction.  Facts
%   are checked by the caller (api.pl); only eig_* shapes are accepted here.
replace_eigenspace_facts(World, Facts) :-
    world_module(World, M),
    forall(member(F, Facts),
           ( functor(F, N, A),
             ( eigenspace_fact(N/A) -> true ; throw(chizu_error(not_a_fact(F))) ) )),
    transaction(( forall(eigenspace_fact(N/A), ( functor(H, N, A), retractall(M:H) )),
                  forall(member(F, Facts), assertz(M:F)) )).

		 /*******************************
		 *      STATES (FIG. 4)         *
		 *******************************/

%!  stop_outcome(+World, +Triplets, +Unique, -Outcome) is det.
%
%   Outcome of one stop at which the triplets Triplets (list of triplet
%   indices of World) were hit; Unique is true if voting made the
%   candidates agree.  Throws chizu_error(_, triplets) for a malformed list
%   or an unknown triplet, chizu_error(_, unique) for a non-boolean Unique.
stop_outcome(World, Ts, Unique, Outcome) :-
    world_module(World, M),
    known_triplets(M, Ts),
    (   atom(Unique), memberchk(Unique, [true, false])
    ->  true
    ;   throw(chizu_error(invalid_boolean(Unique), unique))
    ),
    sort(Ts, Set),
    (   Set == []
    ->  Outcome = none
    ;   Unique == true
    ->  Outcome = unique
    ;   maplist(set_of(M), Set, Ms0)
    ->  sort(Ms0, Ms),
        (   Ms = [S] -> Outcome = in_set(S) ; Outcome = across(Ms) )
    ;   Outcome = unlisted
    ).

known_triplets(M, Ts) :-
    (   is_list(Ts), maplist(integer, Ts)
    ->  true
    ;   throw(chizu_error(invalid_triplets(Ts), triplets))
    ),
    forall(member(T, Ts),
           (   M:eig_triplet(T, _, _, _)
           ->  true
           ;   throw(chizu_error(unknown_triplet(T), triplets))
           )).

set_of(M, T, S) :- M:eig_candidate_set(S, T), !.

%!  localization_state(@State) is semidet.
%
%   State is x, z, y(M) with M an integer >= 1, or y(unlisted).
localization_state(S) :- S == x, !.
localization_state(S) :- S == z, !.
localization_state(S) :- nonvar(S), S = y(M), set_id(M), !.

set_id(M) :- M == unlisted, !.
set_id(M) :- integer(M), M >= 1.

%!  stop_result(@Outcome) is semidet.
%
%   Outcome is a term stop_outcome/4 can give.
stop_result(O) :- O == none, !.
stop_result(O) :- O == unique, !.
stop_result(O) :- O == unlisted, !.
stop_result(O) :- nonvar(O), O = in_set(M), integer(M), M >= 1, !.
stop_result(O) :-
    nonvar(O), O = across(Ms), is_list(Ms), Ms = [_, _|_],
    forall(member(M, Ms), ( integer(M), M >= 1 )), sort(Ms, Ms).

%!  next_state(+Prev, +Outcome, -Next) is det.
%
%   The Fig. 4 transition (table above).  Throws chizu_error(_, state) or
%   chizu_error(_, outcome) if Prev or Outcome is not a state or outcome.
next_state(Prev, Outcome, Next) :-
    (   localization_state(Prev) -> true ; throw(chizu_error(invalid_state(Prev), state)) ),
    (   stop_result(Outcome) -> true ; throw(chizu_error(invalid_outcome(Outcome), outcome)) ),
    transition(Prev, Outcome, Next0), !,
    Next = Next0.

transition(z, _, z).
transition(x, none, x).
transition(x, unique, z).
transition(x, in_set(M), y(M)).
transition(x, across(_), z).
transition(x, unlisted, y(unlisted)).
transition(y(M), none, y(M)).
transition(y(_), unique, z).
transition(y(M), in_set(M), y(M)).
transition(y(unlisted), in_set(M), y(M)).
transition(y(_), in_set(_), z).            % another known set: the common element
transition(y(_), across(_), z).
transition(y(M), unlisted, y(M)).

%!  state_after(+World, +Stops, -State) is det.
%
%   State after the stops Stops (list of stop(Triplets, Unique)), starting
%   from x.
state_after(World, Stops, State) :-
    (   is_list(Stops) -> true ; throw(chizu_error(invalid_stops(Stops), stops)) ),
    foldl(stop_step(World), Stops, x, State).

stop_step(World, Stop, S0, S) :-
    (   nonvar(Stop), Stop = stop(Ts, U)
    ->  stop_outcome(World, Ts, U, O),
        next_state(S0, O, S)
    ;   throw(chizu_error(invalid_stop(Stop), stops))
    ).

		 /*******************************
		 *          GEOMETRY            *
		 *******************************/

%!  covers(+World, ?T, +X, +Y) is nondet.
%
%   (X, Y) lies in the triangle of triplet T's learning points, or within
%   eig_covers_tolerance_m of it.  A degenerate (collinear) triangle covers
%   only what is that close to its segments.
covers(World, T, X, Y) :-
    coordinates(X, Y),
    world_module(World, M),
    parameter(M, eig_covers_tolerance_m, Tol),
    M:eig_triplet(T, Ps, _, _),
    triangle(M, Ps, A, B, C),
    (   inside(X-Y, A, B, C)
    ->  true
    ;   boundary_distance(X-Y, A, B, C, D),
        D =< Tol
    ).

%!  triplet_distance(+World, ?T, +X, +Y, -D) is nondet.
%
%   D (metres) is the smallest distance from (X, Y) to one of triplet T's
%   three learning points (the paper's D(s)).
triplet_distance(World, T, X, Y, D) :-
    coordinates(X, Y),
    world_module(World, M),
    M:eig_triplet(T, Ps, _, _),
    triangle(M, Ps, A, B, C),
    maplist(point_distance(X-Y), [A, B, C], Ds),
    min_list(Ds, D).

point_distance(X-Y, PX-PY, D) :- D is sqrt((X-PX)**2 + (Y-PY)**2).

coordinates(X, Y) :-
    (   number(X) -> true ; throw(chizu_error(invalid_number(X), x)) ),
    (   number(Y) -> true ; throw(chizu_error(invalid_number(Y), y)) ).

triangle(M, [P1, P2, P3], A, B, C) :-
    point(M, P1, A), point(M, P2, B), point(M, P3, C).

point(M, I, X-Y) :- M:eig_point(I, X, Y), !.

cross(AX-AY, BX-BY, PX-PY, Z) :-          % (B - A) x (P - A)
    Z is (BX-AX)*(PY-AY) - (BY-AY)*(PX-AX).

inside(P, A, B, C) :-
    cross(A, B, C, Orient),
    Orient =\= 0,
    cross(A, B, P, S1), cross(B, C, P, S2), cross(C, A, P, S3),
    S1*Orient >= 0, S2*Orient >= 0, S3*Orient >= 0.

boundary_distance(P, A, B, C, D) :-
    segment_distance(P, A, B, D1),
    segment_distance(P, B, C, D2),
    segment_distance(P, C, A, D3),
    D is min(D1, min(D2, D3)).

segment_distance(PX-PY, AX-AY, BX-BY, D) :-
    L2 is (BX-AX)**2 + (BY-AY)**2,
    (   L2 =:= 0
    ->  T = 0
    ;   T is max(0, min(1, ((PX-AX)*(BX-AX) + (PY-AY)*(BY-AY)) / L2))
    ),
    D is sqrt((PX - (AX + T*(BX-AX)))**2 + (PY - (AY + T*(BY-AY)))**2).


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

api:run(eigenspace_facts, Args, _{world:W, points:NP, triplets:NT, candidate_sets:NS}) :-
    existing_world(Args, W),
    arg_(points, Args, Ps0), json_list(Ps0, points),
    foldl(eig_point_item, Ps0, Ps, 0, NP),
    arg_(triplets, Args, Ts0), json_list(Ts0, triplets),
    foldl(eig_triplet_item(NP), Ts0, Ts, 0, NT),
    arg_(candidate_sets, Args, Ss0), json_list(Ss0, candidate_sets),
    foldl(eig_set_item(NT), Ss0, Sss, 0, NS),
    append(Sss, MFs),
    foldl(eig_set_disjoint, MFs, [], _),
    pairs_keys(MFs, Ms),
    append([Ps, Ts, Ms], Facts),
    replace_eigenspace_facts(W, Facts).

api:run(eigenspace_transition, Args, _{outcome:ON, sets:Sets, state:SJ}) :-
    existing_world(Args, W),
    arg_(state, Args, SJ0), json_state(W, SJ0, Prev),
    arg_(triplets, Args, Ts),
    arg_(unique, Args, U),
    stop_outcome(W, Ts, U, Outcome),
    next_state(Prev, Outcome, Next),
    outcome_json(Outcome, ON, Sets),
    state_json(Next, SJ).

api:run(eigenspace_covering, Args, Cs) :-
    existing_world(Args, W),
    arg_(x, Args, X), finite_number(X, x),
    arg_(y, Args, Y), finite_number(Y, y),
    findall(_{triplet:T, distance_m:D},
            ( covers(W, T, X, Y), triplet_distance(W, T, X, Y, D) ),
            Cs).

eig_point_item(P, eig_point(I, X, Y), I, I1) :-
    I1 is I + 1,
    field("points[~d]", [I], F),
    (   P = [X0, Y0] -> true ; throw(chizu_error(invalid_point, F)) ),
    finite_number(X0, F), finite_number(Y0, F),
    X is float(X0), Y is float(Y0).

eig_triplet_item(NP, D, eig_triplet(T, Ps, Ds, A), T, T1) :-
    T1 is T + 1,
    field("triplets[~d]", [T], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_triplet, F)) ),
    field("triplets[~d].points", [T], FP),
    field("triplets[~d].directions_rad", [T], FD),
    field("triplets[~d].area_m2", [T], FA),
    dict_value(D, points, FP, Ps),
    (   is_list(Ps), length(Ps, 3) -> true ; throw(chizu_error(invalid_length(3), FP)) ),
    forall(member(P, Ps), index_in(P, NP, unknown_point, FP)),
    (   sort(Ps, [_, _, _]) -> true ; throw(chizu_error(duplicate_point, FP)) ),
    dict_value(D, directions_rad, FD, Ds0),
    (   is_list(Ds0), length(Ds0, 3) -> true ; throw(chizu_error(invalid_length(3), FD)) ),
    maplist(finite_float(FD), Ds0, Ds),
    dict_value(D, area_m2, FA, A0),
    finite_number(A0, FA),
    (   A0 >= 0 -> A is float(A0) ; throw(chizu_error(invalid_area(A0), FA)) ).

%   Set ids are list positions + 1.
eig_set_item(NT, S, Facts, I, I1) :-
    I1 is I + 1,
    field("candidate_sets[~d]", [I], F),
    (   is_list(S), S \== [] -> true ; throw(chizu_error(invalid_set, F)) ),
    foldl(eig_set_member(NT, I), S, Facts, 0, _).

eig_set_member(NT, I, T, eig_candidate_set(M, T)-F, J, J1) :-
    J1 is J + 1,
    M is I + 1,
    field("candidate_sets[~d][~d]", [I, J], F),
    index_in(T, NT, unknown_triplet, F).

%   Every triplet is in at most one candidate set.
eig_set_disjoint(eig_candidate_set(_, T)-F, Seen, [T|Seen]) :-
    (   memberchk(T, Seen) -> throw(chizu_error(duplicate_triplet(T), F)) ; true ).

%   {"state": "x"} | {"state": "y", "set": M | "unlisted"} | {"state": "z"}
json_state(W, D, State) :-
    (   is_dict(D), get_dict(state, D, K), string(K) -> true
    ;   throw(chizu_error(invalid_state, state))
    ),
    (   K == "x" -> State = x, no_set(D)
    ;   K == "z" -> State = z, no_set(D)
    ;   K == "y"
    ->  (   get_dict(set, D, S) -> true ; throw(chizu_error(missing(set), 'state.set')) ),
        (   S == "unlisted"
        ->  State = y(unlisted)
        ;   integer(S), S >= 1
        ->  world_module(W, M),
            (   M:eig_candidate_set(S, _) -> State = y(S)
            ;   throw(chizu_error(unknown_set(S), 'state.set'))
            )
        ;   throw(chizu_error(invalid_set(S), 'state.set'))
        )
    ;   throw(chizu_error(invalid_state(K), 'state.state'))
    ).

no_set(D) :-
    (   get_dict(set, D, S), S \== null -> throw(chizu_error(unexpected(set), 'state.set')) ; true ).

state_json(x, _{state:"x"}).
state_json(z, _{state:"z"}).
state_json(y(unlisted), _{state:"y", set:"unlisted"}) :- !.
state_json(y(M), _{state:"y", set:M}).

outcome_json(none, "none", []).
outcome_json(unique, "unique", []).
outcome_json(unlisted, "unlisted", []).
outcome_json(in_set(M), "in_set", [M]).
outcome_json(across(Ms), "across", Ms).

