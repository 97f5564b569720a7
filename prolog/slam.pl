/*  The map a laser SLAM run committed to a world.

    The numeric side (numeric/slam/) builds an occupancy grid from a run and,
    when the run is committed, reports these facts per world (asserted only
    through the api op slam_facts, which replaces all of them at once, so
    committing a new run drops the previous run's facts):

      map_pose(Run, I, X, Y, Th)         keyframe pose I (integer >= 0) of run
                                         Run, metres / radians
      map_info(Run, ResM, FreeM2, OccupiedM2, UnknownM2)
                                         occupancy summary (floats >= 0)
      unknown_region(Run, Id, X, Y, AreaM2)
                                         enclosed unknown region Id (integer
                                         >= 0), centroid (X, Y), area
      committed_map(Run)                 Run's map is the world's current map
                                         (at most one per world)
      loop_closure(Run, ScanA, ScanB, Score)
                                         the run's SLAM closed a loop: scan ScanB
                                         matched the submap anchored at scan
                                         ScanA (integers, 0 =< ScanA < ScanB,
                                         counted in the order the scans came),
                                         match score (float in [0, 1]); at most
                                         one per (Run, ScanA, ScanB)

    Run is the run id, an atom matching ^r[0-9a-f]{1,64}$ (valid_run_id/1).
    The rules below only look at the committed run.
*/
:- module(slam,
          [ replace_slam_facts/2,    % +World, +Facts
            slam_fact/1,             % ?Name/Arity
            valid_run_id/1,          % +Text
            committed_run/2,         % +World, -Run
            explored_fraction/2,     % +World, -F
            unknown_region_within/6, % +World, +X, +Y, +R, ?Id, -D
            largest_unknown_region/3, % +World, -Id, -Area
            map_path_length/2,       % +World, -L
            loop_closure_count/2,    % +World, -N
            closes_loop/3            % +World, ?ScanA, ?ScanB
          ]).
:- use_module(library(aggregate)).
:- use_module(library(apply)).
:- use_module(library(lists)).
:- use_module(library(pairs)).
:- use_module(world).

%!  slam_fact(?PI) is nondet.
%
%   The world facts this module reads (declared per world in world.pl).
slam_fact(map_pose/5).
slam_fact(map_info/5).
slam_fact(unknown_region/5).
slam_fact(committed_map/1).
slam_fact(loop_closure/4).

