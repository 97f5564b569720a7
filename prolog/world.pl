/*  World modules: every world's knowledge lives in its own Prolog module.

    A world named `lab` is the module 'world:lab'.  Nothing outside this file
    builds that name, and every user-given name is validated by valid_id/1
    before it becomes an atom, so worlds never see each other's facts and a
    client string never becomes a goal.
*/
:- module(world,
          [ valid_id/1,             % +Text
            text_id/2,              % +Text, -Atom
            world_module/2,         % +World, -Module
            create_world/1,         % +World
            drop_world/1,           % +World
            world_exists/1,         % ?World
            clear_world/1,          % +World
            world_fact/1            % ?Name/Arity
          ]).

%!  world_fact(?PI) is nondet.
%
%   The dynamic predicates every world module holds.  Quantities (angle/4,
%   distance/3) only live there while an observation is being converted.
world_fact(landmark/1).             % landmark(Id)
world_fact(rec/2).                  % rec(L1, L2): L2 recognisable from L1
world_fact(frec/3).                 % frec(L1, L2, Feature)
world_fact(angle/4).                % angle(L1, L2, L3, D): transient
world_fact(distance/3).             % distance(L1, L2, D): transient
world_fact(lr/3).                   % observed lr(L1, L2, L3)
world_fact(align/4).                % observed align(L1, L2, L3, same|not_same)
world_fact(rea/2).                  % rea(L1, L2): L2 was reached from L1
world_fact(rule_probability/2).     % per-world override of a rule's P(head|body)
world_fact(parameter/2).            % per-world override of a named parameter
world_fact(closed/0).               % derived relations are materialised
world_fact(d_lr/4).                 % materialised lr with probability
world_fact(d_align/5).              % materialised align with probability
world_fact(d_rec/3).                % materialised rec with probability
world_fact(eig_point/3).            % eig_point(I, X, Y): eigenspace learning point
world_fact(eig_triplet/4).          % eig_triplet(T, Points, Directions, Area)
world_fact(eig_candidate_set/2).    % eig_candidate_set(M, T): T in candidate set M
world_fact(map_pose/5).             % map_pose(Run, I, X, Y, Th): SLAM keyframe pose
world_fact(map_info/5).             % map_info(Run, Res, Free, Occupied, Unknown)
world_fact(unknown_region/5).       % unknown_region(Run, Id, X, Y, Area)
world_fact(committed_map/1).        % committed_map(Run): the world's current map
world_fact(loop_closure/4).         % loop_closure(Run, ScanA, ScanB, Score): SLAM closure
world_fact(vp_candidate/5).         % vp_candidate(Id, Type, X, Y, RMax): object candidate
world_fact(vp_unknown/4).           % vp_unknown(Id, X, Y, Area): unknown region of the grid
world_fact(vp_group/3).             % vp_group(G, objects|unknown, Members): derived group
world_fact(vp_min_area/1).          % vp_min_area(A): region area threshold of the scene
world_fact(vp_plan_step/9).         % vp_plan_step(K, G, X, Y, Th, TravelM, ObserveS, PRecog, DoneAtS)

%!  valid_id(+Text) is semidet.
%
%   True if Text (atom or string) is a valid world, landmark or feature id:
%   `^[a-z][a-zA-Z0-9_]{0,63}$`.
valid_id(Text) :-
    (   atom(Text) ; string(Text) ),
    atom_codes(Text, [C|Cs]),
    length(Cs, N), N =< 63,
    code_type(C, lower),
    C =< 0'z,
    forall(member(X, Cs), id_code(X)).

id_code(C) :- between(0'a, 0'z, C), !.
id_code(C) :- between(0'A, 0'Z, C), !.
id_code(C) :- between(0'0, 0'9, C), !.
id_code(0'_).

%!  text_id(+Text, -Id) is det.
%
%   Id is the atom for Text; throws chizu_error(invalid_id(Text)) otherwise.
text_id(Text, Id) :-
    (   valid_id(Text)
    ->  atom_string(Id, Text)
    ;   throw(chizu_error(invalid_id(Text)))
    ).

%!  world_module(+World, -Module) is det.
world_module(World, Module) :-
    text_id(World, Id),
    atom_concat('world:', Id, Module).

%!  create_world(+World) is det.
%
%   Creates (or empties) the module of World and declares its facts dynamic.
create_world(World) :-
    world_module(World, M),
    forall(world_fact(Name/Arity),
           ( functor(H, Name, Arity),
             dynamic(M:Name/Arity),
             retractall(M:H) )),
    text_id(World, Id),
    retractall(known_world(Id)),
    assertz(known_world(Id)).

:- dynamic known_world/1.

%!  world_exists(?World) is nondet.
world_exists(World) :-
    (   var(World)
    ->  known_world(World)
    ;   valid_id(World),
        atom_string(Id, World),
        known_world(Id)
    ).

%!  clear_world(+World) is det.
%
%   Removes every fact of World but keeps the world.
clear_world(World) :-
    world_module(World, M),
    forall(world_fact(Name/Arity),
           ( functor(H, Name, Arity), retractall(M:H) )).

%!  drop_world(+World) is det.
drop_world(World) :-
    clear_world(World),
    text_id(World, Id),
    retractall(known_world(Id)).

:- multifile prolog:message//1.
prolog:message(chizu_error(E)) --> [ 'chizu: ~q'-[E] ].
prolog:message(chizu_error(E, Field)) --> [ 'chizu: ~q (field ~w)'-[E, Field] ].
