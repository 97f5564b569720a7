/*  REPL conveniences: `chizu repl WORLD` loads a world's facts and makes the
    world current, so that the world's relations are asked without the world
    argument:  ?- reachable(a, c, P, M).

    The goals are the REST query's, by the same names: every relation
    query.pl allows (its relation_goal/3: rec/3, frec/3, landmark/1,
    reachable/4, state_after/2, committed_map/1, loop_closure/4, joinable/2,
    plan_step/4, mission_outcome/1, ...) is defined here for the current world
    and exported, so the copy REPL, `chizu repl --live` and POST /query answer
    the same goal alike.  The world's facts live in its module 'world:W'.
*/
:- module(repl,
          [ use_world/1,            % +World
            load_world_facts/2,     % +World, +File
            world_goal/1,           % ?Name/Arity
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
:- use_module(query, []).

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

%!  world_goal(?PI) is nondet.
%
%   The relations asked for the current world: query:relation_goal/3's heads.
world_goal(N/A) :-
    distinct(N/A, ( clause(query:relation_goal(_, H, _), _), functor(H, N, A) )).

%   One clause and one export per relation, made while this file compiles:
%       Head :- w(W), query:relation_goal(W, Head, Body), call(Body).
term_expansion(world_goals, Clauses) :-
    findall(C, ( world_goal(N/A),
                 functor(H, N, A),
                 member(C, [ (:- export(N/A)),
                             (H :- w(W), query:relation_goal(W, H, B), call(B)) ]) ),
            Clauses).

world_goals.

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