%!  valid_run_id(+Text) is semidet.
%
%   Text (atom or string) is a run id: `^r[0-9a-f]{1,64}$`.
valid_run_id(Text) :-
    (   atom(Text) ; string(Text) ),
    atom_codes(Text, [0'r|Cs]),
    length(Cs, N), N >= 1, N =< 64,
    forall(member(C, Cs), hex_code(C)).

hex_code(C) :- between(0'0, 0'9, C), !.
hex_code(C) :- between(0'a, 0'f, C).

%!  replace_slam_facts(+World, +Facts) is det.
%
%   Replaces every slam fact of World by Facts, in a transaction.  Every
%   fact is checked first (shape, types, ranges; at most one committed_map,
%   whose run has exactly one map_info; no duplicate pose or region index
%   and no duplicate loop closure within a run); on bad input chizu_error(not_a_fact(F)),
%   chizu_error(invalid_fact(F)) or chizu_error(inconsistent_facts(Why)) is
%   thrown and nothing changes.  Numbers are stored as floats.
replace_slam_facts(World, Facts) :-
    world_module(World, M),
    (   is_list(Facts) -> true ; throw(chizu_error(invalid_facts(Facts))) ),
    maplist(checked_fact, Facts, Normal),
    consistent(Normal),
    transaction(( forall(slam_fact(N/A), ( functor(H, N, A), retractall(M:H) )),
                  forall(member(F, Normal), assertz(M:F)) )).

checked_fact(F, _) :-
    var(F), !,
    throw(chizu_error(invalid_fact(F))).
checked_fact(F, N) :-
    functor(F, Name, Arity),
    (   slam_fact(Name/Arity) -> true ; throw(chizu_error(not_a_fact(F))) ),
    (   normal_fact(F, N0) -> N = N0 ; throw(chizu_error(invalid_fact(F))) ).

normal_fact(map_pose(R, I, X0, Y0, T0), map_pose(R, I, X, Y, T)) :-
    run(R), index(I), real(X0, X), real(Y0, Y), real(T0, T).
normal_fact(map_info(R, Re0, F0, O0, U0), map_info(R, Re, F, O, U)) :-
    run(R), nonneg(Re0, Re), nonneg(F0, F), nonneg(O0, O), nonneg(U0, U).
normal_fact(unknown_region(R, I, X0, Y0, A0), unknown_region(R, I, X, Y, A)) :-
    run(R), index(I), real(X0, X), real(Y0, Y), nonneg(A0, A).
normal_fact(committed_map(R), committed_map(R)) :-
    run(R).
normal_fact(loop_closure(R, A, B, S0), loop_closure(R, A, B, S)) :-
    run(R), index(A), index(B), A < B, score(S0, S).

run(R) :- atom(R), valid_run_id(R).
index(I) :- integer(I), I >= 0.
real(V, F) :-
    number(V),
    catch(F is float(V), _, fail),
    float_class(F, C), memberchk(C, [zero, subnormal, normal]).
nonneg(V, F) :- real(V, F), F >= 0.0.
score(V, F) :- nonneg(V, F), F =< 1.0.

consistent(Facts) :-
    findall(R, member(committed_map(R), Facts), Cs),
    (   Cs = [_, _|_] -> throw(chizu_error(inconsistent_facts(committed_maps(Cs)))) ; true ),
    forall(member(R, Cs),
           (   findall(x, member(map_info(R, _, _, _, _), Facts), [_])
           ->  true
           ;   throw(chizu_error(inconsistent_facts(map_info(R))))
           )),
    findall(R, member(map_info(R, _, _, _, _), Facts), Is),
    no_duplicates(Is, map_info),
    findall(R-I, member(map_pose(R, I, _, _, _), Facts), Ps),
    no_duplicates(Ps, map_pose),
    findall(R-I, member(unknown_region(R, I, _, _, _), Facts), Us),
    no_duplicates(Us, unknown_region),
    findall(R-(A-B), member(loop_closure(R, A, B, _), Facts), Ls),
    no_duplicates(Ls, loop_closure).

no_duplicates(Keys, Kind) :-
    msort(Keys, Sorted),
    (   append(_, [K, K|_], Sorted)
    ->  throw(chizu_error(inconsistent_facts(duplicate(Kind, K))))
    ;   true
    ).

		 /*******************************
		 *            RULES             *
		 *******************************/

%!  committed_run(+World, -Run) is semidet.
committed_run(World, Run) :-
    world_module(World, M),
    M:committed_map(Run0), !,
    Run = Run0.

%!  explored_fraction(+World, -F) is semidet.
%
%   F = (Free + Occupied) / (Free + Occupied + Unknown) of the committed
%   run's map, 0.0 if that total is 0.  Fails if there is no committed map.
explored_fraction(World, F) :-
    committed_run(World, Run),
    world_module(World, M),
    M:map_info(Run, _, Free, Occ, Unk), !,
    Total is Free + Occ + Unk,
    (   Total =:= 0 -> F = 0.0 ; F is float((Free + Occ) / Total) ).

%!  unknown_region_within(+World, +X, +Y, +R, ?Id, -D) is nondet.
%
%   Unknown region Id of the committed run has its centroid D =< R metres
%   from (X, Y).  Throws chizu_error(invalid_number(V), Field) if X, Y or R
%   is not a number (or R is negative).
unknown_region_within(World, X, Y, R, Id, D) :-
    number_arg(X, x), number_arg(Y, y), number_arg(R, radius),
    (   R >= 0 -> true ; throw(chizu_error(invalid_number(R), radius)) ),
    committed_run(World, Run),
    world_module(World, M),
    M:unknown_region(Run, Id, RX, RY, _),
    D is sqrt((X - RX)**2 + (Y - RY)**2),
    D =< R.

number_arg(V, Field) :-
    (   number(V) -> true ; throw(chizu_error(invalid_number(V), Field)) ).

%!  largest_unknown_region(+World, -Id, -Area) is semidet.
%
%   The committed run's unknown region with the largest area (the lowest id
%   among equals).  Fails if there is none.
largest_unknown_region(World, Id, Area) :-
    committed_run(World, Run),
    world_module(World, M),
    findall(I-A, M:unknown_region(Run, I, _, _, A), [P|Ps]),
    foldl(larger_region, Ps, P, Id-Area).

larger_region(I-A, I0-A0, Best) :-
    (   A > A0 -> Best = I-A
    ;   A =:= A0, I < I0 -> Best = I-A
    ;   Best = I0-A0
    ).

%!  map_path_length(+World, -L) is semidet.
%
%   Sum of the distances between consecutive keyframe poses (by index) of
%   the committed run; 0.0 with fewer than two poses.  Fails if there is no
%   committed map.
map_path_length(World, L) :-
    committed_run(World, Run),
    world_module(World, M),
    findall(I-(X-Y), M:map_pose(Run, I, X, Y, _), Ps0),
    keysort(Ps0, Ps),
    pairs_values(Ps, Pts),
    path_length(Pts, 0.0, L).

path_length([P, Q|Rest], L0, L) :- !,
    step_length(P, Q, D),
    L1 is L0 + D,
    path_length([Q|Rest], L1, L).
path_length(_, L, L).

step_length(X0-Y0, X1-Y1, D) :- D is sqrt((X1 - X0)**2 + (Y1 - Y0)**2).

%!  loop_closure_count(+World, -N) is semidet.
%
%   N is the number of loop closures (loop_closure/4) of the committed run,
%   0 if its SLAM closed none.  Fails if there is no committed map.
loop_closure_count(World, N) :-
    committed_run(World, Run),
    world_module(World, M),
    aggregate_all(count, M:loop_closure(Run, _, _, _), N).

%!  closes_loop(+World, ?ScanA, ?ScanB) is nondet.
%
%   The committed run closed a loop between scans ScanA and ScanB (ScanB
%   matched the submap anchored at ScanA; ScanA < ScanB).  Fails if there is
%   no committed map or no such closure.
closes_loop(World, ScanA, ScanB) :-
    committed_run(World, Run),
    world_module(World, M),
    M:loop_closure(Run, ScanA, ScanB, _).
