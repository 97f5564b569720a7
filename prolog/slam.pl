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
:- use_module(json_args).
:- multifile api:run/3.

%!  slam_fact(?PI) is nondet.
%
%   The world facts this module reads (declared per world in world.pl).
slam_fact(PI) :- domain_fact(slam, PI).
slam_fact(unknown_region/5).        % its runs' regions (world.pl)

:- multifile world:domain_fact/2.
world:domain_fact(slam, map_pose/5).
world:domain_fact(slam, map_info/5).
world:domain_fact(slam, committed_map/1).
world:domain_fact(slam, loop_closure/4).

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
    (   is_list(Facts) -> true ; throw(chizu_error(invalid_facts(Facts))) ),
    maplist(checked_fact, Facts, Normal),
    store_slam_facts(World, Normal).

%   Facts already in normal form -- checked one by one, by checked_fact/2 or by
%   the slam_facts operation's field checks (each fact is checked once) --
%   checked across (consistent/1), then stored in one transaction.
store_slam_facts(World, Normal) :-
    world_module(World, M),
    consistent(Normal),
    transaction(( clear_domain(M, slam),
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
real(V, F) :- finite_real(V, F).
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


		 /*******************************
		 *   OPERATIONS (api.pl)        *
		 *******************************/

%   {world, run, poses: [[X, Y, Th]], info: {...}, regions: [{x, y, area_m2}],
%    closures?: [[ScanA, ScanB, Score]]}: replaces the world's SLAM facts.
%   closures is optional (calls stored before loop closures existed have
%   none): missing means no closures.
api:run(slam_facts, Args, _{world:W, run:Run, poses:NP, regions:NR, closures:NC}) :-
    existing_world(Args, W),
    arg_(run, Args, RunText), run_field(RunText, run, Run),
    arg_(poses, Args, Ps0), json_list(Ps0, poses),
    foldl(slam_pose_item(Run), Ps0, Ps, 0, NP),
    arg_(info, Args, Info0), slam_info(Run, Info0, Info),
    arg_(regions, Args, Rs0), json_list(Rs0, regions),
    foldl(slam_region_item(Run), Rs0, Rs, 0, NR),
    (   get_dict(closures, Args, Cs0) -> true ; Cs0 = [] ),
    json_list(Cs0, closures),
    foldl(slam_closure_item(Run), Cs0, Cs, 0, NC),
    append([[committed_map(Run), Info], Ps, Rs, Cs], Facts),
    store_slam_facts(W, Facts).

api:run(slam_summary, Args, _{run:Run, explored_fraction:F, path_length_m:L, resolution_m:Res,
                         free_m2:Free, occupied_m2:Occ, unknown_m2:Unk, regions:Regions,
                         loop_closures:NC}) :-
    existing_world(Args, W),
    committed_map_run(W, Run),
    world_module(W, M),
    M:map_info(Run, Res, Free, Occ, Unk),
    explored_fraction(W, F),
    map_path_length(W, L),
    loop_closure_count(W, NC),
    findall(Id-_{id:Id, x:X, y:Y, area_m2:A}, M:unknown_region(Run, Id, X, Y, A), Rs0),
    keysort(Rs0, Rs),
    pairs_values(Rs, Regions).

api:run(slam_regions_near, Args, Regions) :-
    existing_world(Args, W),
    arg_(x, Args, X), finite_number(X, x),
    arg_(y, Args, Y), finite_number(Y, y),
    arg_(radius, Args, R), finite_number(R, radius),
    (   R >= 0 -> true ; throw(chizu_error(invalid_radius(R), radius)) ),
    committed_map_run(W, Run),
    world_module(W, M),
    findall((D-Id)-_{id:Id, x:RX, y:RY, area_m2:A, distance:D},
            ( unknown_region_within(W, X, Y, R, Id, D),
              M:unknown_region(Run, Id, RX, RY, A) ),
            Rs0),
    keysort(Rs0, Rs),
    pairs_values(Rs, Regions).

%   A SLAM run id (^r[0-9a-f]{1,64}$); the atom is made only after the check.
run_field(Text, Field, Run) :-
    (   valid_run_id(Text) -> atom_string(Run, Text) ; throw(chizu_error(invalid_run_id(Text), Field)) ).

%   The world's committed SLAM run; a world without one has no map to read.
committed_map_run(W, Run) :-
    (   committed_run(W, Run) -> true ; throw(chizu_error(unknown_map(W), map)) ).

%   Pose indices are list positions.
slam_pose_item(Run, P, map_pose(Run, I, X, Y, Th), I, I1) :-
    I1 is I + 1,
    field("poses[~d]", [I], F),
    (   is_list(P), P = [X0, Y0, Th0] -> true ; throw(chizu_error(invalid_pose, F)) ),
    maplist(finite_float(F), [X0, Y0, Th0], [X, Y, Th]).

slam_info(Run, D, map_info(Run, Res, Free, Occ, Unk)) :-
    (   is_dict(D) -> true ; throw(chizu_error(invalid_info, info)) ),
    maplist(slam_info_value(D), [resolution_m, free_m2, occupied_m2, unknown_m2],
            [Res, Free, Occ, Unk]).

slam_info_value(D, Key, V) :-
    field("info.~w", [Key], F),
    dict_value(D, Key, F, V0),
    nonneg_float(F, V0, V).

%   Region ids are list positions.
slam_region_item(Run, D, unknown_region(Run, I, X, Y, A), I, I1) :-
    I1 is I + 1,
    field("regions[~d]", [I], F),
    (   is_dict(D) -> true ; throw(chizu_error(invalid_region, F)) ),
    slam_region_value(D, I, x, FX, X0), finite_float(FX, X0, X),
    slam_region_value(D, I, y, FY, Y0), finite_float(FY, Y0, Y),
    slam_region_value(D, I, area_m2, FA, A0), nonneg_float(FA, A0, A).

slam_region_value(D, I, Key, F, V) :-
    field("regions[~d].~w", [I, Key], F),
    dict_value(D, Key, F, V).

%   One loop closure [ScanA, ScanB, Score]: scan indices (JSON integers >= 0,
%   not 1.0) with ScanA < ScanB, and a match score in [0, 1].
slam_closure_item(Run, C, loop_closure(Run, A, B, S), I, I1) :-
    I1 is I + 1,
    field("closures[~d]", [I], F),
    (   is_list(C), C = [A, B, S0] -> true ; throw(chizu_error(invalid_closure, F)) ),
    (   integer(A), A >= 0 -> true ; throw(chizu_error(invalid_index(A), F)) ),
    (   integer(B), B >= 0 -> true ; throw(chizu_error(invalid_index(B), F)) ),
    (   A < B -> true ; throw(chizu_error(unordered_closure(A, B), F)) ),
    finite_float(F, S0, S),
    (   S =< 1.0, S >= 0.0 -> true ; throw(chizu_error(invalid_score(S0), F)) ).

