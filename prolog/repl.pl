/*  REPL conveniences: `chizu repl WORLD` loads a world's facts and makes the
    world current, so that the paper's relations can be asked without the
    world argument:  ?- reachable(a, c, P, M).
    Eigenspace helpers: eig_state_after/2, covers/3, ...; SLAM map helpers:
    committed_map(Run), explored_fraction(F), largest_unknown_region(Id, A),
    unknown_region_within(X, Y, R, Id, D), map_path_length(L),
    loop_closure_count(N), closes_loop(ScanA, ScanB).  The world's facts
    (map_pose/5, loop_closure/4, ...) live in its module 'world:W'.
*/
:- module(repl,
          [ use_world/1,            % +World
            load_world_facts/2,     % +World, +File
            reachable/4,            % ?From, ?To, -P, -Method
            lr/4,                   % ?L1, ?L2, ?L3, -P
            align/5,                % ?L1, ?L2, ?L3, ?Kind, -P
            rec/3,                  % ?L1, ?L2, -P
            drm_edge/4,             % ?From, ?To, -P, -Method
            landmark/1,             % ?Landmark
            eig_stop_outcome/3,     % +Triplets, +Unique, -Outcome
            eig_next_state/3,       % +Prev, +Outcome, -Next
            eig_state_after/2,      % +Stops, -State
            covers/3,               % ?T, +X, +Y
            triplet_distance/4,     % ?T, +X, +Y, -D
            explored_fraction/1,    % -F
            largest_unknown_region/2, % -Id, -Area
            unknown_region_within/5, % +X, +Y, +R, ?Id, -D
            map_path_length/1,      % -L
            loop_closure_count/1,   % -N
            closes_loop/2,          % ?ScanA, ?ScanB
            committed_map/1,        % ?Run
            observation_group/3,    % ?G, ?Kind, ?Members
            same_group/2,           % ?A, ?B
            plan_step/4,            % ?K, ?G, ?Pose, ?Times
            mission_step/3,         % ?S, ?What, ?Result
            mission_pose/3,         % -X, -Y, -Th
            mission_path/2,         % -Landmarks, -P
            mission_outcome/1,      % -Outcome
            main/0
          ]).
:- use_module(library(main), [argv_options/3]).
:- use_module(world).
:- use_module(qualitative, []).
:- use_module(drm, []).
:- use_module(eigenspace, []).
:- use_module(slam, []).
:- use_module(grouping, []).
:- use_module(mission, []).

:- dynamic current_world/1.

%!  use_world(+World) is det.
use_world(World) :-
    text_id(World, W),
    (   world_exists(W) -> true ; throw(chizu_error(unknown_world(W))) ),
    retractall(current_world(_)),
    assertz(current_world(W)).

%!  load_world_facts(+World, +File) is det.
%
%   Create World and assert the facts stored in File (one term per clause,
%   as written by the service's `facts` operation).  Terms are read as data
%   and only whitelisted fact shapes are asserted.
load_world_facts(World, File) :-
    create_world(World),
    world_module(World, M),
    setup_call_cleanup(open(File, read, In),
                       load_terms(In, M),
                       close(In)).

load_terms(In, M) :-
    read_term(In, T, []),
    (   T == end_of_file
    ->  true
    ;   functor(T, N, A),
        (   world_fact(N/A) -> assertz(M:T) ; throw(chizu_error(not_a_fact(T))) ),
        load_terms(In, M)
    ).

w(W) :- ( current_world(W) -> true ; throw(chizu_error(no_current_world)) ).

reachable(A, B, P, M) :- w(W), drm:reachable(W, A, B, P, M).
lr(A, B, C, P) :- w(W), qualitative:lr(W, A, B, C, P).
align(A, B, C, K, P) :- w(W), qualitative:align(W, A, B, C, K, P).
rec(A, B, P) :- w(W), qualitative:rec(W, A, B, P).
drm_edge(A, B, P, M) :- w(W), drm:drm_edge(W, A, B, P, M, _).
landmark(L) :- w(W), world_module(W, M), M:landmark(L).

%   Eigenspace localization (eigenspace.pl), e.g.
%   ?- eig_state_after([stop([3, 7], false), stop([7], false)], S).
eig_stop_outcome(Ts, U, O) :- w(W), eigenspace:stop_outcome(W, Ts, U, O).
eig_next_state(S0, O, S) :- eigenspace:next_state(S0, O, S).
eig_state_after(Stops, S) :- w(W), eigenspace:state_after(W, Stops, S).
covers(T, X, Y) :- w(W), eigenspace:covers(W, T, X, Y).
triplet_distance(T, X, Y, D) :- w(W), eigenspace:triplet_distance(W, T, X, Y, D).

%   The committed SLAM map (slam.pl), e.g.
%   ?- explored_fraction(F), largest_unknown_region(Id, A).
explored_fraction(F) :- w(W), slam:explored_fraction(W, F).
largest_unknown_region(Id, A) :- w(W), slam:largest_unknown_region(W, Id, A).
unknown_region_within(X, Y, R, Id, D) :- w(W), slam:unknown_region_within(W, X, Y, R, Id, D).
map_path_length(L) :- w(W), slam:map_path_length(W, L).
loop_closure_count(N) :- w(W), slam:loop_closure_count(W, N).
closes_loop(A, B) :- w(W), slam:closes_loop(W, A, B).
committed_map(Run) :- w(W), world_module(W, M), M:committed_map(Run).

%   The last viewpoint scene and plan (grouping.pl), e.g.
%   ?- plan_step(K, G, pose(X, Y, Th), times(TravelM, ObserveS, PRecog, DoneAtS)).
observation_group(G, Kind, Members) :- w(W), grouping:observation_group(W, G, Kind, Members).
same_group(A, B) :- w(W), grouping:same_group(W, A, B).
plan_step(K, G, Pose, Times) :- w(W), grouping:plan_step(W, K, G, Pose, Times).

%   The last mission (mission.pl), e.g.
%   ?- mission_step(S, What, Result).   ?- mission_outcome(O).
mission_step(S, What, R) :- w(W), world_module(W, M), M:mission_step(S, What, R).
mission_pose(X, Y, Th) :- w(W), mission:mission_pose(W, X, Y, Th).
mission_path(Ls, P) :- w(W), mission:mission_path(W, Ls, P).
mission_outcome(O) :- w(W), mission:mission_outcome(W, O).

%!  main is det.
%
%   Entry for `swipl prolog/load.pl -g repl:main -- --world W --facts F`.
main :-
    current_prolog_flag(argv, Argv),
    argv_options(Argv, _, Opts),
    (   memberchk(world(W0), Opts), memberchk(facts(F), Opts)
    ->  atom_string(W0, WS),
        load_world_facts(WS, F),
        use_world(WS),
        format("chizu: world ~w loaded; try  ?- reachable(From, To, P, Method).~n", [W0])
    ;   true
    ).
